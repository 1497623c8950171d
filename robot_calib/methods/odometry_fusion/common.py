# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What both fusion filters share: their output and result types, and input helpers.

Both variants (:mod:`.seed` and :mod:`.improved`) are
:class:`robot_calib.core.estimator.Estimator` s fed with time-ordered core
samples: ``ImuSample``, ``OdomSample`` (wheel odometry), ``JointStateSample``
(wheel joints, :func:`wheel_twist`) and :class:`LidarOdomSample` (a lidar
odometry pose, only for the seed's distance accuracy check,
:func:`lidar_accuracy`). ``update`` returns a :class:`FusionOutput` when the
sample produced an estimate, a :class:`Rejected` when the sample was not used,
or None. ``result`` returns a :class:`FusionResult`.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping, Optional

import numpy as np
from robot_calib.core import types as T
from robot_calib.methods.odometry_fusion.params import FusionParams


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


@dataclass(frozen=True)
class LidarOdomSample:
    """A lidar odometry pose (m) for the seed's distance accuracy check."""

    odom: T.OdomSample


@dataclass(frozen=True)
class Rejected:
    """What :meth:`update` returns for a sample it did not use, with the reason."""

    reason: str


@dataclass(frozen=True)
class FusionOutput:
    """
    One fused estimate: pose, twist and their 3x3 covariances, at time ``t`` (s).

    ``v`` is the forward speed, ``v_lateral`` the sideways one (m/s, base_link y: a
    holonomic robot's, 0 for wheels that cannot slide sideways).
    """

    t: float
    x: float
    y: float
    yaw: float
    v: float
    w: float
    pose_cov: np.ndarray
    twist_cov: np.ndarray
    v_lateral: float = 0.0


def from_odometry(sample: Any, output: Any) -> bool:
    """
    Tell whether ``output`` is an estimate made by a wheel input (a ``keep`` of run_batch).

    Keeps one estimate per accepted odometry or joint-state sample, leaving out
    the IMU dead-reckoning estimates made while the odometry is silent.
    """
    return isinstance(output, FusionOutput) and \
        isinstance(sample, (T.OdomSample, T.JointStateSample))


@dataclass(frozen=True)
class NisStats:
    """Consistency of the improved filter's odometry updates (normalised innovation squared)."""

    updates: int
    """Odometry updates that used at least one channel."""
    total: float
    """Sum of their NIS (exact, for the mean)."""
    last: float
    """NIS of the latest update (nan before any)."""
    average: float
    """Moving average over ``window`` updates (nan until the window is full)."""
    window: int
    """Updates in the moving average."""
    band: tuple[float, float]
    """Two-sided 95 % band of that moving average (nan, nan until the window is full)."""
    in_band: int
    """Updates whose NIS was inside its own two-sided 95 % band..."""
    checked: int
    """...out of this many."""
    window_in_band: int
    """Moving averages inside their band..."""
    window_checked: int
    """...out of this many."""
    history: tuple[float, ...]
    """NIS of every ``history_stride``-th update (thinned to a bounded size, for plots)."""
    history_stride: int
    """Updates between two items of ``history``."""

    @property
    def mean(self) -> Optional[float]:
        """Return the mean NIS of all updates (None before any)."""
        return self.total / self.updates if self.updates else None

    @property
    def in_band_fraction(self) -> Optional[float]:
        """Return the fraction of updates with the NIS in its band (None before any)."""
        return self.in_band / self.checked if self.checked else None

    @property
    def window_in_band_fraction(self) -> Optional[float]:
        """Return the fraction of moving averages in their band (None before any)."""
        return self.window_in_band / self.window_checked if self.window_checked else None

    @property
    def average_in_band(self) -> bool:
        """Tell whether the moving average is in its band (True while it is unknown)."""
        return not math.isfinite(self.average) or \
            self.band[0] <= self.average <= self.band[1]


@dataclass(frozen=True)
class FusionResult:
    """Everything a fusion filter has estimated and counted so far."""

    mode: str
    """The variant: ``seed`` or ``improved``."""
    t: Optional[float]
    """Filter time (s), None before the first sample."""
    state: np.ndarray
    """State vector (see the variant's module for its layout)."""
    covariance: np.ndarray
    """Its covariance."""
    estimates: Mapping[str, float]
    """Named estimates (biases, scales and their standard deviations; seed: velocity)."""
    imu_extrinsic: str
    """Source of the IMU mounting: none, param, tf or gravity."""
    imu_rotation: Optional[np.ndarray]
    """IMU -> base_link rotation (3x3), None until known."""
    imu_forward_known: bool
    """Whether the IMU's forward axis is known (else only its up axis: no accelerometer)."""
    accel_units: str
    """IMU acceleration units: mps2, g, detected_mps2, detected_g, unknown or pending."""
    counts: Mapping[str, int]
    """Filter counters (rejections by channel, gaps, re-initialisations...)."""
    warnings: tuple[tuple[float, str], ...]
    """Recent warnings as (time s, message), the latest last."""
    path_length: float
    """Distance travelled by the fused estimate (m)."""
    lidar_accuracy: float
    """Seed's accuracy of the fused distance against the lidar's (nan without lidar)."""
    lidar_valid: bool
    """Whether that accuracy passes the seed's threshold (0.95)."""
    noise_scales: Optional[tuple[float, float]] = None
    """Improved: adapted noise scale of the speed and yaw-rate channels."""
    nis: Optional[NisStats] = None
    """Improved: consistency of the odometry updates."""
    imu_stale: Optional[bool] = None
    """Improved: whether the IMU is silent (propagation by the wheels only)."""
    yaw_rate_fit: Optional[Mapping[str, Any]] = None
    """Improved: the odometry yaw-rate calibration over the recording (status, blocks...)."""
    odometry_state: Optional[np.ndarray] = None
    """Seed: the odometry state observed (x, y, vx, vy, ax, ay by integration)."""
    odometry_covariance: Optional[np.ndarray] = None
    """Seed: its covariance ``P_o``."""
