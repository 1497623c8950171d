# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
IMU + wheel-odometry fusion (seed 004): the seed-faithful filter and an improved planar EKF.

Two filters share one streaming interface (``imu()``, ``odom()``, ``wheels()``)
and a batch :func:`run`:

* :class:`SeedFusion` (``mode: seed``) does exactly what seed 004 writes: state
  ``[x, y, vx, vy, ax, ay]`` in the odometry frame, the IMU drives the
  prediction (its acceleration, clamped to the robot's limits, rotated by the
  integrated gyro heading), the wheel odometry (wheel speeds in rev/s ->
  ``v = (2 pi n_L r + 2 pi n_R r) / 2``, position by integration) is the
  observation of the whole state, with its own covariance
  ``P_o = F P_o F' + R_o``, the "novel" covariance ``S = P + P_o`` and gain
  ``K = P S^-1``.
* :class:`ImprovedFusion` (``mode: improved``, the default) is an error-aware
  planar EKF with state ``[x, y, yaw, v, b_g, b_a, k_w, k_v]``: pose (m, m,
  rad), forward speed (m/s), gyro z bias (rad/s), forward accelerometer bias
  (m/s^2), the odometry yaw-rate scale (a skid-steer or track-width error,
  dimensionless) and the odometry yaw rate per unit speed (a left/right wheel
  radius mismatch, rad/m). The IMU (gyro z and forward specific force,
  rotated into ``base_link`` by the mounting extrinsic from a parameter,
  ``/tf_static`` or, failing both, the gravity direction) drives the
  prediction; the wheel
  odometry's forward speed and yaw rate are scalar observations, each gated
  by its innovation (chi-square, 1 dof) so wheel slip and outliers are
  rejected and counted. A stationary robot (wheels exactly still) gives a
  zero-velocity update that pins the gyro bias.

Noise adaptation (improved mode, ``adaptation: nis``, the default) keeps one
bounded scale factor per odometry channel (speed, yaw rate) that multiplies
both that channel's measurement noise and the process noise feeding it
(accelerometer noise for the speed, gyro noise for the yaw rate). The scale
follows a stochastic approximation of ``E[NIS] = 1`` in log space
(``log s += (dt / adapt_time) * (min(NIS, 3) - 1)``), clamped to
``[adapt_min, adapt_max]``. Why: from a scalar innovation stream only the
total innovation variance is identifiable, not the split between Q and R, so
we adapt the total and keep the nominal split (physically motivated
defaults); the multiplicative update on a positive nominal keeps every
covariance positive definite and bounded by construction, unlike plain
Sage-Husa whose ``C - H P H'`` can go negative; the NIS cap of 3 stops a
slip episode from inflating the noise fast enough to let the slip in; and it
costs a few flops per update where variational-Bayes adaptation iterates
per step. ``adaptation: iae`` is the classic innovation-based adaptive
estimation of R alone (Mohamed & Schwarz 1999, ``R = C - H P H'`` from the
windowed innovation covariance, clipped to the same bounds), kept for
comparison.

The gyro bias is learnt at standstill (zero-velocity update: the gyro must
read its bias) and, by default, NOT from the wheel yaw rate: wheel slip,
skid steering and a left/right radius mismatch all mimic a gyro bias there,
so that update is a Schmidt-Kalman consider update that corrects only the
wheel yaw-rate scale and per-speed offset (``bias_from_wheels: true``
turns it into a full update).

Consistency is monitored with the normalised innovation squared (NIS) of
each odometry update (2 dof when both channels are used), counted inside or
outside its two-sided 95 % chi-square band; its moving average over
``nis_window`` updates is also compared with the (narrower) band of that
average, which exposes time-correlated innovations.

Sensor latency: an IMU sample or odometry up to ``max_lag`` older than the
filter time is applied at the filter time (counted); older ones are
rejected. Equations are tagged ``seed 004`` where they come from the seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Iterable, Optional

import numpy as np
from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix, wrap_angle
from robot_calib.core.params import param
from robot_calib.core.series import Thinned
from scipy.special import chdtri

G = 9.80665
"""Standard gravity (m/s^2)."""


@dataclass
class SeedParams:
    """Seed-faithful filter settings (seed 004)."""

    max_speed: float = param(2.0, 'm/s', 'Clamp of the IMU-predicted speed (robot limit)',
                             minimum=0.01)
    max_accel: float = param(3.0, 'm/s^2', 'Clamp of the IMU acceleration (robot limit)',
                             minimum=0.01)
    q_position: float = param(1e-4, 'm^2', 'Process noise Q of x, y per prediction', minimum=0.0)
    q_velocity: float = param(1e-3, 'm^2/s^2', 'Process noise Q of vx, vy per prediction',
                              minimum=0.0)
    q_accel: float = param(1e-2, 'm^2/s^4', 'Process noise Q of ax, ay per prediction',
                           minimum=0.0)
    r_position: float = param(1e-4, 'm^2', 'Odometry noise R_o of x, y per step', minimum=0.0)
    r_velocity: float = param(1e-3, 'm^2/s^2', 'Odometry noise R_o of vx, vy per step',
                              minimum=0.0)
    r_accel: float = param(1e-1, 'm^2/s^4', 'Odometry noise R_o of ax, ay per step', minimum=0.0)
    accuracy_threshold: float = param(0.95, '', 'Lidar accuracy check: valid at or above this',
                                      minimum=0.0, maximum=1.0)


