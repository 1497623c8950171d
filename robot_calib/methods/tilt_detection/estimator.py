# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Tilt estimation and fall detection from a 6D IMU (seed 002).

Two estimators share one interface (:class:`TiltEstimator`):

``seed``
    The seed's per-axis two-state Kalman filter, exactly as seed 002 writes it:
    state ``X = [angle, gyro_bias]`` for roll and for pitch, the gyro rate as the
    control input, the accelerometer roll/pitch as the observation,
    ``A = [[1, -dt], [0, 1]]``, ``B = [dt, 0]'``, ``H = [1, 0]``,
    ``Q = diag(Q_angle, Q_gyro)``, scalar ``R``. The fall decision is the seed's
    "angle outside a preset range": ``|roll| > fall_angle or |pitch| > fall_angle``.

``improved`` (the default)
    A whole-sphere attitude estimator (unit quaternions only, no Euler angles,
    so a robot on its side or back is an ordinary state). The structure follows
    the ideas published for VQF (Laidig & Seel, *Information Fusion* 2023):
    the gyroscope is integrated into an almost-inertial frame ``I``; the
    accelerometer is rotated into ``I`` and low-pass filtered there (linear
    accelerations of a robot that does not drift away average out, gravity
    does not); a separate inclination correction ``q_inc`` (``I`` -> earth)
    makes the filtered acceleration point up. The correction is therefore
    blind to bumps, vibration and braking shorter than the filter time
    constant. The gyro bias is estimated by a small Kalman filter, from the
    mean rate while the IMU is at rest and, in motion, from the inclination
    corrections the accelerometer asks for. Beyond VQF, the same Kalman
    filter also estimates the three gyro scale factors (MEMS gyros carry
    0.5-2 % sensitivity errors; while turning fast they, not the bias,
    dominate the drift): the gyro error is modelled as ``b + diag(s) w``.
    Written from the published description, not from VQF's code.

Fall detection (:class:`FallDetector`) uses the angle between the body z axis
(``base_link`` after the mounting rotation) and world up, with a threshold,
a minimum duration, hysteresis (``clear_angle``) and a clear time.

Units: time s, rates rad/s, specific force m/s^2, angles rad. Quaternions are
``(w, x, y, z)``, sensor-to-earth.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Optional

import numpy as np

from robot_calib.core.params import param

GRAVITY = 9.80665
"""Standard gravity (m/s^2)."""

CLEAR_MARGIN = 0.0873
"""Default hysteresis between ``fall_angle`` and ``clear_angle`` (rad, 5 deg)."""


# --------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SeedFilterParams:
    """Noise settings of the seed's per-axis Kalman filter (seed 002)."""

    q_angle: float = param(0.001, 'rad^2', 'Process noise of the angle state per step '
                           '(seed: Q_angle)', minimum=0.0)
    q_gyro: float = param(0.0005, '(rad/s)^2', 'Process noise of the gyro bias state per step '
                          '(seed: Q_gyro)', minimum=0.0)
    r_angle: float = param(0.03, 'rad^2', 'Variance of the accelerometer angle observation '
                           '(seed: R)', minimum=1e-12)


