# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The improved fusion filter (``mode: improved``, the default): an error-aware planar EKF.

State ``[x, y, yaw, v, b_g, b_a, k_w, k_v]``: pose (m, m, rad), forward speed
(m/s), gyro z bias (rad/s), forward accelerometer bias (m/s^2), the odometry
yaw-rate scale (a skid-steer or track-width error, dimensionless) and the
odometry yaw rate per unit speed (a left/right wheel radius mismatch, rad/m).
The IMU (gyro z and forward specific force, rotated into ``base_link`` by the
mounting extrinsic from a parameter, ``/tf_static`` or, failing both, the
gravity direction: :mod:`.frontend`) drives the prediction, with gravity
taken out of the forward force on slopes (:mod:`.gravity`); the wheel
odometry's forward speed and yaw rate are scalar observations, each gated by
its innovation (chi-square, 1 dof) so wheel slip and outliers are rejected
and counted. A stationary robot (wheels exactly still) gives a zero-velocity
update that pins the gyro bias. A holonomic robot's odometry (mecanum or omni
wheels) also reports a sideways speed: it is taken as an input, moving the
pose along base_link y, and a robot sliding sideways is not stationary. Noise
adaptation and NIS monitoring: :mod:`.improved_consistency`.

The gyro bias is learnt at standstill (zero-velocity update: the gyro must
read its bias) and, by default, NOT from the wheel yaw rate: wheel slip,
skid steering and a left/right radius mismatch all mimic a gyro bias there,
so that update is a Schmidt-Kalman consider update that corrects only the
wheel yaw-rate scale and per-speed offset (``bias_from_wheels: true``
turns it into a full update).

Sensor latency: an IMU sample or odometry up to ``max_lag`` older than the
filter time is applied at the filter time (counted); older ones are
rejected. Odometry whose content lags its stamps by ``odometry_delay`` is
used at the time it describes (:mod:`.delay`). Equations from seed 004 are
tagged ``seed 004``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from robot_calib.core import types as T
from robot_calib.core.chi2 import chi2_ppf
from robot_calib.core.geometry import wrap_scalar
from robot_calib.methods.odometry_fusion.common import FusionOutput
from robot_calib.methods.odometry_fusion.delay import DelayedOdometry
from robot_calib.methods.odometry_fusion.gravity import GravityTracker, WheelAcceleration
from robot_calib.methods.odometry_fusion.improved_consistency import NisMonitor, NoiseAdapter
from robot_calib.methods.odometry_fusion.variant_base import FusionFilter

IX, IY, IYAW, IV, IBG, IBA, IKW, IKV = range(8)
"""Indices of the improved state."""

_EYE8 = np.eye(8)
_CONSIDER_W = 6
"""States the wheel yaw rate does not correct by default: the first 6 (all but k_w, k_v)."""
_CONSIDER_POSE = 3
"""States a standstill update leaves alone with ``continuous_pose``: the first 3 (pose)."""

REJECTION_TOLD = 0.5
"""Seconds of continuously rejected wheel data after which a warning says so (s)."""

_FIT_KEYS = ('yaw_rate_scale', 'yaw_rate_scale_std', 'yaw_rate_per_speed',
             'yaw_rate_per_speed_std', 'odometry_delay', 'odometry_delay_std')
"""The yaw-rate fit's numbers that are estimates (with their stds)."""

_outer = np.multiply.outer
_add_reduce = np.add.reduce