@dataclass
class FusionParams:
    """Parameters of the ``odometry_fusion`` node (SI units)."""

    mode: str = param('improved', '', 'improved (default) or seed (seed-faithful 004)',
                      choices=('improved', 'seed'))
    base_frame: str = param('base_link', '', 'Robot body frame the IMU extrinsic refers to')
    odom_frame: str = param('odom', '', 'Frame of the fused pose (header.frame_id)')
    imu_extrinsic: str = param(
        'auto', '', 'IMU mounting source: auto (tf_static if received, else imu_rpy if non-zero, '
        'else the up axis from gravity at start), param (imu_rpy), tf (only /tf_static), '
        'gravity (up axis from gravity)', choices=('auto', 'param', 'tf', 'gravity'))
    imu_rpy: list = param([0.0, 0.0, 0.0], 'rad',
                          'base_link -> IMU rotation as roll, pitch, yaw (R = Rz Ry Rx)', length=3)
    accel_units: str = param('auto', '', 'IMU acceleration units: auto (detected from the '
                             'gravity magnitude), mps2 or g', choices=('auto', 'mps2', 'g'))
    wheel_source: str = param('auto', '', 'Wheel input: auto (odom; joint_states only when no '
                              'odom arrives within 1 s of it), odom or joint_states',
                              choices=('auto', 'odom', 'joint_states'))
    drive_type: str = param('differential', '', 'Drive of joint_states input: differential or '
                            'steered_wheel (one steered drive wheel ahead of the rear axle)',
                            choices=('differential', 'steered_wheel'))
    wheel_radius: float = param(0.1, 'm', 'Nominal wheel radius (joint_states input)',
                                minimum=1e-4)
    track_width: float = param(0.5, 'm', 'Distance between the wheels (joint_states input)',
                               minimum=1e-3)
    left_wheel_radius: float = param(0.0, 'm', 'Left wheel radius; 0 uses wheel_radius',
                                     minimum=0.0)
    right_wheel_radius: float = param(0.0, 'm', 'Right wheel radius; 0 uses wheel_radius',
                                      minimum=0.0)
    wheel_base: float = param(0.6, 'm', 'Steered wheel: distance rear axle -> steered wheel',
                              minimum=1e-3)
    steering_joint: str = param('steering_joint', '', 'Steered wheel: steering joint name')
    traction_joint: str = param('traction_joint', '', 'Steered wheel: traction joint name')
    left_wheel_joint: str = param('left_wheel_joint', '', 'Left wheel joint name')
    right_wheel_joint: str = param('right_wheel_joint', '', 'Right wheel joint name')
    initial_pose_from_odom: bool = param(True, '', 'Start at the first odometry pose (else 0)')
    gyro_noise: float = param(0.003, 'rad/s/sqrt(Hz)', 'Gyro white-noise density (low-cost '
                              'MEMS incl. vibration)', minimum=1e-6)
    gyro_bias_walk: float = param(2e-5, 'rad/s/sqrt(s)', 'Gyro bias random walk', minimum=0.0)
    gyro_bias_init: float = param(0.01, 'rad/s', 'Initial gyro bias standard deviation',
                                  minimum=1e-6)
    accel_noise: float = param(0.5, 'm/s^2/sqrt(Hz)', 'Forward specific-force noise density as '
                               'the filter sees it: vibration, bumps and terrain pitch of a '
                               'wheeled base, not the datasheet noise', minimum=1e-6)
    accel_bias_walk: float = param(0.005, 'm/s^2/sqrt(s)', 'Accelerometer bias random walk '
                                   '(also absorbs slowly varying slope)', minimum=0.0)
    accel_bias_init: float = param(0.3, 'm/s^2', 'Initial forward accel bias std (mount tilt)',
                                   minimum=1e-6)
    lateral_slip: float = param(0.02, '1/sqrt(s)', 'Lateral position noise per unit speed '
                                '(side slip), m/s/sqrt(Hz) per m/s', minimum=0.0)
    odom_speed_noise: float = param(0.02, 'm/s', 'Wheel speed noise (constant part)',
                                    minimum=1e-6)
    odom_speed_noise_rel: float = param(0.02, '', 'Wheel speed noise per unit speed',
                                        minimum=0.0)
    odom_yaw_rate_noise: float = param(0.02, 'rad/s', 'Wheel yaw-rate noise (constant part)',
                                       minimum=1e-6)
    odom_yaw_rate_noise_rel: float = param(0.1, '', 'Wheel yaw-rate noise per unit yaw rate',
                                           minimum=0.0)
    yaw_rate_scale_init: float = param(0.3, '', 'Initial std of the odometry yaw-rate scale',
                                       minimum=1e-6)
    yaw_rate_scale_walk: float = param(0.002, '1/sqrt(s)', 'Random walk of the odometry '
                                       'yaw-rate scale (surface changes)', minimum=0.0)
    yaw_rate_offset_init: float = param(0.02, 'rad/m', 'Initial std of the odometry yaw rate '
                                        'per unit speed (left/right wheel radius mismatch)',
                                        minimum=1e-6)
    yaw_rate_offset_walk: float = param(1e-4, 'rad/m/sqrt(s)', 'Random walk of the yaw rate '
                                        'per unit speed', minimum=0.0)
    bias_from_wheels: bool = param(False, '', 'Let the wheel yaw rate correct the gyro bias; '
                                   'off: the bias is a consider state there (wheel slip and '
                                   'radius mismatch mimic a bias) and is learnt at standstill')
    zero_velocity_update: bool = param(True, '', 'Wheels exactly still: pin speed and yaw rate')
    zero_velocity_threshold: float = param(1e-3, 'm/s or rad/s', 'Wheel speed and yaw rate '
                                           'below which the robot is taken as stationary',
                                           minimum=0.0)
    gate_probability: float = param(0.9999, '', 'Chi-square gate of each odometry channel '
                                    '(1 dof); 1 disables gating', minimum=0.5, maximum=1.0)
    adaptive: bool = param(True, '', 'On-line odometry noise adaptation (IAE)')
    adaptation: str = param('nis', '', 'nis: one scale per odometry channel on both its '
                            'measurement and process noise, driven to E[NIS] = 1; iae: '
                            "measurement noise only, R = C - H P H' (Mohamed & Schwarz)",
                            choices=('nis', 'iae'))
    adapt_time: float = param(10.0, 's', 'Time constant of the innovation averaging',
                              minimum=0.1)
    adapt_min: float = param(0.01, '', 'Lower bound of the noise scale factor', minimum=1e-3)
    adapt_max: float = param(100.0, '', 'Upper bound of the noise scale factor', minimum=1.0)
    nis_window: int = param(20, '', 'Odometry updates in the NIS moving average', minimum=1)
    max_speed: float = param(3.0, 'm/s', 'Physical speed limit: clamp of the speed state',
                             minimum=0.01)
    max_robot_accel: float = param(5.0, 'm/s^2', 'Forward acceleration limit of the robot: the '
                                   'IMU input is clamped to it', minimum=0.1)
    max_gyro: float = param(35.0, 'rad/s', 'Gyro readings above this are rejected', minimum=0.1)
    max_accel: float = param(160.0, 'm/s^2', 'Accelerometer readings above this are rejected',
                             minimum=1.0)
    sensor_timeout: float = param(0.5, 's', 'A sensor silent this long is stale', minimum=0.01)
    max_lag: float = param(0.2, 's', 'Odometry older than the filter by more is rejected',
                           minimum=0.0)
    reset_jump: float = param(1.0, 'm', 'Odometry pose jump beyond twist*dt taken as a reset',
                              minimum=0.01)
    reinit_after: float = param(3.0, 's', 'Re-initialise after this long of rejected odometry',
                                minimum=0.1)
    diagnostics_period: float = param(1.0, 's', 'Period of /diagnostics', minimum=0.05)
    seed: SeedParams = field(default_factory=SeedParams)


