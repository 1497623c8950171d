# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The improved ``tilt_detection`` variant (the default): a whole-sphere attitude estimator.

Unit quaternions only, no Euler angles, so a robot on its side or back is an
ordinary state. The structure follows the ideas published for VQF (Laidig &
Seel, *Information Fusion* 2023): the gyroscope is integrated into an
almost-inertial frame ``I``; the accelerometer is rotated into ``I`` and
low-pass filtered there (linear accelerations of a robot that does not drift
away average out, gravity does not); a separate inclination correction
``q_inc`` (``I`` -> earth) makes the filtered acceleration point up. The
correction is therefore blind to bumps, vibration and braking shorter than
the filter time constant. The gyro bias is estimated by a small Kalman
filter, from the mean rate while the IMU is at rest and, in motion, from the
inclination corrections the accelerometer asks for. Beyond VQF, the same
Kalman filter also estimates the three gyro scale factors (MEMS gyros carry
0.5-2 % sensitivity errors; while turning fast they, not the bias, dominate
the drift): the gyro error is modelled as ``b + diag(s) w``. Written from the
published description, not from VQF's code.

The fall decision is the angle between the body z axis (``base_link`` after
the mounting rotation) and world up.

Units: time s, rates rad/s, specific force m/s^2, angles rad. Quaternions are
``(w, x, y, z)``, sensor-to-earth.
"""

from __future__ import annotations

import math
from typing import Optional

from robot_calib.methods.tilt_detection.lowpass import LowPass, LowPass3
from robot_calib.methods.tilt_detection.params import ImprovedFilterParams
from robot_calib.methods.tilt_detection.quaternion import (align_up, positive_w, qmul, qnorm,
                                                           qrot)
from robot_calib.methods.tilt_detection.variant_base import TiltEstimatorBase


class AttitudeEstimator:
    """
    Whole-sphere 6D attitude estimator with gyro bias estimation (see the module docstring).

    Call :meth:`update` with each sample; :attr:`quat` is the sensor-to-earth
    attitude (yaw drifts; inclination is what the accelerometer observes).
    """

    def __init__(self, p: ImprovedFilterParams, ts: float = 0.005):
        """Create the estimator for a nominal sampling period ``ts`` (s)."""
        self.p = p
        self.ts = ts
        self._deg = math.pi / 180.0
        th_g = p.rest_gyro_threshold * self._deg
        self._rest_gyr2 = th_g * th_g
        """Squared rate threshold of rest, and of still enough to snap ((rad/s)^2)."""
        self._rest_acc2 = p.rest_accel_threshold ** 2
        # a mean rate beyond the largest bias accepted is a turn, however steady
        self._rest_mean2 = (max(p.bias_clip, p.rest_gyro_threshold) * self._deg) ** 2
        self._snap_on = p.rest_snap_angle > 0.0
        self._snap_cos = math.cos(p.rest_snap_angle * self._deg)
        self._bias_on = p.motion_bias or p.rest_bias
        self.reset()

    # -- state ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the attitude (the next sample re-initialises from the accelerometer)."""
        p = self.p
        ts = self.ts
        self.q_gyr = (1.0, 0.0, 0.0, 0.0)
        self.q_inc = (1.0, 0.0, 0.0, 0.0)
        self.initialised = False
        self.acc_lp = LowPass3(3, p.tau_acc, ts)
        self.rest_gyr_lp = LowPass3(3, p.rest_tau, ts)
        self.rest_acc_lp = LowPass3(3, p.rest_tau, ts)
        self._bias_every = max(1, int(round(p.bias_update_period / ts)))
        self._acc_n = 0
        self._acc_x = self._acc_y = self._acc_dt = 0.0
        self._acc_g = [0.0, 0.0, 0.0]
        self.rd_lp = LowPass(9, p.tau_acc, ts * self._bias_every)
        self.r_lp = LowPass(9, p.tau_acc, ts * self._bias_every)
        self.rb_lp = LowPass(2, p.tau_acc, ts * self._bias_every)
        self.rest_time = 0.0
        self.rest = False
        self.rest_gyr = (0.0, 0.0, 0.0)
        self._rest_acc = (0.0, 0.0, 0.0)
        self.snaps = 0
        if not hasattr(self, 'bias'):
            self.bias = [0.0, 0.0, 0.0]
            self.scale = [0.0, 0.0, 0.0]
            d6 = [(p.bias_sigma_init * self._deg) ** 2] * 3 + [p.scale_sigma_init ** 2] * 3
            self.P6 = [[d6[i] if i == j else 0.0 for j in range(6)] for i in range(6)]
            s0 = (p.bias_sigma_init * self._deg) ** 2
            self.P = [[s0, 0.0, 0.0], [0.0, s0, 0.0], [0.0, 0.0, s0]]

    def _set_ts(self, ts: float) -> None:
        self.ts = ts
        for f in (self.acc_lp, self.rest_gyr_lp, self.rest_acc_lp):
            f.set_ts(ts)
        self._bias_every = max(1, int(round(self.p.bias_update_period / ts)))
        for f in (self.r_lp, self.rb_lp, self.rd_lp):
            f.set_ts(ts * self._bias_every)

    @property
    def quat(self) -> tuple:
        """Return the sensor-to-earth attitude (w, x, y, z)."""
        return qmul(self.q_inc, self.q_gyr)

    # -- one sample ----------------------------------------------------------------------
    def update(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
               dt: float) -> tuple:
        """Process one sample (rad/s, m/s^2, s since the previous one); return the quaternion."""
        p = self.p
        ts = self.ts
        if abs(dt - ts) > 0.2 * ts:
            self._set_ts(dt)
        if not self.initialised:
            n = math.sqrt(ax * ax + ay * ay + az * az)
            self.q_inc = align_up(ax / n, ay / n, az / n)
            self.q_gyr = (1.0, 0.0, 0.0, 0.0)
            self.initialised = True
        else:
            # Strapdown integration of the bias-corrected rate (exact for a constant rate).
            b = self.bias
            sc = self.scale
            wx = gx - b[0] - sc[0] * gx
            wy = gy - b[1] - sc[1] * gy
            wz = gz - b[2] - sc[2] * gz
            wn = math.sqrt(wx * wx + wy * wy + wz * wz)
            if wn > 1e-12:
                half = 0.5 * wn * dt
                s = math.sin(half) / wn
                self.q_gyr = qnorm(qmul(self.q_gyr, (math.cos(half), s * wx, s * wy, s * wz)))
        self._rest_detection(gx, gy, gz, ax, ay, az, dt)

        # Acceleration in the almost-inertial frame, low-pass filtered there.
        a0, a1, a2 = qrot(self.q_gyr, ax, ay, az)
        lp = self.acc_lp.step(a0, a1, a2)
        if self._snap_on and self.rest_time >= p.rest_snap_time and self.acc_lp.ready \
                and self._turn_rate2(gx, gy, gz) < self._rest_gyr2:
            lp = self._rest_snap(lp)
        # Into the earth frame; correct the inclination so that it points up.
        ex, ey, ez = qrot(self.q_inc, lp[0], lp[1], lp[2])
        n = math.sqrt(ex * ex + ey * ey + ez * ez)
        if n > 1e-9:
            ex, ey, ez = ex / n, ey / n, ez / n
            self.q_inc = qnorm(qmul(align_up(ex, ey, ez), self.q_inc))
        if self._bias_on:
            # Average the corrections over bias_update_period, then one Kalman update.
            self._acc_x += ex
            self._acc_y += ey
            self._acc_dt += dt
            self._acc_n += 1
            ag = self._acc_g
            ag[0] += gx
            ag[1] += gy
            ag[2] += gz
            if self._acc_n >= self._bias_every:
                if p.scale_estimation:
                    n = self._acc_n
                    self._bias_scale_update(self._acc_x, self._acc_y, self._acc_dt,
                                            (ag[0] / n, ag[1] / n, ag[2] / n))
                else:
                    self._bias_update(self._acc_x, self._acc_y, self._acc_dt)
                self._acc_n = 0
                self._acc_x = self._acc_y = self._acc_dt = 0.0
                self._acc_g = [0.0, 0.0, 0.0]
        return qmul(self.q_inc, self.q_gyr)

    def _turn_rate2(self, gx: float, gy: float, gz: float) -> float:
        """Return the squared bias-corrected rate ((rad/s)^2)."""
        b = self.bias
        return (gx - b[0]) ** 2 + (gy - b[1]) ** 2 + (gz - b[2]) ** 2

    def _rest_snap(self, lp: tuple) -> tuple:
        """At rest, restart the acceleration filter from the mean reading if they disagree."""
        m = self._rest_acc
        mi = qrot(self.q_gyr, m[0], m[1], m[2])
        dot = mi[0] * lp[0] + mi[1] * lp[1] + mi[2] * lp[2]
        n2 = (mi[0] ** 2 + mi[1] ** 2 + mi[2] ** 2) * (lp[0] ** 2 + lp[1] ** 2 + lp[2] ** 2)
        n = math.sqrt(n2)
        if n <= 0.0 or dot / n > self._snap_cos:
            return lp
        self.acc_lp.fill(mi)
        self.snaps += 1
        return mi

    def _rest_detection(self, gx: float, gy: float, gz: float, ax: float, ay: float,
                        az: float, dt: float) -> None:
        """
        Count the time the IMU has been still.

        Still: rates and force near their low-pass means, and the mean rate no
        larger than a gyro bias can be (a steady spin is steady too, but its
        rate is motion, not bias).
        """
        g0, g1, g2 = self.rest_gyr_lp.step(gx, gy, gz)
        a0, a1, a2 = self.rest_acc_lp.step(ax, ay, az)
        dg = (gx - g0) ** 2 + (gy - g1) ** 2 + (gz - g2) ** 2
        da = (ax - a0) ** 2 + (ay - a1) ** 2 + (az - a2) ** 2
        if dg < self._rest_gyr2 and da < self._rest_acc2 and \
                g0 * g0 + g1 * g1 + g2 * g2 <= self._rest_mean2:
            self.rest_time += dt
            self.rest = self.rest_time >= self.p.rest_min_time
            self.rest_gyr = (g0, g1, g2)
            self._rest_acc = (a0, a1, a2)
        else:
            self.rest_time = 0.0
            self.rest = False

    def _bias_scale_update(self, ex: float, ey: float, dt: float, g: tuple) -> None:
        """
        Kalman update of gyro bias (rad/s) and scale factors from rest or the correction.

        The gyro error is modelled as ``b + diag(s) w``; its effect on the
        inclination is ``R (b + diag(s) w)``, compared after the same low-pass
        filter as the acceleration with the corrections the accelerometer made.
        ``g``: mean raw rate (rad/s) over the last ``dt`` seconds.
        """
        p = self.p
        deg = self._deg
        b = self.bias
        sc = self.scale
        w, x, y, z = self.quat
        R = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
             2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
             2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
        RD = [R[0] * g[0], R[1] * g[1], R[2] * g[2], R[3] * g[0], R[4] * g[1], R[5] * g[2],
              R[6] * g[0], R[7] * g[1], R[8] * g[2]]
        eb = [b[0] + sc[0] * g[0], b[1] + sc[1] * g[1], b[2] + sc[2] * g[2]]
        rb = [R[0] * eb[0] + R[1] * eb[1] + R[2] * eb[2], R[3] * eb[0] + R[4] * eb[1]
              + R[5] * eb[2]]
        Rf = self.r_lp(R)
        RDf = self.rd_lp(RD)
        rbf = self.rb_lp(rb)
        P = self.P6
        v = (0.1 * deg) ** 2 * dt / p.bias_forgetting_time
        vs = p.scale_sigma_init ** 2 * dt / (10.0 * p.bias_forgetting_time)
        if P[0][0] < (p.bias_sigma_init * deg) ** 2:
            P[0][0] += v
            P[1][1] += v
            P[2][2] += v
        if P[3][3] < p.scale_sigma_init ** 2:
            P[3][3] += vs
            P[4][4] += vs
            P[5][5] += vs
        xs = b + sc
        if self.rest and p.rest_bias:
            # H = [I 0]: P H' is the first three columns of P, H P H' its upper left block
            PHt = [row[:3] for row in P]
            e = [self.rest_gyr[0] - b[0], self.rest_gyr[1] - b[1], self.rest_gyr[2] - b[2]]
            s2 = (p.bias_sigma_rest * deg) ** 2
            wr = s2 * s2 / v + s2
            S = [[P[0][0] + wr, P[0][1], P[0][2]], [P[1][0], P[1][1] + wr, P[1][2]],
                 [P[2][0], P[2][1], P[2][2] + wr]]
        elif p.motion_bias and not self.rest:
            H = (Rf[0:3] + RDf[0:3], Rf[3:6] + RDf[3:6], Rf[6:9] + RDf[6:9])
            hx = [_dot6(h, xs) for h in H]
            e = [-ey / dt + rbf[0] - hx[0], ex / dt + rbf[1] - hx[1], -hx[2]]
            s2 = (p.bias_sigma_motion * deg) ** 2
            wm = s2 * s2 / v + s2
            PHt = [[r0 * h[0] + r1 * h[1] + r2 * h[2] + r3 * h[3] + r4 * h[4] + r5 * h[5]
                    for h in H] for r0, r1, r2, r3, r4, r5 in P]
            # S = H P H' + W (symmetric: the lower triangle mirrors the upper one)
            c0, c1, c2 = zip(*PHt)
            s00, s01, s02 = _dot6(H[0], c0), _dot6(H[0], c1), _dot6(H[0], c2)
            s11, s12, s22 = _dot6(H[1], c1), _dot6(H[1], c2), _dot6(H[2], c2)
            S = [[s00 + wm, s01, s02], [s01, s11 + wm, s12],
                 [s02, s12, s22 + wm / p.bias_vertical_factor]]
        else:
            return
        self._apply_bias_scale_update(xs, e, PHt, S)

    def _apply_bias_scale_update(self, xs: list, e: list, PHt: list, S: list) -> None:
        """
        Apply a Kalman update to bias (rad/s) and scale: state ``xs``, innovation ``e``.

        ``PHt`` is P H' (6 x 3) and ``S`` the innovation covariance H P H' + W (3 x 3).
        """
        p = self.p
        P = self.P6
        clip = p.bias_clip * self._deg
        e = [_clip(ei, clip) for ei in e]
        # K = P H' S^-1 (closed-form inverse of the 3x3 SPD S instead of an LU solve)
        Si = _inv3(S)
        if Si is None:
            return
        (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = Si
        K = [(r0 * a00 + r1 * a10 + r2 * a20, r0 * a01 + r1 * a11 + r2 * a21,
              r0 * a02 + r1 * a12 + r2 * a22) for r0, r1, r2 in PHt]
        e0, e1, e2 = e
        xs = [xi + k0 * e0 + k1 * e1 + k2 * e2 for xi, (k0, k1, k2) in zip(xs, K)]
        # P -= K (P H')' : symmetric, so the upper triangle is computed and mirrored
        for i in range(6):
            k0, k1, k2 = K[i]
            Pi = P[i]
            for j in range(i, 6):
                h0, h1, h2 = PHt[j]
                Pi[j] -= k0 * h0 + k1 * h1 + k2 * h2
                P[j][i] = Pi[j]
        sclip = p.scale_clip
        self.bias = [_clip(xs[0], clip), _clip(xs[1], clip), _clip(xs[2], clip)]
        self.scale = [_clip(xs[3], sclip), _clip(xs[4], sclip), _clip(xs[5], sclip)]

    def _bias_update(self, ex: float, ey: float, dt: float) -> None:
        """
        Kalman update of the gyro bias (3 states, rad/s) from rest or from the correction.

        ``ex``, ``ey``: summed inclination corrections (rad, about earth y and -x) over the
        last ``dt`` seconds.
        """
        p = self.p
        deg = self._deg
        b = self.bias
        w, x, y, z = self.quat
        # Rotation matrix sensor -> earth (rows).
        R = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
             2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
             2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
        rb = [R[0] * b[0] + R[1] * b[1] + R[2] * b[2], R[3] * b[0] + R[4] * b[1] + R[5] * b[2]]
        # The correction acts through the same low-pass filter as the acceleration, so the
        # rotation and the bias's effect are filtered alike before they are compared.
        Rf = self.r_lp(R)
        rbf = self.rb_lp(rb)
        P = self.P
        v = (0.1 * deg) ** 2 * dt / p.bias_forgetting_time
        p0 = (p.bias_sigma_init * deg) ** 2
        if P[0][0] < p0:
            for i in range(3):
                P[i][i] += v
        if self.rest and p.rest_bias:
            H = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
            e = [self.rest_gyr[i] - b[i] for i in range(3)]
            s2 = (p.bias_sigma_rest * deg) ** 2
            wv = [s2 * s2 / v + s2] * 3
        elif p.motion_bias and not self.rest:
            H = Rf
            # Inclination correction per second (rad/s) about earth x and y.
            e = [-ey / dt + rbf[0] - (Rf[0] * b[0] + Rf[1] * b[1] + Rf[2] * b[2]),
                 ex / dt + rbf[1] - (Rf[3] * b[0] + Rf[4] * b[1] + Rf[5] * b[2]),
                 -(Rf[6] * b[0] + Rf[7] * b[1] + Rf[8] * b[2])]
            s2 = (p.bias_sigma_motion * deg) ** 2
            wm = s2 * s2 / v + s2
            wv = [wm, wm, wm / p.bias_vertical_factor]
        else:
            return
        clip = p.bias_clip * deg
        e = [min(clip, max(-clip, ei)) for ei in e]
        # K = P H' (W + H P H')^-1 ; b += K e ; P -= K H P
        PHt = [[P[i][0] * H[j * 3] + P[i][1] * H[j * 3 + 1] + P[i][2] * H[j * 3 + 2]
                for j in range(3)] for i in range(3)]
        S = [[H[i * 3] * PHt[0][j] + H[i * 3 + 1] * PHt[1][j] + H[i * 3 + 2] * PHt[2][j]
              + (wv[i] if i == j else 0.0) for j in range(3)] for i in range(3)]
        Si = _inv3(S)
        if Si is None:
            return
        K = [[PHt[i][0] * Si[0][j] + PHt[i][1] * Si[1][j] + PHt[i][2] * Si[2][j]
              for j in range(3)] for i in range(3)]
        for i in range(3):
            b[i] += K[i][0] * e[0] + K[i][1] * e[1] + K[i][2] * e[2]
            b[i] = min(clip, max(-clip, b[i]))
        # H P = (P H')' for a symmetric P, so K H P = K PHt'
        self.P = [[P[i][j] - (K[i][0] * PHt[j][0] + K[i][1] * PHt[j][1] + K[i][2] * PHt[j][2])
                   for j in range(3)] for i in range(3)]


def _dot6(a: list, b: list) -> float:
    """Return the dot product of two 6-vectors."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]


def _clip(v: float, lim: float) -> float:
    """Return ``v`` clipped to [-lim, lim] (NaN stays NaN, like numpy.clip)."""
    return -lim if v < -lim else (lim if v > lim else v)


def _inv3(m: list) -> Optional[list]:
    """Return the inverse of a 3x3 matrix (cofactors), None when singular or not finite."""
    a, b, c = m[0]
    d, e, f = m[1]
    g, h, i = m[2]
    A = e * i - f * h
    B = -(d * i - f * g)
    C = d * h - e * g
    det = a * A + b * B + c * C
    if det == 0.0 or not math.isfinite(det):
        return None
    r = 1.0 / det
    return [[A * r, -(b * i - c * h) * r, (b * f - c * e) * r],
            [B * r, (a * i - c * g) * r, -(a * f - c * d) * r],
            [C * r, -(a * h - b * g) * r, (a * e - b * d) * r]]


class ImprovedTiltEstimator(TiltEstimatorBase):
    """
    Tilt and fall alert from the whole-sphere attitude estimator (``mode: improved``).

    Implements the Estimator protocol; the attitude is that of
    :class:`AttitudeEstimator` (IMU frame) turned into base_link by the
    mounting, the fall decision the tilt of base_link z from up.
    """

    mode = 'improved'

    def _new_filter(self) -> None:
        """Create the attitude filter for the nominal sampling period."""
        self._filter = AttitudeEstimator(self.params.improved, self.ts)

    def _restart_filter(self) -> None:
        """Restart the attitude from the next sample (gyro bias and scale are kept)."""
        self._filter.reset()

    def _estimate(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
                  dt: float) -> tuple:
        """Run the attitude filter on one sample (see :meth:`TiltEstimatorBase._estimate`)."""
        f = self._filter
        q_imu = f.update(gx, gy, gz, ax, ay, az, dt)
        # base_link -> earth = (imu -> earth) * (base_link -> imu)
        q = positive_w(qmul(q_imu, self._mount_conj))
        w, x, y, z = q
        c = 1.0 - 2.0 * (x * x + y * y)   # tilt_of(q), inlined
        tilt = math.acos(-1.0 if c < -1.0 else (1.0 if c > 1.0 else c))
        roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
        return q, tilt, roll, pitch, tuple(f.bias), f.rest, tilt

    def _gyro_scale(self) -> Optional[tuple]:
        """Return the gyro scale-factor errors (relative, IMU axes)."""
        return tuple(self._filter.scale)

    def _rest_snaps(self) -> int:
        """Return how often the acceleration filter restarted from the mean reading at rest."""
        return self._filter.snaps