@dataclass(frozen=True)
class ImprovedFilterParams:
    """Settings of the whole-sphere attitude estimator (physically motivated defaults)."""

    tau_acc: float = param(3.0, 's', 'Time constant of the low-pass filter of the acceleration '
                           'in the almost-inertial frame (longer: less trust in the '
                           'accelerometer during linear acceleration)', minimum=0.01)
    bias_sigma_init: float = param(0.5, 'deg/s', 'Initial gyro bias uncertainty (1 sigma)',
                                   minimum=0.0)
    bias_forgetting_time: float = param(100.0, 's', 'Time in which the bias uncertainty grows '
                                        'by 0.1 deg/s (bias random walk)', minimum=1.0)
    bias_clip: float = param(2.0, 'deg/s', 'Largest gyro bias the estimator accepts',
                             minimum=0.0)
    bias_sigma_motion: float = param(0.1, 'deg/s', 'Noise of the bias measurement made from '
                                     'inclination corrections in motion', minimum=1e-6)
    bias_vertical_factor: float = param(1e-4, '', 'Relative weight of the bias about the '
                                        'vertical axis in motion (unobservable from gravity)',
                                        minimum=1e-12)
    bias_sigma_rest: float = param(0.03, 'deg/s', 'Noise of the bias measurement at rest',
                                   minimum=1e-6)
    bias_update_period: float = param(0.05, 's', 'Period of the gyro bias Kalman update (the '
                                      'corrections in between are averaged)', minimum=0.0)
    scale_estimation: bool = param(True, '', 'Also estimate the gyro scale factors in motion '
                                   '(from the inclination corrections while turning)')
    scale_sigma_init: float = param(0.01, '', 'Initial gyro scale-factor uncertainty (1 sigma, '
                                    'relative)', minimum=0.0)
    scale_clip: float = param(0.05, '', 'Largest relative gyro scale error accepted',
                              minimum=0.0)
    motion_bias: bool = param(True, '', 'Estimate the gyro bias in motion')
    rest_bias: bool = param(True, '', 'Estimate the gyro bias at rest')
    rest_min_time: float = param(1.5, 's', 'Time the IMU must be still to count as at rest',
                                 minimum=0.0)
    rest_tau: float = param(0.5, 's', 'Time constant of the rest-detection low-pass filters',
                            minimum=0.01)
    rest_gyro_threshold: float = param(2.0, 'deg/s', 'Largest gyro deviation from its mean at '
                                       'rest', minimum=0.0)
    rest_accel_threshold: float = param(0.5, 'm/s^2', 'Largest accelerometer deviation from '
                                        'its mean at rest', minimum=0.0)
    rest_snap_angle: float = param(5.0, 'deg', 'When the IMU is still and the filtered '
                                   'acceleration and the mean accelerometer reading disagree by '
                                   'more than this, the filter restarts from the mean (fast '
                                   'recovery after gyro saturation or a gap; 0: off)',
                                   minimum=0.0)
    rest_snap_time: float = param(0.5, 's', 'How long the IMU must be still (and not '
                                  'turning) before such a restart', minimum=0.0)


@dataclass(frozen=True)
class TiltParams:
    """Parameters of ``tilt_detection`` (names are the node's ROS parameters)."""

    mode: str = param('improved', '', "Estimator: 'improved' (whole-sphere attitude filter) "
                      "or 'seed' (the seed's per-axis Kalman filter)",
                      choices=('improved', 'seed'))
    fall_angle: float = param(math.pi / 4, 'rad', 'Tilt from upright that raises the fall '
                              'alert', minimum=0.0, maximum=math.pi)
    fall_min_duration: float = param(0.02, 's', 'How long the tilt must exceed fall_angle '
                                     'before the alert is raised', minimum=0.0)
    clear_angle: float = param(-1.0, 'rad', 'Tilt below which the robot counts as upright '
                               'again; negative: fall_angle - 0.0873', maximum=math.pi)
    clear_duration: float = param(1.0, 's', 'Upright time that clears the alert', minimum=0.0)
    mounting_rpy: list = param([0.0, 0.0, 0.0], 'rad', 'Rotation of the IMU frame in base_link '
                               '(roll, pitch, yaw); replaced by /tf_static when present', length=3)
    use_tf_static: bool = param(True, '', 'Take the IMU mounting rotation from /tf_static '
                                '(base_link -> IMU frame) when available')
    base_frame: str = param('base_link', '', 'Robot body frame the tilt refers to')
    max_accel: float = param(16.0 * GRAVITY, 'm/s^2', 'Specific-force norm above which a sample '
                             'is rejected (sensor saturation or garbage)', minimum=0.0)
    max_gyro: float = param(35.0, 'rad/s', 'Rate norm above which a sample is rejected',
                            minimum=0.0)
    max_dt: float = param(0.5, 's', 'Gap between samples above which the filter restarts from '
                          'the accelerometer', minimum=0.0)
    stop_on_alert: bool = param(False, '', 'Publish a zero-velocity cmd_vel while the fall '
                                'alert is raised')
    diagnostics_period: float = param(1.0, 's', 'Period of /diagnostics messages (0: every '
                                      'sample)', minimum=0.0)
    seed: SeedFilterParams = field(default_factory=SeedFilterParams)
    improved: ImprovedFilterParams = field(default_factory=ImprovedFilterParams)

    def __post_init__(self) -> None:
        """Check the values that depend on each other."""
        if len(self.mounting_rpy) != 3:
            raise ValueError('mounting_rpy needs 3 values (roll, pitch, yaw in rad)')
        if self.effective_clear_angle() > self.fall_angle:
            raise ValueError('clear_angle must not exceed fall_angle')

    def effective_clear_angle(self) -> float:
        """Return clear_angle (rad), resolving a negative value to fall_angle - 0.0873."""
        if self.clear_angle < 0.0:
            return max(0.0, self.fall_angle - CLEAR_MARGIN)
        return self.clear_angle