def _chi2_ppf(probability: float, dof: float) -> float:
    """Return the chi-square quantile of ``probability`` with ``dof`` degrees of freedom."""
    return float(chdtri(dof, 1.0 - probability))


def _wrap(a: float) -> float:
    """Wrap a scalar angle (rad) to (-pi, pi] (fast path of geometry.wrap_angle)."""
    if -math.pi < a <= math.pi:
        return a
    a = math.fmod(a + math.pi, 2.0 * math.pi)
    a = a + math.pi if a <= 0.0 else a - math.pi
    return a if a != -math.pi else math.pi


def lidar_accuracy(d: float, d_lidar: float) -> tuple[float, bool]:
    """
    Return the seed's accuracy ``1 - |d - d_l| / d_l`` and whether it is valid (>= 0.95).

    :param d: travelled distance from the fused positions (m)
    :param d_lidar: travelled distance measured by the lidar (m)
    :return: (accuracy, valid); (nan, False) when ``d_lidar`` is not positive
    """
    if not (math.isfinite(d) and math.isfinite(d_lidar)) or d_lidar <= 0.0:
        return float('nan'), False
    acc = 1.0 - abs(d - d_lidar) / d_lidar  # seed 004, accuracy check
    return acc, acc >= 0.95


def nis_band(dof: int, window: int, prob: float = 0.95) -> tuple[float, float]:
    """
    Return the two-sided ``prob`` band of the mean of ``window`` NIS values of ``dof`` dof.

    :param dof: degrees of freedom of one NIS value
    :param window: number of values averaged
    :param prob: band probability
    :return: (low, high) of the average NIS
    """
    n = dof * window
    a = (1.0 - prob) / 2.0
    return float(_chi2_ppf(a, n) / window), float(_chi2_ppf(1.0 - a, n) / window)


def wheel_twist(params: FusionParams, sample: T.JointStateSample,
                last: Optional[T.JointStateSample]) -> Optional[tuple[float, float]]:
    """
    Return (v m/s, w rad/s) of the drive from joint states, or None.

    Wheel velocities (rad/s) are used when present, else position differences
    with the previous sample. Speed as seed 004 writes it with rev/s
    ``n = omega / (2 pi)``: ``v = (2 pi n_L r_L + 2 pi n_R r_R) / 2``.

    :param params: geometry (wheel radii m, track width m, joint names)
    :param sample: current joint states
    :param last: previous joint states (for position differences)
    """
    if params.drive_type == 'steered_wheel':
        return _steered_twist(params, sample, last)
    rl = params.left_wheel_radius or params.wheel_radius
    rr = params.right_wheel_radius or params.wheel_radius
    pl, wl = sample.get(params.left_wheel_joint)
    pr, wr = sample.get(params.right_wheel_joint)
    if not (math.isfinite(wl) and math.isfinite(wr)):
        if last is None:
            return None
        ql, _ = last.get(params.left_wheel_joint)
        qr, _ = last.get(params.right_wheel_joint)
        dt = sample.t - last.t
        if dt <= 0 or not all(math.isfinite(v) for v in (pl, pr, ql, qr)):
            return None
        wl, wr = (pl - ql) / dt, (pr - qr) / dt
    n_l, n_r = wl / (2 * math.pi), wr / (2 * math.pi)
    v = (2 * math.pi * n_l * rl + 2 * math.pi * n_r * rr) / 2.0  # seed 004, wheel speed
    w = (2 * math.pi * n_r * rr - 2 * math.pi * n_l * rl) / params.track_width
    return v, w


def _steered_twist(params: FusionParams, sample: T.JointStateSample,
                   last: Optional[T.JointStateSample]) -> Optional[tuple[float, float]]:
    """
    Return (v m/s, w rad/s) of a steered drive wheel (base_link on the rear axle).

    Wheel rim speed ``u = omega r``; ``v = u cos(delta)``, ``w = u sin(delta) / wheel_base``.
    """
    delta, _ = sample.get(params.steering_joint)
    pos, vel = sample.get(params.traction_joint)
    if not math.isfinite(vel):
        if last is None:
            return None
        q, _ = last.get(params.traction_joint)
        dt = sample.t - last.t
        if dt <= 0 or not (math.isfinite(pos) and math.isfinite(q)):
            return None
        vel = (pos - q) / dt
    if not math.isfinite(delta):
        return None
    u = vel * params.wheel_radius
    return u * math.cos(delta), u * math.sin(delta) / params.wheel_base