class ImprovedFusion(DelayedOdometry, FusionFilter):
    """Planar EKF: pose, speed, gyro bias, accel bias and odometry yaw-rate scale (see module)."""

    mode = 'improved'

    def _start(self) -> None:
        """Set the initial state: still at the origin, biases 0, scale 1, their priors."""
        super()._start()
        p = self.p
        # the state as Python floats (cheaper per element than a small array; same arithmetic)
        self.x = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        self.P = np.diag([1e-6, 1e-6, 1e-6, 0.25, p.gyro_bias_init ** 2,
                          p.accel_bias_init ** 2, p.yaw_rate_scale_init ** 2,
                          p.yaw_rate_offset_init ** 2])
        self.gz = 0.0
        self._gz_sum = 0.0
        self._gz_n = 0
        self.ax = 0.0
        self.use_acc = False
        self._gate = float(chi2_ppf(p.gate_probability, 1)) if p.gate_probability < 1 \
            else float('inf')
        self.noise = NoiseAdapter(p, self._gate)
        self.nis = NisMonitor(p.nis_window)
        self.yaw_fit = self._new_yaw_fit(p.odometry_delay)
        self.gravity = GravityTracker(p.gravity_time_constant) if p.gravity_compensation \
            else None
        self.front.full_vectors = self.gravity is not None
        self.wheel_accel = WheelAcceleration(p.sensor_timeout)
        self._yaw_rate_world = 0.0
        self._horizontal = 1.0
        self._rej_since: dict = {'slip_speed': None, 'slip_yaw_rate': None}
        self._rej_told: dict = {'slip_speed': False, 'slip_yaw_rate': False}
        self.imu_stale = True
        self._cov_acc = [0.0, 0.0, 0.0, 0.0, 0.0]
        self._cov_mode = (True, False)
        self._w_fallback = 0.0
        self._last_upd_t: Optional[float] = None
        self._pl_last: Optional[tuple] = None
        self._start_delay()

    def _carry_inputs(self) -> tuple:
        """Return what DelayLine.carry needs: turn rate, gyro bias, speeds, mounting z row."""
        rot = self.front.rot
        return (self._yaw_rate_world, self.x[IBG], self.x[IV] * self._horizontal,
                self.odom_lateral, None if rot is None or self.imu_stale else rot[2].tolist())

    # -- initialisation --------------------------------------------------------------------
    def _init_pose(self, s: Optional[T.OdomSample]) -> None:
        """Start at the first odometry pose ``s`` (or 0) when ``initial_pose_from_odom``."""
        if self.initialised:
            return
        if s is not None and self.p.initial_pose_from_odom:
            self.x[IX], self.x[IY], self.x[IYAW] = float(s.x), float(s.y), float(s.yaw)
        self.initialised = True

    def reinitialise(self, t: float, v: float, reason: str) -> None:
        """Reset speed and the bias/scale uncertainties, keep the pose; warn."""
        p = self.p
        self._flush()
        self.x[IV] = v
        self.x[IKW] = 1.0 if not (0.2 < self.x[IKW] < 5.0) else self.x[IKW]
        P = np.diag(np.maximum(np.diag(self.P), 0.0))
        P[IV, IV] = 0.25
        P[IBG, IBG] = max(P[IBG, IBG], p.gyro_bias_init ** 2)
        P[IBA, IBA] = max(P[IBA, IBA], p.accel_bias_init ** 2)
        P[IKW, IKW] = max(P[IKW, IKW], p.yaw_rate_scale_init ** 2)
        P[IKV, IKV] = max(P[IKV, IKV], p.yaw_rate_offset_init ** 2)
        self.P = P
        self.noise.reset()
        self.count('reinitialisations')
        self.warn(t, f'filter re-initialised ({reason})')

    def _on_gyro_missing(self, t: float) -> None:
        """Add the turn the zeros hid; reset the yaw-rate terms, learnt against no gyro."""
        p = self.p
        self._flush()
        self.x[IYAW] = wrap_scalar(self.x[IYAW] + self.zero_gyro.hidden_turn)
        self.x[IKW], self.x[IKV] = 1.0, 0.0
        for i, var in ((IKW, p.yaw_rate_scale_init ** 2), (IKV, p.yaw_rate_offset_init ** 2)):
            self.P[i, :] = 0.0
            self.P[:, i] = 0.0
            self.P[i, i] = var
        self.yaw_fit = self._new_yaw_fit(self.delay_applied)

    # -- prediction ------------------------------------------------------------------------
    def _predict(self, t: float) -> None:
        """Integrate the state to ``t`` (s); the covariance follows in chunks (see _flush)."""
        if self.t is None:
            self.t = t
            return
        dt = t - self.t
        if dt <= 0.0:
            return
        if dt > self.p.sensor_timeout:
            # every input silent (a gap, or a clock that jumped ahead): nothing is known about
            # the motion in between, so none is invented; the odometry re-initialises after it
            self._flush()
            self.t = t
            return
        p = self.p
        x = self.x
        mode = (self.imu_stale, self.use_acc)
        if mode != self._cov_mode:
            self._flush()
            self._cov_mode = mode
        if self.imu_stale:
            w_in, a_in = self._w_fallback, 0.0
        else:
            w_in = self._yaw_rate_world - x[IBG]
            a_in = self.ax - x[IBA] if self.use_acc else 0.0
            # clamp to what the robot can do on its wheels (seed 004's clamping): a shock
            # or an aliased spike must not throw the speed off
            lim = p.max_robot_accel
            a_in = lim if a_in > lim else (-lim if a_in < -lim else a_in)
        yaw, v = x[IYAW], x[IV]
        c, s = math.cos(yaw), math.sin(yaw)
        # constant-rate planar kinematics, first order (IMU as input); a holonomic robot's
        # sideways speed (from its odometry, an input here) moves it along base_link y and
        # turns into forward speed as it rotates (the transport term of a rotating frame)
        vh, vl = v * self._horizontal, self.odom_lateral
        dx, dy = (vh * c - vl * s) * dt, (vh * s + vl * c) * dt
        x[IX] += dx
        x[IY] += dy
        yaw += w_in * dt
        x[IYAW] = yaw if -math.pi < yaw <= math.pi else wrap_scalar(yaw)
        v += (a_in + vl * w_in) * dt if vl else a_in * dt
        x[IV] = v if abs(v) <= p.max_speed else math.copysign(p.max_speed, v)
        acc = self._cov_acc
        acc[0] += dt
        acc[1] += dx
        acc[2] += dy
        acc[3] += c * dt
        acc[4] += s * dt
        self.t = t
        if acc[0] >= 0.25:
            self._flush()

    def _flush(self) -> None:
        """Propagate P over the pending chunk of prediction (<= 0.25 s): P = F P F' + Q."""
        dt, dx, dy, sc, ss = self._cov_acc
        if dt <= 0.0:
            return
        self._cov_acc = [0.0, 0.0, 0.0, 0.0, 0.0]
        p = self.p
        stale, use_acc = self._cov_mode
        F = _EYE8.copy()
        F[IX, IYAW] = -dy  # d(displacement)/d(yaw): the displacement rotated by 90 deg
        F[IY, IYAW] = dx
        F[IX, IV] = sc
        F[IY, IV] = ss
        qs = self.noise.scales if p.adaptation == 'nis' else (1.0, 1.0)
        if not stale:
            F[IYAW, IBG] = -dt
            q_yaw = (p.gyro_noise ** 2) * dt * qs[1]
        else:
            q_yaw = (p.odom_yaw_rate_noise ** 2) * dt
        if use_acc and not stale:
            F[IV, IBA] = -dt
            q_v = (p.accel_noise ** 2) * dt * qs[0]
        else:
            # no accelerometer: speed as a random walk, 0.5 m/s^2/sqrt(Hz)
            q_v = (0.5 ** 2) * dt * qs[0]
        P = F @ self.P @ F.T
        c, s = math.cos(self.x[IYAW]), math.sin(self.x[IYAW])
        lat = (p.lateral_slip * abs(self.x[IV])) ** 2 * dt
        if self.odom_lateral:
            lat += (p.lateral_slip * self.odom_lateral) ** 2 * dt
        P[IX, IX] += lat * s * s + 1e-8 * dt
        P[IY, IY] += lat * c * c + 1e-8 * dt
        P[IX, IY] -= lat * s * c
        P[IY, IX] -= lat * s * c
        P[IYAW, IYAW] += q_yaw
        P[IV, IV] += q_v
        P[IBG, IBG] += (p.gyro_bias_walk ** 2) * dt
        P[IBA, IBA] += (p.accel_bias_walk ** 2) * dt
        P[IKW, IKW] += (p.yaw_rate_scale_walk ** 2) * dt
        P[IKV, IKV] += (p.yaw_rate_offset_walk ** 2) * dt
        self.P = P

    def _imu_step(self, t: float, gz: float, ax: float, use_acc: bool) -> Optional[str]:
        """Predict to ``t`` (s), then hold gyro z (rad/s) and forward force (m/s^2) as input."""
        if self.t is not None and t < self.t:
            if self.t - t > self.p.max_lag:
                return 'stale'
            # a little older than the filter (sensor latency): use it from now on
            self.count('late_imu')
        self._predict(t)
        self.imu_stale = False
        if use_acc and self.gravity is not None:
            # the forward force less gravity on a slope (gravity.py); the motion's own
            # acceleration from the wheels, speed and turn rate
            motion = self.wheel_accel.in_base(self.x[IV], self.odom_lateral, gz - self.x[IBG])
            ax = self.gravity.update(t, self.front.gyro, self.front.force, *motion)
            # the turn about the vertical and the horizontal share of the speed
            self._yaw_rate_world, self._horizontal = self.gravity.level(self.front.gyro)
        else:
            self._yaw_rate_world, self._horizontal = gz, 1.0
        self.gz, self.ax, self.use_acc = gz, ax, use_acc
        self._gz_sum += gz
        self._gz_n += 1
        if self.t is None:
            self.t = t
        return None

    # -- odometry update -------------------------------------------------------------------
    def _unit_update(self, i: int, sign: float, resid: float, r: float,
                     consider: Optional[int] = None) -> tuple[float, float]:
        """
        Kalman update with one observation ``h = sign * e_i`` (sign +-1); (s, NIS).

        ``P h`` is a column of P; ``consider`` (n) leaves the first n states
        uncorrected (Schmidt-Kalman consider update): their uncertainty enters
        the innovation variance, their values are kept.
        """
        Ph = self.P[:, i] if sign > 0.0 else -self.P[:, i]
        return self._gain_update(Ph, float(Ph[i] * sign) + r, resid, consider)

    def _gain_update(self, Ph: np.ndarray, s: float, resid: float,
                     consider: Optional[int]) -> tuple[float, float]:
        """
        Apply the update of gain ``Ph / s`` to the innovation ``resid``; (s, NIS).

        P is updated in place; ``Ph`` may be a view of P: it is read in full (into
        the gain and the outer product) before P changes.
        """
        P = self.P
        k = Ph / s
        if consider is None:
            # P = (I - k h') P = P - k Ph': symmetric by construction
            P -= _outer(k, Ph)
        else:
            k[:consider] = 0.0
            # Joseph form for any gain, expanded: (I - k h') P (I - k h')' + r k k'
            #   = P - k Ph' - Ph k' + s k k' (whole 8x8 arrays: fewer numpy calls than
            # updating only the rows and columns >= consider, and on this size calls cost)
            kPh = _outer(k, Ph)
            P -= kPh
            P -= kPh.T
            P += s * _outer(k, k)
        x = self.x
        for i, ki in enumerate(k.tolist()):
            x[i] += ki * resid  # the products of k * resid, without an array call
        return s, resid * resid / s

    def _wheel_step(self, t: float, v: float, w: float) -> Optional[str]:
        """Update with the wheel speed v (m/s) and yaw rate w (rad/s); return a rejection."""
        p = self.p
        if not self.initialised:
            self._init_pose(None)
        if self.t is not None and t < self.t:
            if self.t - t > p.max_lag:
                return 'stale'
            t = self.t  # a little late: apply now
        self._predict_to_wheels(t, v, w)
        self.wheel_accel.update(t, v, self.odom_lateral)
        still = p.zero_velocity_update and abs(v) < p.zero_velocity_threshold and \
            abs(w) < p.zero_velocity_threshold and \
            abs(self.odom_lateral) < p.zero_velocity_threshold
        fresh = self._gz_n > 0
        gz_avg = self._gz_sum / self._gz_n if fresh else self.gz
        self._gz_sum, self._gz_n = 0.0, 0
        if still and not self.imu_stale and self._gyro_turning(t, gz_avg):
            # late odometry (or wheels held while the robot is pushed round) still reads
            # zero while the gyro already turns: pinning the bias there teaches it the turn
            still = False
            self.count('standstill_refused_gyro_turning')
        # nominal variances of the two channels
        r_v = (p.odom_speed_noise + p.odom_speed_noise_rel * abs(v)) ** 2
        r_w = (p.odom_yaw_rate_noise + p.odom_yaw_rate_noise_rel * abs(w)) ** 2
        nis_total, dof, rejected = 0.0, 0, []
        nis_v = self._speed_update(t, v, r_v, still)
        if nis_v is None:
            rejected.append('slip_speed')
        else:
            nis_total += nis_v
            dof += 1
        if not self.imu_stale:
            nis_w = self._yaw_rate_update(t, v, w, r_w, gz_avg, still, fresh)
            if nis_w is None:
                rejected.append('slip_yaw_rate')
            else:
                nis_total += nis_w
                dof += 1
        if still:
            self._unit_update(IV, 1.0, -self.x[IV], 1e-4, self._still_consider)
        self._last_upd_t = t
        self._after_update(t, v, r_v, rejected, nis_total, dof)
        if rejected:
            return None if dof else 'gated_' + rejected[0]
        return None

    def _wheel_turn_rate(self, v: float, w: float) -> float:
        """
        Return the turn rate (rad/s) the wheels tell while the IMU is silent.

        ``(w - k_v v) / k_w`` with the calibration over the recording once it is ``ok``,
        else with the filter's states of them.
        """
        fit = self.yaw_fit.result()
        if fit['status'] == 'ok':
            kw, kv = fit['yaw_rate_scale'], fit['yaw_rate_per_speed']
        else:
            kw, kv = self.x[IKW], self.x[IKV]
        return (w - kv * v) / kw if abs(kw) > 1e-3 else w

    def _interval(self, t: float) -> float:
        """Return the time (s) the gyro was averaged over since the last odometry update."""
        return t - self._last_upd_t if self._last_upd_t is not None else 0.1

    def _still_gyro_variance(self, t: float) -> float:
        """Return the nominal variance of the gyro averaged over the interval ((rad/s)^2)."""
        return (self.p.gyro_noise ** 2) / max(self._interval(t), 1e-3) + 1e-6

    def _gyro_turning(self, t: float, gz_avg: float) -> bool:
        """Return True when the gyro, less its bias, turns beyond its noise and bias error."""
        innov = gz_avg - self.x[IBG]
        var = float(self.P[IBG, IBG]) + self._still_gyro_variance(t)
        return innov * innov / var > self._gate

    @property
    def _still_consider(self) -> Optional[int]:
        """Return the states a standstill update leaves uncorrected (None: none)."""
        return _CONSIDER_POSE if self.p.continuous_pose else None

    def _predict_to_wheels(self, t: float, v: float, w: float) -> None:
        """Predict to the odometry time ``t`` (s); wheels only while the IMU is stale."""
        p = self.p
        gap = self.last_odom_t is not None and t - self.last_odom_t > p.sensor_timeout
        imu_stale = self.last_imu_t is None or t - self.last_imu_t > p.sensor_timeout
        if imu_stale and not self.imu_stale:
            self.warn(t, 'IMU stale: propagating with wheel odometry only')
            self.count('imu_stale_periods')
        self.imu_stale = imu_stale
        if imu_stale:
            self._w_fallback = self._wheel_turn_rate(v, w)
        self._predict(t)
        self._flush()
        if gap:
            self.count('odom_gaps')
            self.reinitialise(t, v, f'odometry silent for {t - self.last_odom_t:.2f} s')
        self.last_odom_t = t

    def _speed_update(self, t: float, v: float, r_v: float, still: bool) -> Optional[float]:
        """Update with the wheel speed (z = v); return its NIS, or None when gated out."""
        res_v = v - self.x[IV]
        s_pred = float(self.P[IV, IV])
        r_eff = r_v * self.noise.scales[0]
        s_v = s_pred + r_eff
        nis_v = res_v * res_v / s_v
        used = not (nis_v > self._gate and not still)
        if used:
            self._unit_update(IV, 1.0, res_v, r_eff, self._still_consider if still else None)
        self.noise.adapt(0, res_v, s_pred, r_v, s_v, t)
        return nis_v if used else None

    def _yaw_rate_update(self, t: float, v: float, w: float, r_w: float, gz_avg: float,
                         still: bool, fresh: bool) -> Optional[float]:
        """
        Update with the wheel yaw rate (z = k_w (gz - b_g) + k_v v); return its NIS or None.

        ``gz_avg`` is the gyro z averaged over the odometry interval (rad/s), ``fresh``
        whether gyro samples arrived in it; at standstill a zero-velocity update then pins
        the gyro bias. The calibration over the recording (:mod:`.yaw_rate_fit`) takes
        the accepted intervals while moving.
        """
        p = self.p
        x = self.x
        kw = x[IKW]
        w_imu = gz_avg - x[IBG]
        # h = (0, 0, 0, 0, -k_w, 0, w_imu, v): P h is one matrix-vector product and
        # h' P h = sum of its 3 non-zero terms (the same value up to rounding)
        h4, h6, h7 = -kw, w_imu, v
        Ph = self.P @ np.array((0.0, 0.0, 0.0, 0.0, h4, 0.0, h6, h7))
        _, _, _, _, Ph4, _, Ph6, Ph7 = Ph.tolist()
        res_w = w - kw * w_imu - x[IKV] * v
        # variance of the gyro averaged over the odometry interval: sigma^2 / T
        r_gyro = (kw ** 2) * (p.gyro_noise ** 2) / max(self._interval(t), 1e-3)
        s_pred = h4 * Ph4 + h6 * Ph6 + h7 * Ph7
        if p.adaptation == 'nis':
            r_gyro *= self.noise.scales[1]
        r_eff = r_w * self.noise.scales[1] + r_gyro
        s_w = s_pred + r_eff
        nis_w = res_w * res_w / s_w
        used = not (nis_w > self._gate and not still)
        self.yaw_fit.add(t, w, w_imu, v, fresh and not still, fresh,
                         (kw, x[IKV], math.sqrt(self._gate * s_w)))
        self._check_found_delay(t)
        if used:
            self._gain_update(Ph, s_w, res_w, None if p.bias_from_wheels else _CONSIDER_W)
        self.noise.adapt(1, res_w, s_pred + r_gyro, r_w, s_w, t)
        if still:
            # zero-velocity update: the gyro must read its bias
            # nominal gyro noise of the average over the interval (not adapted: the
            # yaw-rate channel's scale also carries wheel noise; an adapted-down value
            # here made the bias over-confident)
            self._unit_update(IBG, -1.0, 0.0 - (gz_avg - x[IBG]), self._still_gyro_variance(t),
                              self._still_consider)
        return nis_w if used else None

    def _after_update(self, t: float, v: float, r_v: float, rejected: list, nis_total: float,
                      dof: int) -> None:
        """Count rejections, record the NIS, guard the state and extend the path length."""
        for r in rejected:
            self.count('rejected_' + r)
        self._persistent_rejection(t, v, rejected, r_v * self.noise.scales[0])
        if dof:
            self.nis.record(nis_total, dof)
        self._guard(t, v)
        prev = self._pl_last
        if prev is not None:
            self.path_length += math.hypot(self.x[IX] - prev[0], self.x[IY] - prev[1])
        self._pl_last = (float(self.x[IX]), float(self.x[IY]))

    def _persistent_rejection(self, t: float, v: float, rejected: list, r_v: float) -> None:
        """Re-initialise a channel whose measurements were all rejected for reinit_after (s)."""
        since_any = self._rej_since
        if not rejected and since_any['slip_speed'] is None and \
                since_any['slip_yaw_rate'] is None:
            return  # nothing rejected now or pending: the loop below would change nothing
        p = self.p
        for channel in ('slip_speed', 'slip_yaw_rate'):
            if channel not in rejected:
                self._rej_since[channel] = None
                continue
            since = self._rej_since[channel]
            if since is None:
                self._rej_since[channel] = t
                self._rej_told[channel] = False
                continue
            if not self._rej_told[channel] and t - since > REJECTION_TOLD:
                # said once per episode: the fused estimate runs on the IMU alone meanwhile
                self._rej_told[channel] = True
                self.warn(t, f'wheel {channel[5:].replace("_", " ")} rejected for '
                          f'{t - since:.1f} s: wheel slip, or a wrong IMU-propagated '
                          'estimate (a slope leaks gravity into the acceleration)')
            if t - since <= p.reinit_after:
                continue
            self._rej_since[channel] = None
            P = self.P
            if channel == 'slip_speed':
                # the speed state lost the wheels (a long slip, a changed wheel, a bad
                # prediction): restart it from the wheel speed, uncorrelated
                self.x[IV] = v
                P[IV, :] = 0.0
                P[:, IV] = 0.0
                P[IV, IV] = r_v + 0.01
                what = 'speed'
            else:
                # the wheel yaw-rate model no longer fits: restart its scale and offset
                for i, init in ((IKW, p.yaw_rate_scale_init), (IKV, p.yaw_rate_offset_init)):
                    P[i, :] = 0.0
                    P[:, i] = 0.0
                    P[i, i] = init ** 2
                what = 'wheel yaw-rate model'
            self.count('reinitialisations')
            self.warn(t, f'{what} re-initialised: wheel {channel[5:].replace("_", " ")} '
                      f'rejected for {t - since:.1f} s')

    def _guard(self, t: float, v: float) -> None:
        """Re-initialise when the state or covariance is no longer finite or sane."""
        P = self.P
        x = self.x
        # the sum of the 8 states in numpy's (pairwise) order: only its finiteness counts
        xsum = ((x[0] + x[1]) + (x[2] + x[3])) + ((x[4] + x[5]) + (x[6] + x[7]))
        bad = not math.isfinite(xsum + float(_add_reduce(P, None)))  # P.sum(), less overhead
        if not bad:
            d = P.diagonal().tolist()
            bad = min(d) < 0 or d[IBG] > 1.0 or abs(x[IBG]) > 1.0 or \
                not (0.05 < x[IKW] < 20.0)
        if bad:
            if not all(math.isfinite(v) for v in x[:3]):
                x[0] = x[1] = x[2] = 0.0
            self.x[IBG] = 0.0 if not (abs(self.x[IBG]) <= 1.0) else self.x[IBG]
            self.x[IBA] = 0.0
            self.x[IKW] = 1.0
            self.x[IKV] = 0.0
            self.P = np.diag([1.0, 1.0, 0.1, 0.25, self.p.gyro_bias_init ** 2,
                              self.p.accel_bias_init ** 2, self.p.yaw_rate_scale_init ** 2,
                              self.p.yaw_rate_offset_init ** 2])
            self.reinitialise(t, v, 'state or covariance diverged')

    # -- output ----------------------------------------------------------------------------
    def _output(self) -> Optional[FusionOutput]:
        """Return the current estimate with covariances, or None before initialisation."""
        if self.t is None or not self.initialised:
            return None
        self._flush()
        x, P = self.x, self.P
        w = (self.gz - x[IBG]) if not self.imu_stale else self._w_fallback
        pose_cov = P[:3, :3].copy()
        var_w = (self.p.gyro_noise ** 2) * 30.0 + float(P[IBG, IBG]) if not self.imu_stale \
            else self.p.odom_yaw_rate_noise ** 2
        vl = self.odom_lateral
        var_lat = (self.p.lateral_slip * abs(x[IV])) ** 2 + 1e-6
        if vl:  # a holonomic robot's sideways speed, as its odometry measured it
            var_lat += (self.p.odom_speed_noise + self.p.odom_speed_noise_rel * abs(vl)) ** 2
        twist_cov = np.array(((float(P[IV, IV]), 0.0, 0.0), (0.0, var_lat, 0.0),
                              (0.0, 0.0, var_w)))
        return FusionOutput(self.t, float(x[IX]), float(x[IY]), float(x[IYAW]), float(x[IV]),
                            float(w), pose_cov, twist_cov, vl)

    def _estimates(self) -> dict:
        """
        Return the bias estimates, the adaptation state and the yaw-rate calibration.

        The yaw-rate scale and per-speed term are the fit over the recording
        (:mod:`.yaw_rate_fit`), present once it has enough motion; the filter's own
        random-walk states of them are nuisance states, not reported.
        """
        sd = np.sqrt(np.maximum(np.diag(self.P), 0.0))
        out = {'gyro_bias': float(self.x[IBG]), 'gyro_bias_std': float(sd[IBG]),
               'accel_bias': float(self.x[IBA]), 'accel_bias_std': float(sd[IBA])}
        fit = self.yaw_fit.result(stale_ok=self._for_status)
        out.update((k, fit[k]) for k in _FIT_KEYS if k in fit)
        out['odometry_delay_applied'] = self.delay_applied
        out['noise_scale_speed'] = float(self.noise.scales[0])
        out['noise_scale_yaw_rate'] = float(self.noise.scales[1])
        return out

    def _variant_result(self) -> dict:
        """Return the noise scales, the NIS statistics, the IMU's staleness, the fit."""
        return {'noise_scales': (float(self.noise.scales[0]), float(self.noise.scales[1])),
                'nis': self.nis.stats(), 'imu_stale': self.imu_stale,
                'yaw_rate_fit': self.yaw_fit.result(stale_ok=self._for_status)}