# --------------------------------------------------------------------------------------------
# Small quaternion helpers on Python floats (fast for one sample at a time)
# --------------------------------------------------------------------------------------------
def _qmul(a: tuple, b: tuple) -> tuple:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def _qrot(q: tuple, x: float, y: float, z: float) -> tuple:
    """Rotate (x, y, z) by unit quaternion q: R(q) v."""
    w, a, b, c = q
    # t = 2 * (q_vec x v); v' = v + w t + q_vec x t
    tx = 2.0 * (b * z - c * y)
    ty = 2.0 * (c * x - a * z)
    tz = 2.0 * (a * y - b * x)
    return (x + w * tx + b * tz - c * ty,
            y + w * ty + c * tx - a * tz,
            z + w * tz + a * ty - b * tx)


def _qnorm(q: tuple) -> tuple:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _align_up(x: float, y: float, z: float) -> tuple:
    """Return the smallest rotation taking unit vector (x, y, z) to (0, 0, 1)."""
    if z > -0.999999:
        s = math.sqrt(2.0 * (1.0 + z))
        return (0.5 * s, y / s, -x / s, 0.0)
    return (0.0, 1.0, 0.0, 0.0)  # upside down: half turn about x


def quat_from_rpy_tuple(roll: float, pitch: float, yaw: float) -> tuple:
    """Return (w, x, y, z) of R = Rz(yaw) Ry(pitch) Rx(roll) (rad) as a tuple."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def tilt_of(q: tuple) -> float:
    """Return the tilt (rad, [0, pi]) of sensor-to-earth quaternion q: body z vs world up."""
    c = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])
    return math.acos(-1.0 if c < -1.0 else (1.0 if c > 1.0 else c))


def _butter2(tau: float, ts: float) -> tuple:
    """
    Return (b0, b1, b2, a1, a2) of a 2nd-order Butterworth low-pass, fc = sqrt(2)/(2 pi tau).

    Bilinear transform with pre-warping (Laidig & Seel 2023 choose the cut-off
    this way so that the filter's step response has time constant ``tau``).
    """
    fc = math.sqrt(2.0) / (2.0 * math.pi * tau)
    c = math.tan(math.pi * min(fc * ts, 0.49))
    d = c * c + math.sqrt(2.0) * c + 1.0
    b0 = c * c / d
    return (b0, 2.0 * b0, b0, 2.0 * (c * c - 1.0) / d, (1.0 - math.sqrt(2.0) * c + c * c) / d)


class _LowPass:
    """
    A bank of 2nd-order Butterworth low-pass filters (direct form I).

    Direct form I keeps past inputs and outputs as its state, so a new
    sampling period changes the coefficients without a jump. Until
    ``tau`` seconds of samples have been seen, the output is the running mean
    of the inputs (a fast, unbiased start).
    """

    __slots__ = ('n', 'tau', 'coef', 'x1', 'x2', 'y1', 'y2', 'count', 'sum', 'init_n', 'ready')

    def __init__(self, n: int, tau: float, ts: float):
        self.n = n
        self.tau = tau
        self.coef = _butter2(tau, ts)
        self.count = 0
        self.sum = [0.0] * n
        self.init_n = max(1, int(round(tau / ts)))
        self.ready = False

    def set_ts(self, ts: float) -> None:
        """Recompute the coefficients for sampling period ``ts`` (s)."""
        self.coef = _butter2(self.tau, ts)
        if not self.ready:
            self.init_n = max(1, int(round(self.tau / ts)))

    def fill(self, value: list) -> None:
        """Set the filter to the steady state of a constant input ``value``."""
        self.x1 = list(value)
        self.x2 = list(value)
        self.y1 = list(value)
        self.y2 = list(value)
        self.ready = True

    def __call__(self, x: list) -> list:
        n = self.n
        if not self.ready:
            self.count += 1
            s = self.sum
            for i in range(n):
                s[i] += x[i]
            mean = [v / self.count for v in s]
            if self.count >= self.init_n:
                self.x1 = list(mean)
                self.x2 = list(mean)
                self.y1 = list(mean)
                self.y2 = list(mean)
                self.ready = True
            return mean
        b0, b1, b2, a1, a2 = self.coef
        x1 = self.x1
        x2 = self.x2
        y1 = self.y1
        y2 = self.y2
        y = [0.0] * n
        for i in range(n):
            xi = x[i]
            yi = b0 * xi + b1 * x1[i] + b2 * x2[i] - a1 * y1[i] - a2 * y2[i]
            x2[i] = x1[i]
            x1[i] = xi
            y2[i] = y1[i]
            y1[i] = yi
            y[i] = yi
        return y


class _LowPass3(_LowPass):
    """The 3-channel case of :class:`_LowPass`, unrolled (it runs several times per sample)."""

    __slots__ = ()

    def __call__(self, x: list) -> list:
        if not self.ready:
            return _LowPass.__call__(self, x)
        b0, b1, b2, a1, a2 = self.coef
        x1 = self.x1
        x2 = self.x2
        y1 = self.y1
        y2 = self.y2
        u0, u1, u2 = x[0], x[1], x[2]
        v0 = b0 * u0 + b1 * x1[0] + b2 * x2[0] - a1 * y1[0] - a2 * y2[0]
        v1 = b0 * u1 + b1 * x1[1] + b2 * x2[1] - a1 * y1[1] - a2 * y2[1]
        v2 = b0 * u2 + b1 * x1[2] + b2 * x2[2] - a1 * y1[2] - a2 * y2[2]
        self.x2 = x1
        self.x1 = [u0, u1, u2]
        self.y2 = y1
        self.y1 = [v0, v1, v2]
        return [v0, v1, v2]


# --------------------------------------------------------------------------------------------
# Seed-faithful estimator
# --------------------------------------------------------------------------------------------
class SeedKalmanAxis:
    """One axis of the seed's 2-state Kalman filter (seed 002), state [angle rad, bias rad/s]."""

    def __init__(self, q_angle: float, q_gyro: float, r_angle: float, angle0: float = 0.0):
        """Create the filter with the seed's noise values and an initial angle (rad)."""
        self.q_angle = q_angle
        self.q_gyro = q_gyro
        self.r = r_angle
        self.x = np.array([angle0, 0.0])
        self.P = np.zeros((2, 2))

    def step(self, rate: float, z_angle: float, dt: float) -> float:
        """
        Run one predict/update: gyro rate (rad/s), accel angle (rad), dt (s); return angle.

        The matrix products are written out for A = [[1, -dt], [0, 1]],
        B = [dt, 0]', H = [1, 0], Q = diag(Q_angle, Q_gyro).
        """
        angle, bias = float(self.x[0]), float(self.x[1])
        (p00, p01), (p10, p11) = self.P
        # seed 002, X(k|k-1) = A X(k-1|k-1) + B U(k)
        angle = angle - dt * bias + dt * rate
        # seed 002, P(k|k-1) = A P A' + Q
        q00 = p00 - dt * (p10 + p01) + dt * dt * p11 + self.q_angle
        q01 = p01 - dt * p11
        q10 = p10 - dt * p11
        q11 = p11 + self.q_gyro
        # seed 002, K = P H' / (H P H' + R)
        s = q00 + self.r
        k0 = q00 / s
        k1 = q10 / s
        # seed 002, X(k|k) = X(k|k-1) + K (Z(k) - H X(k|k-1))
        innov = z_angle - angle
        angle += k0 * innov
        bias += k1 * innov
        # seed 002, P(k|k) = (I - K H) P(k|k-1)
        self.P = np.array([[q00 - k0 * q00, q01 - k0 * q01],
                           [q10 - k1 * q00, q11 - k1 * q01]])
        self.x = np.array([angle, bias])
        return angle


def accel_roll_pitch(ax: float, ay: float, az: float) -> tuple:
    """
    Return the accelerometer roll and pitch (rad) as the seed uses them as observations.

    roll = atan2(a_y, a_z), pitch = atan2(-a_x, sqrt(a_y^2 + a_z^2)) (REP-103, z up).
    """
    return math.atan2(ay, az), math.atan2(-ax, math.sqrt(ay * ay + az * az))


class SeedEstimator:
    """The seed's roll and pitch Kalman filters; the attitude is Rx(roll) Ry(pitch), yaw 0."""

    def __init__(self, p: SeedFilterParams):
        """Create the two axis filters (initialised from the first accelerometer sample)."""
        self.p = p
        self.roll: Optional[SeedKalmanAxis] = None
        self.pitch: Optional[SeedKalmanAxis] = None

    def reset(self) -> None:
        """Restart from the next accelerometer sample."""
        self.roll = None
        self.pitch = None

    def update(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
               dt: float) -> tuple:
        """Return (quaternion, roll, pitch) after one sample; rates rad/s, accel m/s^2, dt s."""
        r_acc, p_acc = accel_roll_pitch(ax, ay, az)
        if self.roll is None:
            p = self.p
            self.roll = SeedKalmanAxis(p.q_angle, p.q_gyro, p.r_angle, r_acc)
            self.pitch = SeedKalmanAxis(p.q_angle, p.q_gyro, p.r_angle, p_acc)
            roll, pitch = r_acc, p_acc
        else:
            # The seed feeds each axis its own gyro rate (small-angle Euler rates).
            roll = self.roll.step(gx, r_acc, dt)
            pitch = self.pitch.step(gy, p_acc, dt)
        return quat_from_rpy_tuple(roll, pitch, 0.0), roll, pitch


# --------------------------------------------------------------------------------------------
# Improved estimator
# --------------------------------------------------------------------------------------------
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
        self._still_rate2 = (p.rest_gyro_threshold * self._deg) ** 2
        self.reset()

    # -- state ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the attitude (the next sample re-initialises from the accelerometer)."""
        p = self.p
        ts = self.ts
        self.q_gyr = (1.0, 0.0, 0.0, 0.0)
        self.q_inc = (1.0, 0.0, 0.0, 0.0)
        self.initialised = False
        self.acc_lp = _LowPass3(3, p.tau_acc, ts)
        self.rest_gyr_lp = _LowPass3(3, p.rest_tau, ts)
        self.rest_acc_lp = _LowPass3(3, p.rest_tau, ts)
        self._bias_every = max(1, int(round(p.bias_update_period / ts)))
        self._acc_n = 0
        self._acc_x = self._acc_y = self._acc_dt = 0.0
        self._acc_g = [0.0, 0.0, 0.0]
        self.rd_lp = _LowPass(9, p.tau_acc, ts * self._bias_every)
        self.r_lp = _LowPass(9, p.tau_acc, ts * self._bias_every)
        self.rb_lp = _LowPass(2, p.tau_acc, ts * self._bias_every)
        self.rest_time = 0.0
        self.rest = False
        self.rest_gyr = (0.0, 0.0, 0.0)
        self._rest_acc = (0.0, 0.0, 0.0)
        self.snaps = 0
        if not hasattr(self, 'bias'):
            self.bias = [0.0, 0.0, 0.0]
            self.scale = [0.0, 0.0, 0.0]
            self.P6 = np.diag([(p.bias_sigma_init * self._deg) ** 2] * 3
                              + [p.scale_sigma_init ** 2] * 3)
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
        return _qmul(self.q_inc, self.q_gyr)

    # -- one sample ----------------------------------------------------------------------
    def update(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
               dt: float) -> tuple:
        """Process one sample (rad/s, m/s^2, s since the previous one); return the quaternion."""
        p = self.p
        if abs(dt - self.ts) > 0.2 * self.ts:
            self._set_ts(dt)
        if not self.initialised:
            n = math.sqrt(ax * ax + ay * ay + az * az)
            self.q_inc = _align_up(ax / n, ay / n, az / n)
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
                self.q_gyr = _qnorm(_qmul(self.q_gyr, (math.cos(half), s * wx, s * wy, s * wz)))
        self._rest_detection(gx, gy, gz, ax, ay, az, dt)

        # Acceleration in the almost-inertial frame, low-pass filtered there.
        a_i = _qrot(self.q_gyr, ax, ay, az)
        lp = self.acc_lp(a_i)
        if p.rest_snap_angle > 0.0 and self.rest_time >= p.rest_snap_time \
                and self.acc_lp.ready and self._turn_rate2(gx, gy, gz) < self._still_rate2:
            lp = self._rest_snap(lp)
        # Into the earth frame; correct the inclination so that it points up.
        ex, ey, ez = _qrot(self.q_inc, lp[0], lp[1], lp[2])
        n = math.sqrt(ex * ex + ey * ey + ez * ez)
        if n > 1e-9:
            ex, ey, ez = ex / n, ey / n, ez / n
            self.q_inc = _qnorm(_qmul(_align_up(ex, ey, ez), self.q_inc))
        if p.motion_bias or p.rest_bias:
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
        return self.quat

    def _turn_rate2(self, gx: float, gy: float, gz: float) -> float:
        """Return the squared bias-corrected rate ((rad/s)^2)."""
        b = self.bias
        return (gx - b[0]) ** 2 + (gy - b[1]) ** 2 + (gz - b[2]) ** 2

    def _rest_snap(self, lp: list) -> list:
        """At rest, restart the acceleration filter from the mean reading if they disagree."""
        m = self._rest_acc
        mi = _qrot(self.q_gyr, m[0], m[1], m[2])
        dot = mi[0] * lp[0] + mi[1] * lp[1] + mi[2] * lp[2]
        n2 = (mi[0] ** 2 + mi[1] ** 2 + mi[2] ** 2) * (lp[0] ** 2 + lp[1] ** 2 + lp[2] ** 2)
        n = math.sqrt(n2)
        if n <= 0.0 or dot / n > math.cos(self.p.rest_snap_angle * self._deg):
            return lp
        self.acc_lp.fill(list(mi))
        self.snaps += 1
        return list(mi)

    def _rest_detection(self, gx: float, gy: float, gz: float, ax: float, ay: float,
                        az: float, dt: float) -> None:
        p = self.p
        g = self.rest_gyr_lp([gx, gy, gz])
        a = self.rest_acc_lp([ax, ay, az])
        dg = (gx - g[0]) ** 2 + (gy - g[1]) ** 2 + (gz - g[2]) ** 2
        da = (ax - a[0]) ** 2 + (ay - a[1]) ** 2 + (az - a[2]) ** 2
        th_g = p.rest_gyro_threshold * self._deg
        if dg < th_g * th_g and da < p.rest_accel_threshold ** 2:
            self.rest_time += dt
            self.rest = self.rest_time >= p.rest_min_time
            self.rest_gyr = (g[0], g[1], g[2])
            self._rest_acc = (a[0], a[1], a[2])
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
        if P[0, 0] < (p.bias_sigma_init * deg) ** 2:
            P[0, 0] += v
            P[1, 1] += v
            P[2, 2] += v
        if P[3, 3] < p.scale_sigma_init ** 2:
            P[3, 3] += vs
            P[4, 4] += vs
            P[5, 5] += vs
        xs = np.array(b + sc)
        if self.rest and p.rest_bias:
            H = np.hstack((np.eye(3), np.zeros((3, 3))))
            e = np.array([self.rest_gyr[i] - b[i] for i in range(3)])
            s2 = (p.bias_sigma_rest * deg) ** 2
            W = np.diag([s2 * s2 / v + s2] * 3)
        elif p.motion_bias and not self.rest:
            H = np.hstack((np.array(Rf).reshape(3, 3), np.array(RDf).reshape(3, 3)))
            hx = H @ xs
            e = np.array([-ey / dt + rbf[0] - hx[0], ex / dt + rbf[1] - hx[1], -hx[2]])
            s2 = (p.bias_sigma_motion * deg) ** 2
            wm = s2 * s2 / v + s2
            W = np.diag([wm, wm, wm / p.bias_vertical_factor])
        else:
            return
        clip = p.bias_clip * deg
        e = np.clip(e, -clip, clip)
        PHt = P @ H.T
        S = H @ PHt + W
        try:
            K = np.linalg.solve(S, PHt.T).T
        except np.linalg.LinAlgError:
            return
        xs = xs + K @ e
        xs[:3] = np.clip(xs[:3], -clip, clip)
        xs[3:] = np.clip(xs[3:], -p.scale_clip, p.scale_clip)
        P = P - K @ PHt.T
        self.P6 = 0.5 * (P + P.T)   # keep it symmetric over hours of updates
        self.bias = [float(v) for v in xs[:3]]
        self.scale = [float(v) for v in xs[3:]]

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


def _inv3(m: list) -> Optional[list]:
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


# --------------------------------------------------------------------------------------------
# Fall detector
# --------------------------------------------------------------------------------------------
class FallDetector:
    """
    Latched fall alert with threshold, minimum duration, hysteresis and clear time.

    Raised when the tilt (rad) stays above ``fall_angle`` for ``min_duration``
    seconds; cleared when it stays below ``clear_angle`` for ``clear_duration``.
    """

    def __init__(self, fall_angle: float, min_duration: float, clear_angle: float,
                 clear_duration: float):
        """Create the detector (angles rad, durations s)."""
        self.fall_angle = fall_angle
        self.min_duration = min_duration
        self.clear_angle = clear_angle
        self.clear_duration = clear_duration
        self.alert = False
        self._above_since: Optional[float] = None
        self._below_since: Optional[float] = None
        self.episodes = 0
        self.last_change_t: Optional[float] = None

    def update(self, t: float, tilt: float) -> Optional[bool]:
        """Feed the tilt (rad) at time ``t`` (s); return the new alert state when it changes."""
        if not self.alert:
            if tilt > self.fall_angle:
                if self._above_since is None:
                    self._above_since = t
                if t - self._above_since >= self.min_duration - 1e-9:
                    self.alert = True
                    self._below_since = None
                    self.episodes += 1
                    self.last_change_t = t
                    return True
            else:
                self._above_since = None
            return None
        if tilt < self.clear_angle:
            if self._below_since is None:
                self._below_since = t
            if t - self._below_since >= self.clear_duration - 1e-9:
                self.alert = False
                self._above_since = None
                self.last_change_t = t
                return False
        else:
            self._below_since = None
        return None

    def interrupt(self) -> None:
        """Forget partial timing (after a gap or a filter restart); the alert itself stays."""
        self._above_since = None
        self._below_since = None


# --------------------------------------------------------------------------------------------
# The method: estimator + detector
# --------------------------------------------------------------------------------------------
@dataclass
class TiltState:
    """
    The result of one sample.

    ``quat`` is base_link-to-earth (w, x, y, z; yaw not meaningful), ``tilt``
    the angle between base_link z and up (rad), ``roll``/``pitch`` (rad),
    ``alert`` the latched fall alert, ``changed`` True when the alert changed
    on this sample, ``bias`` the gyro bias estimate (rad/s, IMU frame).
    """

    t: float
    quat: tuple
    tilt: float
    alert: bool
    changed: bool = False
    roll: float = 0.0
    pitch: float = 0.0
    bias: tuple = (0.0, 0.0, 0.0)
    rest: bool = False


class TiltEstimator:
    """
    Streaming tilt estimation and fall detection; :meth:`update` per sample, :func:`run` batch.

    The caller validates samples (finite, in range, increasing stamps); gaps
    longer than ``max_dt`` restart the attitude filter from the accelerometer.
    """

    def __init__(self, params: Optional[TiltParams] = None, ts: float = 0.005):
        """Create the estimator with ``params`` and a nominal sampling period ``ts`` (s)."""
        self.params = params if params is not None else TiltParams()
        p = self.params
        self.mount = quat_from_rpy_tuple(*p.mounting_rpy)   # IMU frame in base_link
        self.detector = FallDetector(p.fall_angle, p.fall_min_duration,
                                     p.effective_clear_angle(), p.clear_duration)
        self.ts = ts
        self.last_t: Optional[float] = None
        self.restarts = 0
        self.max_tilt = 0.0
        if p.mode == 'seed':
            self.seed = SeedEstimator(p.seed)
            self.att = None
        else:
            self.seed = None
            self.att = AttitudeEstimator(p.improved, ts)

    def set_mounting(self, q_base_imu: Any) -> None:
        """Set the IMU mounting rotation: quaternion (w, x, y, z) of the IMU frame in base_link."""
        q = tuple(float(v) for v in q_base_imu)
        self.mount = _qnorm(q)

    def reset(self) -> None:
        """Restart the attitude filter from the next sample (the alert state is kept)."""
        if self.att is not None:
            self.att.reset()
        else:
            self.seed.reset()
        self.detector.interrupt()
        self.last_t = None
        self.restarts += 1

    def update(self, t: float, gyro: Any, accel: Any) -> TiltState:
        """Process one IMU sample: time (s), gyro (rad/s) and specific force (m/s^2), IMU frame."""
        gx, gy, gz = float(gyro[0]), float(gyro[1]), float(gyro[2])
        ax, ay, az = float(accel[0]), float(accel[1]), float(accel[2])
        dt = self.ts if self.last_t is None else t - self.last_t
        if dt > self.params.max_dt:
            self.reset()
            dt = self.ts
        self.last_t = t
        m = self.mount
        roll = pitch = 0.0
        if self.att is not None:
            q_imu = self.att.update(gx, gy, gz, ax, ay, az, dt)
            # base_link -> earth = (imu -> earth) * (base_link -> imu)
            q = _qmul(q_imu, (m[0], -m[1], -m[2], -m[3]))
            bias = tuple(self.att.bias)
            rest = self.att.rest
        else:
            # The seed's filter works in the body frame: rotate the measurements first.
            gx, gy, gz = _qrot(m, gx, gy, gz)
            ax, ay, az = _qrot(m, ax, ay, az)
            q, roll, pitch = self.seed.update(gx, gy, gz, ax, ay, az, dt)
            bias = (self.seed.roll.x[1], self.seed.pitch.x[1], 0.0)
            rest = False
        if q[0] < 0.0:
            q = (-q[0], -q[1], -q[2], -q[3])
        tilt = tilt_of(q)
        if self.att is not None:
            w, x, y, z = q
            roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
            pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
            decision = tilt
        else:
            # seed 002: fallen when an angle leaves the preset range
            decision = max(abs(roll), abs(pitch))
        if decision > self.max_tilt:
            self.max_tilt = decision
        changed = self.detector.update(t, decision)
        return TiltState(t, q, tilt, self.detector.alert, changed is not None, roll, pitch,
                         bias, rest)


def run(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray,
        params: Optional[TiltParams] = None) -> dict[str, np.ndarray]:
    """
    Run the estimator over a whole recording (batch API, causal).

    :param t: sample times (s), shape (N,)
    :param gyro: rates (rad/s), shape (N, 3), IMU frame
    :param accel: specific force (m/s^2), shape (N, 3), IMU frame
    :param params: parameters (defaults when None)
    :return: ``quat`` (N, 4) base_link-to-earth (w, x, y, z), ``tilt`` (N,) rad,
        ``alert`` (N,) bool, ``bias`` (N, 3) rad/s
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    ts = float(np.median(np.diff(t))) if n > 1 else 0.005
    est = TiltEstimator(params, ts)
    quat = np.empty((n, 4))
    tilt = np.empty(n)
    alert = np.zeros(n, dtype=bool)
    bias = np.empty((n, 3))
    g = np.asarray(gyro, dtype=float).tolist()
    a = np.asarray(accel, dtype=float).tolist()
    tl = t.tolist()
    for k in range(n):
        s = est.update(tl[k], g[k], a[k])
        quat[k] = s.quat
        tilt[k] = s.tilt
        alert[k] = s.alert
        bias[k] = s.bias
    return {'quat': quat, 'tilt': tilt, 'alert': alert, 'bias': bias}