class _ImuFrontEnd:
    """IMU units detection and mounting rotation shared by both filters."""

    def __init__(self, params: FusionParams):
        self.p = params
        self.rot: Optional[np.ndarray] = None
        self.rot_source = 'none'
        self.forward_known = False
        self.accel_scale: Optional[float] = {'mps2': 1.0, 'g': G}.get(params.accel_units)
        self.units_source = params.accel_units if self.accel_scale else 'pending'
        self._norms: list[float] = []
        self._acc_sum = np.zeros(3)
        self._n_up = 0
        self.warnings: list[str] = []
        rpy = list(params.imu_rpy) + [0.0] * 3
        if params.imu_extrinsic == 'param' or (params.imu_extrinsic == 'auto'
                                               and any(abs(v) > 0 for v in rpy[:3])):
            self.set_rotation(quat_to_matrix(quat_from_rpy(*rpy[:3])), 'param')

    def set_rotation(self, rot: np.ndarray, source: str) -> None:
        """Use ``rot`` (3x3, IMU -> base) from ``source``."""
        self.rot = np.asarray(rot, dtype=float)
        self._r0 = [float(v) for v in self.rot[0]]
        self._r2 = [float(v) for v in self.rot[2]]
        self.rot_source = source
        self.forward_known = source in ('param', 'tf')

    def convert(self, s: T.ImuSample, g: tuple, acc: tuple
                ) -> Optional[tuple[float, float, bool]]:
        """
        Return (gyro z rad/s, forward specific force m/s^2, accel usable) in base_link.

        None while the units or the gravity axis are still being determined.
        """
        if self.accel_scale is None:
            self._norms.append(math.sqrt(acc[0] ** 2 + acc[1] ** 2 + acc[2] ** 2))
            if len(self._norms) >= 10:
                med = float(np.median(self._norms))
                if 0.5 < med < 1.5:
                    self.accel_scale, self.units_source = G, 'detected_g'
                    self.warnings.append(f'IMU acceleration is in g (|a| median {med:.3f}): '
                                         'converting to m/s^2')
                elif 5.0 < med < 15.0:
                    self.accel_scale, self.units_source = 1.0, 'detected_mps2'
                else:
                    self.accel_scale, self.units_source = 1.0, 'unknown'
                    self.warnings.append(f'IMU |a| median {med:.3f} is neither 1 g nor 9.81 '
                                         'm/s^2: acceleration ignored')
        if self.rot is None and self.p.imu_extrinsic in ('auto', 'gravity', 'tf'):
            if self.p.imu_extrinsic == 'tf':
                return None
            self._acc_sum += np.asarray(acc, dtype=float)
            self._n_up += 1
            if self._n_up < 10 or self.accel_scale is None:
                return None
            mean = self._acc_sum / self._n_up
            if np.linalg.norm(mean) * self.accel_scale < 0.5 * G:
                self.warnings.append('no gravity in the IMU acceleration: taking the IMU z '
                                     'axis as up (set imu_rpy or publish /tf_static)')
                self.set_rotation(np.eye(3), 'gravity')
            else:
                self.set_rotation(_rotation_to_up(mean / np.linalg.norm(mean)), 'gravity')
        if self.rot is None or self.accel_scale is None:
            return None
        r2, r0 = self._r2, self._r0
        gz = r2[0] * g[0] + r2[1] * g[1] + r2[2] * g[2]
        use_acc = self.forward_known and self.units_source != 'unknown'
        ax = (r0[0] * acc[0] + r0[1] * acc[1] + r0[2] * acc[2]) * self.accel_scale \
            if use_acc else 0.0
        return gz, ax, use_acc


def _rotation_to_up(up: np.ndarray) -> np.ndarray:
    """Return a rotation (IMU -> level frame) mapping the unit vector ``up`` onto +z."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(up, z)
    c = float(up @ z)
    s = float(np.linalg.norm(v))
    if s < 1e-9:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * ((1 - c) / (s * s))


@dataclass
class FusionOutput:
    """One fused estimate: pose, twist and their 3x3 covariances, at time ``t`` (s)."""

    t: float
    x: float
    y: float
    yaw: float
    v: float
    w: float
    pose_cov: np.ndarray
    twist_cov: np.ndarray


class _Base:
    """Common bookkeeping of both filters (counters, events, lidar check)."""

    def __init__(self, params: FusionParams):
        self.p = params
        self.front = _ImuFrontEnd(params)
        self.t: Optional[float] = None
        self.counts: dict[str, int] = {}
        self.events: list[tuple[float, str]] = []
        self.path_length = 0.0
        self.last_imu_t: Optional[float] = None
        self.last_odom_t: Optional[float] = None
        self._odom_last: Optional[T.OdomSample] = None
        self._joints_last: Optional[T.JointStateSample] = None
        self._lidar_start: Optional[tuple[float, float]] = None
        self.lidar_distance = 0.0
        self._lidar_last: Optional[T.OdomSample] = None
        self._fused_at_lidar_start: Optional[float] = None

    def count(self, key: str, n: int = 1) -> None:
        """Increase counter ``key`` by ``n``."""
        self.counts[key] = self.counts.get(key, 0) + n

    def warn(self, t: float, message: str) -> None:
        """Record a warning event at time ``t`` (s)."""
        self.events.append((t, message))
        if len(self.events) > 1000:
            del self.events[:500]

    # -- input adapters --------------------------------------------------------------------
    def imu(self, s: T.ImuSample) -> Optional[str]:
        """Feed one IMU sample; return a rejection reason or None when used."""
        gx, gy, gz = np.asarray(s.gyro, dtype=float).tolist()
        ax, ay, az = np.asarray(s.accel, dtype=float).tolist()
        if not math.isfinite(gx + gy + gz + ax + ay + az + s.t):
            return 'non_finite'
        if max(abs(gx), abs(gy), abs(gz)) > self.p.max_gyro:
            return 'gyro_out_of_range'
        if math.sqrt(ax * ax + ay * ay + az * az) * (self.front.accel_scale or 1.0) > \
                self.p.max_accel:
            return 'accel_out_of_range'
        if self.last_imu_t is not None and s.t <= self.last_imu_t:
            return 'out_of_order'
        conv = self.front.convert(s, (gx, gy, gz), (ax, ay, az))
        while self.front.warnings:
            self.warn(s.t, self.front.warnings.pop(0))
        if conv is None:
            self.last_imu_t = s.t
            return 'initialising'
        if self.last_imu_t is not None and s.t - self.last_imu_t > self.p.sensor_timeout:
            self.count('imu_gaps')
            self.warn(s.t, f'IMU silent for {s.t - self.last_imu_t:.2f} s; resumed')
        self.last_imu_t = s.t
        return self._imu(s.t, *conv)

    def odom(self, s: T.OdomSample) -> Optional[str]:
        """Feed one wheel-odometry message; return a rejection reason or None when used."""
        vals = (s.t, s.x, s.y, s.yaw, s.vx, s.vy, s.wz)
        if not all(math.isfinite(v) for v in vals):
            return 'non_finite'
        last = self._odom_last
        if last is not None and s.t <= last.t:
            return 'out_of_order'
        v, w = s.vx, s.wz
        self._odom_last = s
        if last is not None:
            dt = s.t - last.t
            c, sn = math.cos(last.yaw), math.sin(last.yaw)
            dx, dy = s.x - last.x, s.y - last.y
            fwd = c * dx + sn * dy
            dyaw = _wrap(s.yaw - last.yaw)
            moved = math.hypot(dx, dy)
            twist_zero = s.vx == 0.0 and s.wz == 0.0 and last.vx == 0.0 and last.wz == 0.0
            expect = max(abs(s.vx), abs(last.vx)) * dt
            jump_limit = self.p.max_speed * dt + self.p.reset_jump
            if moved > expect + self.p.reset_jump and (not twist_zero or moved > jump_limit):
                self.count('odom_resets')
                self.warn(s.t, f'odometry pose jumped {moved:.2f} m: reset taken, '
                          'using increments after it')
                if twist_zero:
                    return 'odom_reset'
            elif twist_zero and (moved > 1e-6 or abs(dyaw) > 1e-6) and dt > 0:
                # a driver that fills only the pose: velocity from pose increments
                v, w = fwd / dt, dyaw / dt
        else:
            self._init_pose(s)
        if abs(v) > 3.0 * self.p.max_speed:
            return 'speed_out_of_range'
        return self._odom(s.t, v, w)

    def wheels(self, s: T.JointStateSample) -> Optional[str]:
        """Feed one joint-state message (differential drive); return a rejection reason."""
        tw = wheel_twist(self.p, s, self._joints_last)
        last = self._joints_last
        self._joints_last = s
        if last is not None and s.t <= last.t:
            return 'out_of_order'
        if tw is None:
            return 'missing_wheel_joints'
        if last is None and self.t is None:
            self._init_pose(None)
        v, w = tw
        if not (math.isfinite(v) and math.isfinite(w)):
            return 'non_finite'
        if abs(v) > 3.0 * self.p.max_speed:
            return 'speed_out_of_range'
        return self._odom(s.t, v, w)

    def lidar(self, s: T.OdomSample) -> None:
        """Feed a lidar odometry pose (m) for the seed's distance accuracy check."""
        if not all(math.isfinite(v) for v in (s.t, s.x, s.y)):
            return
        if self._lidar_last is None:
            self._fused_at_lidar_start = self.path_length
        else:
            self.lidar_distance += math.hypot(s.x - self._lidar_last.x, s.y - self._lidar_last.y)
        self._lidar_last = s

    def lidar_check(self) -> tuple[float, bool]:
        """Return the seed's (accuracy, valid) of fused vs lidar distance since the first scan."""
        if self._fused_at_lidar_start is None:
            return float('nan'), False
        return lidar_accuracy(self.path_length - self._fused_at_lidar_start, self.lidar_distance)

    # -- to override -----------------------------------------------------------------------
    def _init_pose(self, s: Optional[T.OdomSample]) -> None:
        raise RuntimeError('abstract')

    def _imu(self, t: float, gz: float, ax: float, use_acc: bool) -> Optional[str]:
        raise RuntimeError('abstract')

    def _odom(self, t: float, v: float, w: float) -> Optional[str]:
        raise RuntimeError('abstract')


# indices of the improved state
IX, IY, IYAW, IV, IBG, IBA, IKW, IKV = range(8)


_EYE8 = np.eye(8)
_CONSIDER_W = np.array([True, True, True, True, True, True, False, False])
"""States the wheel yaw rate does not correct by default (only its scale and offset)."""


class ImprovedFusion(_Base):
    """Planar EKF: pose, speed, gyro bias, accel bias and odometry yaw-rate scale (see module)."""

    def __init__(self, params: Optional[FusionParams] = None):
        """Create the filter with ``params`` (defaults when None)."""
        super().__init__(params or FusionParams())
        p = self.p
        self.x = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0])
        self.P = np.diag([1e-6, 1e-6, 1e-6, 0.25, p.gyro_bias_init ** 2,
                          p.accel_bias_init ** 2, p.yaw_rate_scale_init ** 2,
                          p.yaw_rate_offset_init ** 2])
        self.initialised = False
        self.gz = 0.0
        self._gz_sum = 0.0
        self._gz_n = 0
        self.ax = 0.0
        self.use_acc = False
        self.lam = np.ones(2)
        self._c2 = None
        self.nis_hist = Thinned()
        """NIS of every update, thinned to a bounded size (plots); ``nis_sum`` is exact."""
        self.nis_sum = 0.0
        self._nis_win: list[float] = []
        self._nis_dof_win: list[int] = []
        self.nis_avg = float('nan')
        self.nis_in_band = 0
        self.nis_checked = 0
        self._gate = float(_chi2_ppf(p.gate_probability, 1)) if p.gate_probability < 1 \
            else float('inf')
        self._band = {}
        self._rej_since: dict = {'slip_speed': None, 'slip_yaw_rate': None}
        self.last_output: Optional[FusionOutput] = None
        self.imu_stale = True
        self._cov_acc = [0.0, 0.0, 0.0, 0.0, 0.0]

    # -- initialisation --------------------------------------------------------------------
    def _init_pose(self, s: Optional[T.OdomSample]) -> None:
        if self.initialised:
            return
        if s is not None and self.p.initial_pose_from_odom:
            self.x[IX], self.x[IY], self.x[IYAW] = s.x, s.y, s.yaw
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
        self.lam[:] = 1.0
        self._c2 = None
        self.count('reinitialisations')
        self.warn(t, f'filter re-initialised ({reason})')

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
            w_in = self.gz - x[IBG]
            a_in = self.ax - x[IBA] if self.use_acc else 0.0
            # clamp to what the robot can do on its wheels (seed 004's clamping): a shock
            # or an aliased spike must not throw the speed off
            lim = p.max_robot_accel
            a_in = lim if a_in > lim else (-lim if a_in < -lim else a_in)
        yaw, v = x[IYAW], x[IV]
        c, s = math.cos(yaw), math.sin(yaw)
        # constant-rate planar kinematics, first order (IMU as input)
        dx, dy = v * c * dt, v * s * dt
        x[IX] += dx
        x[IY] += dy
        x[IYAW] = _wrap(yaw + w_in * dt)
        v += a_in * dt
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
        qs = self.lam if p.adaptation == 'nis' else (1.0, 1.0)
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

    _cov_mode = (True, False)

    _w_fallback = 0.0

    def _imu(self, t: float, gz: float, ax: float, use_acc: bool) -> Optional[str]:
        if self.t is not None and t < self.t:
            if self.t - t > self.p.max_lag:
                return 'stale'
            # a little older than the filter (sensor latency): use it from now on
            self.count('late_imu')
        self._predict(t)
        self.imu_stale = False
        self.gz, self.ax, self.use_acc = gz, ax, use_acc
        self._gz_sum += gz
        self._gz_n += 1
        if self.t is None:
            self.t = t
        return None

    # -- odometry update -------------------------------------------------------------------
    def _scalar_update(self, h: np.ndarray, resid: float, r: float,
                       consider: Optional[np.ndarray] = None) -> tuple[float, float]:
        """
        Kalman update with one scalar observation; return (innovation variance, NIS).

        ``consider`` masks states left uncorrected (Schmidt-Kalman consider update):
        their uncertainty enters the innovation variance, their values are kept.
        """
        Ph = self.P @ h
        s = float(h @ Ph) + r
        k = Ph / s
        if consider is None:
            self.x += k * resid
            # P = (I - k h') P = P - Ph Ph' / s: symmetric by construction
            self.P = self.P - np.outer(k, Ph)
        else:
            k[consider] = 0.0
            self.x += k * resid
            # Joseph form for any gain, expanded: (I - k h') P (I - k h')' + r k k'
            #   = P - k Ph' - Ph k' + s k k'
            kPh = np.outer(k, Ph)
            self.P = self.P - kPh - kPh.T + s * np.outer(k, k)
        return s, resid * resid / s

    def _odom(self, t: float, v: float, w: float) -> Optional[str]:
        p = self.p
        if not self.initialised:
            self._init_pose(None)
        if self.t is not None and t < self.t:
            if self.t - t > p.max_lag:
                return 'stale'
            t = self.t  # a little late: apply now
        gap = self.last_odom_t is not None and t - self.last_odom_t > p.sensor_timeout
        imu_stale = self.last_imu_t is None or t - self.last_imu_t > p.sensor_timeout
        if imu_stale and not self.imu_stale:
            self.warn(t, 'IMU stale: propagating with wheel odometry only')
            self.count('imu_stale_periods')
        self.imu_stale = imu_stale
        kw = self.x[IKW] if abs(self.x[IKW]) > 1e-3 else 1.0
        self._w_fallback = w / kw
        self._predict(t)
        self._flush()
        if gap:
            self.count('odom_gaps')
            self.reinitialise(t, v, f'odometry silent for {t - self.last_odom_t:.2f} s')
        self.last_odom_t = t
        x = self.x
        still = p.zero_velocity_update and abs(v) < p.zero_velocity_threshold and \
            abs(w) < p.zero_velocity_threshold
        gz_avg = self._gz_sum / self._gz_n if self._gz_n else self.gz
        self._gz_sum, self._gz_n = 0.0, 0
        # nominal variances of the two channels
        r_v = (p.odom_speed_noise + p.odom_speed_noise_rel * abs(v)) ** 2
        r_w = (p.odom_yaw_rate_noise + p.odom_yaw_rate_noise_rel * abs(w)) ** 2
        nis_total, dof, rejected = 0.0, 0, []
        # speed channel: z = v
        h = np.zeros(8)
        h[IV] = 1.0
        res_v = v - x[IV]
        s_pred = float(self.P[IV, IV])
        r_eff = r_v * self.lam[0]
        s_v = s_pred + r_eff
        nis_v = res_v * res_v / s_v
        if nis_v > self._gate and not still:
            rejected.append('slip_speed')
        else:
            self._scalar_update(h, res_v, r_eff)
            nis_total += nis_v
            dof += 1
        self._adapt(0, res_v, s_pred, r_v, s_v, t)
        # yaw-rate channel: z = k_w (gz - b_g)
        if not self.imu_stale:
            w_imu = gz_avg - x[IBG]
            h = np.zeros(8)
            h[IBG] = -x[IKW]
            h[IKW] = w_imu
            h[IKV] = v
            res_w = w - x[IKW] * w_imu - x[IKV] * v
            # variance of the gyro averaged over the odometry interval: sigma^2 / T
            interval = t - self._last_upd_t if self._last_upd_t is not None else 0.1
            r_gyro = (x[IKW] ** 2) * (p.gyro_noise ** 2) / max(interval, 1e-3)
            s_pred = float(h @ self.P @ h)
            if p.adaptation == 'nis':
                r_gyro *= self.lam[1]
            r_eff = r_w * self.lam[1] + r_gyro
            s_w = s_pred + r_eff
            nis_w = res_w * res_w / s_w
            if nis_w > self._gate and not still:
                rejected.append('slip_yaw_rate')
            else:
                self._scalar_update(h, res_w, r_eff,
                                    None if p.bias_from_wheels else _CONSIDER_W)
                nis_total += nis_w
                dof += 1
            self._adapt(1, res_w, s_pred + r_gyro, r_w, s_w, t)
            if still:
                # zero-velocity update: the gyro must read its bias
                h = np.zeros(8)
                h[IBG] = -1.0
                # nominal gyro noise of the average over the interval (not adapted: the
                # yaw-rate channel's scale also carries wheel noise; an adapted-down value
                # here made the bias over-confident)
                self._scalar_update(h, 0.0 - (gz_avg - x[IBG]),
                                    (p.gyro_noise ** 2) / max(interval, 1e-3) + 1e-6)
        if still:
            h = np.zeros(8)
            h[IV] = 1.0
            self._scalar_update(h, -x[IV], 1e-4)
        self._last_upd_t = t
        for r in rejected:
            self.count('rejected_' + r)
        self._persistent_rejection(t, v, rejected, r_v * self.lam[0])
        if dof:
            self._record_nis(nis_total, dof)
        self._guard(t, v)
        prev = self._pl_last
        if prev is not None:
            self.path_length += math.hypot(self.x[IX] - prev[0], self.x[IY] - prev[1])
        self._pl_last = (float(self.x[IX]), float(self.x[IY]))
        if rejected:
            return None if dof else 'gated_' + rejected[0]
        return None

    _last_upd_t: Optional[float] = None

    def _persistent_rejection(self, t: float, v: float, rejected: list, r_v: float) -> None:
        """Re-initialise a channel whose measurements were all rejected for reinit_after (s)."""
        p = self.p
        for channel in ('slip_speed', 'slip_yaw_rate'):
            if channel not in rejected:
                self._rej_since[channel] = None
                continue
            since = self._rej_since[channel]
            if since is None:
                self._rej_since[channel] = t
                continue
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
    _pl_last: Optional[tuple] = None

    def _adapt(self, i: int, resid: float, s_pred: float, r_nom: float, s_tot: float,
               t: float) -> None:
        """Adapt the noise scale of channel ``i`` (0 speed, 1 yaw rate) from its innovation."""
        p = self.p
        if not p.adaptive:
            return
        if self._c2 is None:
            self._c2 = [None, None]
            self._c2_t = [t, t]
        if self._c2[i] is None:
            self._c2[i] = r_nom + s_pred
            self._c2_t[i] = t
        dt = max(t - self._c2_t[i], 0.0)
        self._c2_t[i] = t
        a = min(1.0, max(dt, 0.001) / p.adapt_time)
        if p.adaptation == 'nis':
            # stochastic approximation of E[NIS] = 1 on log(scale); the NIS is capped at 3
            # so that a slip episode raises the scale by at most exp(2 a) per update
            nis = resid * resid / s_tot
            lam = self.lam[i] * math.exp(a * (min(nis, 3.0) - 1.0))
        else:
            e2 = min(resid * resid, self._gate * s_tot)  # clipped: an outlier cannot dominate
            self._c2[i] += a * (e2 - self._c2[i])
            # IAE: R = C_nu - H P H', as a bounded scale of the nominal (Mohamed & Schwarz 1999)
            lam = (self._c2[i] - s_pred) / r_nom
        self.lam[i] = min(max(lam, p.adapt_min), p.adapt_max)

    def _record_nis(self, nis: float, dof: int) -> None:
        """Record one update's NIS; count it inside or outside its two-sided 95 % band."""
        self.nis_hist.append(nis)
        self.nis_sum += nis
        band1 = self._band.get((dof, 1))
        if band1 is None:
            band1 = self._band[(dof, 1)] = nis_band(dof, 1)
        self.nis_checked += 1
        if band1[0] <= nis <= band1[1]:
            self.nis_in_band += 1
        self._nis_win.append(nis)
        self._nis_dof_win.append(dof)
        n = self.p.nis_window
        if len(self._nis_win) > n:
            del self._nis_win[0]
            del self._nis_dof_win[0]
        if len(self._nis_win) == n:
            total_dof = sum(self._nis_dof_win)
            band = self._band.get(total_dof)
            if band is None:
                lo, hi = nis_band(1, total_dof)
                band = self._band[total_dof] = (lo * total_dof / n, hi * total_dof / n)
            self.nis_avg = sum(self._nis_win) / n
            self.nis_window_checked += 1
            if band[0] <= self.nis_avg <= band[1]:
                self.nis_window_in_band += 1
            self.nis_band_now = band

    nis_window_checked = 0
    nis_window_in_band = 0
    nis_band_now = (float('nan'), float('nan'))

    def _guard(self, t: float, v: float) -> None:
        """Re-initialise when the state or covariance is no longer finite or sane."""
        P = self.P
        bad = not math.isfinite(float(self.x.sum()) + float(P.sum()))
        if not bad:
            d = P.diagonal()
            bad = float(d.min()) < 0 or d[IBG] > 1.0 or abs(self.x[IBG]) > 1.0 or \
                not (0.05 < self.x[IKW] < 20.0)
        if bad:
            if not np.all(np.isfinite(self.x[:3])):
                self.x[:3] = 0.0
            self.x[IBG] = 0.0 if not (abs(self.x[IBG]) <= 1.0) else self.x[IBG]
            self.x[IBA] = 0.0
            self.x[IKW] = 1.0
            self.x[IKV] = 0.0
            self.P = np.diag([1.0, 1.0, 0.1, 0.25, self.p.gyro_bias_init ** 2,
                              self.p.accel_bias_init ** 2, self.p.yaw_rate_scale_init ** 2,
                              self.p.yaw_rate_offset_init ** 2])
            self.reinitialise(t, v, 'state or covariance diverged')

    # -- output ----------------------------------------------------------------------------
    def output(self) -> Optional[FusionOutput]:
        """Return the current estimate with covariances, or None before initialisation."""
        if self.t is None or not self.initialised:
            return None
        self._flush()
        x, P = self.x, self.P
        w = (self.gz - x[IBG]) if not self.imu_stale else self._w_fallback
        pose_cov = P[:3, :3].copy()
        var_w = (self.p.gyro_noise ** 2) * 30.0 + P[IBG, IBG] if not self.imu_stale else \
            self.p.odom_yaw_rate_noise ** 2
        lat = (self.p.lateral_slip * abs(x[IV])) ** 2 + 1e-6
        twist_cov = np.diag([P[IV, IV], lat, var_w])
        out = FusionOutput(self.t, float(x[IX]), float(x[IY]), float(x[IYAW]), float(x[IV]),
                           float(w), pose_cov, twist_cov)
        self.last_output = out
        return out

    def state_summary(self) -> dict:
        """Return the current bias/scale estimates and adaptation state."""
        sd = np.sqrt(np.maximum(np.diag(self.P), 0.0))
        return {'gyro_bias': float(self.x[IBG]), 'gyro_bias_std': float(sd[IBG]),
                'accel_bias': float(self.x[IBA]), 'accel_bias_std': float(sd[IBA]),
                'yaw_rate_scale': float(self.x[IKW]), 'yaw_rate_scale_std': float(sd[IKW]),
                'yaw_rate_per_speed': float(self.x[IKV]),
                'yaw_rate_per_speed_std': float(sd[IKV]),
                'noise_scale_speed': float(self.lam[0]),
                'noise_scale_yaw_rate': float(self.lam[1])}


# indices of the seed state
SX, SY, SVX, SVY, SAX, SAY = range(6)


class SeedFusion(_Base):
    """Seed 004 as written: 6-state linear filter, IMU prediction, odometry state observation."""

    def __init__(self, params: Optional[FusionParams] = None):
        """Create the filter with ``params`` (defaults when None)."""
        super().__init__(params or FusionParams())
        sp = self.p.seed
        self.x = np.zeros(6)
        self.P = np.diag([1e-4, 1e-4, 1e-2, 1e-2, 1e-1, 1e-1])
        self.Q = np.diag([sp.q_position] * 2 + [sp.q_velocity] * 2 + [sp.q_accel] * 2)
        self.Ro = np.diag([sp.r_position] * 2 + [sp.r_velocity] * 2 + [sp.r_accel] * 2)
        self.Po = np.zeros((6, 6))
        self.z = np.zeros(6)
        self.heading = 0.0
        self.odom_yaw = 0.0
        self.initialised = False
        self._odom_v_last: Optional[tuple[float, float]] = None

    def _init_pose(self, s: Optional[T.OdomSample]) -> None:
        if self.initialised:
            return
        if s is not None and self.p.initial_pose_from_odom:
            self.x[SX], self.x[SY] = s.x, s.y
            self.z[SX], self.z[SY] = s.x, s.y
            self.heading = self.odom_yaw = s.yaw
        self.initialised = True

    _z_t: Optional[float] = None

    @staticmethod
    def transition(dt: float) -> np.ndarray:
        """Return F of the constant-acceleration model over ``dt`` (s)."""
        F = np.eye(6)
        F[SX, SVX] = F[SY, SVY] = dt
        F[SX, SAX] = F[SY, SAY] = 0.5 * dt * dt
        F[SVX, SAX] = F[SVY, SAY] = dt
        return F

    def _imu(self, t: float, gz: float, ax: float, use_acc: bool) -> Optional[str]:
        sp = self.p.seed
        if self.t is None:
            self.t = t
            return None
        dt = t - self.t
        if dt <= 0:
            return 'stale'
        self.t = t
        if dt > self.p.sensor_timeout:  # a gap or a clock jump: no motion is invented over it
            return None
        self.heading = wrap_angle(self.heading + gz * dt)
        # IMU acceleration, clamped to the robot's limits (seed 004), into the odom frame
        a = max(-sp.max_accel, min(sp.max_accel, ax))
        F = self.transition(dt)
        x = F @ self.x  # seed 004, x_pred = F x
        x[SAX] = a * math.cos(self.heading)
        x[SAY] = a * math.sin(self.heading)
        sp_now = math.hypot(x[SVX], x[SVY])
        if sp_now > sp.max_speed:  # clamp the IMU velocity (seed 004)
            x[SVX] *= sp.max_speed / sp_now
            x[SVY] *= sp.max_speed / sp_now
        self.x = x
        self.P = F @ self.P @ F.T + self.Q  # seed 004, P = F P F' + Q
        self.path_length += math.hypot(x[SVX], x[SVY]) * dt
        return None

    def _odom(self, t: float, v: float, w: float) -> Optional[str]:
        if not self.initialised:
            self._init_pose(None)
        last = self._z_t
        self._z_t = t
        if last is None or t - last > self.p.sensor_timeout:  # first, or after a gap or jump
            self.z[SVX] = v * math.cos(self.odom_yaw)
            self.z[SVY] = v * math.sin(self.odom_yaw)
            if self.t is None:
                self.t = t
            return None
        dt = t - last
        if dt <= 0:
            return 'stale'
        # odometry by integration of the wheel speed (seed 004)
        self.odom_yaw = wrap_angle(self.odom_yaw + w * dt)
        vx, vy = v * math.cos(self.odom_yaw), v * math.sin(self.odom_yaw)
        z = self.z
        ax_o, ay_o = (vx - z[SVX]) / dt, (vy - z[SVY]) / dt
        z[SX] += vx * dt
        z[SY] += vy * dt
        z[SVX], z[SVY], z[SAX], z[SAY] = vx, vy, ax_o, ay_o
        F = self.transition(dt)
        self.Po = F @ self.Po @ F.T + self.Ro  # seed 004, P_o = F P_o F' + R_o
        self.update(z)
        return None

    def update(self, z: np.ndarray) -> None:
        """Apply seed 004's observation step with the odometry state ``z``."""
        S = self.P + self.Po  # seed 004, "novel" covariance S = P + P_o
        K = self.P @ np.linalg.inv(S)  # seed 004, K = P S^-1
        self.x = self.x + K @ (z - self.x)  # seed 004, x = x_pred + K (z - x_pred)
        self.P = (np.eye(6) - K) @ self.P  # seed 004, P = (I - K) P

    def output(self) -> Optional[FusionOutput]:
        """Return the current estimate (heading from the gyro integration), or None."""
        if self.t is None or not self.initialised:
            return None
        x, P = self.x, self.P
        v = math.hypot(x[SVX], x[SVY])
        c, s = math.cos(self.heading), math.sin(self.heading)
        fwd = c * x[SVX] + s * x[SVY]
        pose_cov = np.zeros((3, 3))
        pose_cov[:2, :2] = P[:2, :2]
        pose_cov[2, 2] = float('nan')  # the seed state has no heading
        twist_cov = np.diag([P[SVX, SVX] + P[SVY, SVY], float('nan'), float('nan')])
        return FusionOutput(self.t, float(x[SX]), float(x[SY]), self.heading,
                            math.copysign(v, fwd), float('nan'), pose_cov, twist_cov)

    def state_summary(self) -> dict:
        """Return the seed filter's state (velocity, acceleration)."""
        return {'vx': float(self.x[SVX]), 'vy': float(self.x[SVY]),
                'ax': float(self.x[SAX]), 'ay': float(self.x[SAY])}


def make_filter(params: Optional[FusionParams] = None) -> _Base:
    """Return the filter selected by ``params.mode``."""
    params = params or FusionParams()
    return SeedFusion(params) if params.mode == 'seed' else ImprovedFusion(params)


def run(samples: Iterable[tuple[str, object]], params: Optional[FusionParams] = None,
        ) -> tuple[list[FusionOutput], _Base]:
    """
    Run a filter over a time-ordered recording and return (estimates, filter).

    :param samples: (kind, sample) pairs; kind is 'imu', 'odom', 'joint_states',
        'lidar_odom' or 'tf_static'
    :param params: parameters (defaults when None)
    :return: one estimate per accepted odometry sample, and the filter (counters,
        NIS history, bias estimates)
    """
    f = make_filter(params)
    outs = []
    for kind, s in samples:
        if kind == 'imu':
            f.imu(s)
        elif kind in ('odom', 'joint_states'):
            reason = f.odom(s) if kind == 'odom' else f.wheels(s)
            if reason is None:
                o = f.output()
                if o is not None:
                    outs.append(o)
        elif kind == 'lidar_odom':
            f.lidar(s)
        elif kind == 'tf_static':
            apply_static_transform(f, s, [], params or FusionParams())
    return outs, f


def apply_static_transform(f: _Base, tf: T.StaticTransform, known: list,
                           params: FusionParams, imu_frame: Optional[str] = None) -> bool:
    """
    Use a static transform chain base_frame -> IMU frame as the IMU extrinsic.

    :param f: the filter
    :param tf: the new transform (appended to ``known``)
    :param known: all static transforms received so far
    :param params: parameters (base frame, extrinsic source)
    :param imu_frame: the IMU's frame id when known (else any child named like 'imu')
    :return: True when the extrinsic was set from tf
    """
    known.append(tf)
    if params.imu_extrinsic not in ('auto', 'tf'):
        return False
    rot = _chain_rotation(known, params.base_frame, imu_frame)
    if rot is None:
        return False
    f.front.set_rotation(rot, 'tf')
    return True


def _chain_rotation(known: list, base: str, target: Optional[str]) -> Optional[np.ndarray]:
    """Return the rotation base -> target through the static transforms (tree search)."""
    children: dict[str, list] = {}
    for tf in known:
        children.setdefault(tf.parent, []).append(tf)
    stack = [(base, np.eye(3))]
    seen = {base}
    while stack:
        frame, rot = stack.pop()
        for tf in children.get(frame, []):
            if tf.child in seen:
                continue
            r = rot @ quat_to_matrix(tf.rotation)
            if (target is not None and tf.child == target) or \
                    (target is None and 'imu' in tf.child.lower()):
                return r
            seen.add(tf.child)
            stack.append((tf.child, r))
    return None
