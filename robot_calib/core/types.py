# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Small immutable sample types shared by every core, the I/O layer and the nodes.

All quantities are SI: time ``t`` in seconds (float, from the message header
stamp), lengths in metres, angles in radians, rates in rad/s, accelerations in
m/s^2. ``stamp_ns`` keeps the exact integer header stamp (nanoseconds) so that
an output can carry the stamp of the input that produced it; it is -1 when a
sample was made without a message (then ``round(t * 1e9)`` is used).

Frames follow REP-103/105: x forward, y left, z up; planar yaw is wrapped to
(-pi, pi]. Vectors are numpy float64 arrays; quaternions are ``(w, x, y, z)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Optional, Union

import numpy as np


def _nan_cov(n: int) -> np.ndarray:
    return np.full((n, n), np.nan)


def stamp_of(t: float, stamp_ns: int = -1) -> int:
    """Return the integer header stamp (ns) for a sample time ``t`` (s)."""
    return int(stamp_ns) if stamp_ns >= 0 else int(round(t * 1e9))


@dataclass(frozen=True, slots=True)
class ImuSample:
    """
    One IMU reading: body rates (rad/s), specific force (m/s^2, gravity included).

    ``orientation`` (w, x, y, z) is filled only by estimators (sensor-to-world);
    ``*_cov`` are 3x3 covariances, NaN-filled when unknown (ROS: -1 in [0]).
    """

    t: float
    gyro: np.ndarray
    accel: np.ndarray
    frame_id: str = 'imu_link'
    orientation: Optional[np.ndarray] = None
    orientation_cov: Optional[np.ndarray] = None
    gyro_cov: Optional[np.ndarray] = None
    accel_cov: Optional[np.ndarray] = None
    stamp_ns: int = -1


@dataclass(frozen=True, slots=True)
class OdomSample:
    """
    Planar odometry: pose (m, m, rad) in ``frame_id``, twist (m/s, rad/s) in ``child_frame_id``.

    ``pose_cov`` and ``twist_cov`` are 3x3 covariances of (x, y, yaw) and
    (vx, vy, wz); NaN-filled when unknown. ``z``, ``roll`` and ``pitch`` are
    carried through for completeness (m, rad). ``orientation_norm`` is the norm
    of the message's quaternion before it was normalised (1 for a proper
    rotation, 0 when the driver left it unset) so that validation can tell a
    corrupt one.
    """

    t: float
    x: float
    y: float
    yaw: float
    vx: float = 0.0
    vy: float = 0.0
    wz: float = 0.0
    frame_id: str = 'odom'
    child_frame_id: str = 'base_link'
    pose_cov: np.ndarray = field(default_factory=lambda: _nan_cov(3))
    twist_cov: np.ndarray = field(default_factory=lambda: _nan_cov(3))
    z: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    stamp_ns: int = -1
    orientation_norm: float = 1.0


@dataclass(frozen=True, slots=True)
class ScanSample:
    """
    A planar laser scan: ranges (m) at ``angle_min + i * angle_increment`` (rad).

    Beams that returned nothing are NaN or inf, as real drivers publish them.
    """

    t: float
    angle_min: float
    angle_increment: float
    ranges: np.ndarray
    range_min: float = 0.05
    range_max: float = 30.0
    frame_id: str = 'laser'
    intensities: Optional[np.ndarray] = None
    time_increment: float = 0.0
    scan_time: float = 0.0
    stamp_ns: int = -1

    def angles(self) -> np.ndarray:
        """Return the angle of every beam (rad)."""
        return self.angle_min + self.angle_increment * np.arange(self.ranges.size)

    def beams(self, max_range: float = math.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Return the beams with a return: (indices, ranges m, angles rad), in beam order.

        A return lies in ``[max(range_min, 0), min(range_max, max_range)]`` (a
        ``range_max`` of 0 or less counts as unset). Beam ``i`` points at
        ``angle_min + i * angle_increment``, whatever the sign of the increment
        (a negative one: a lidar scanning clockwise, or mounted upside down).
        """
        r = np.asarray(self.ranges, dtype=float)
        hi = min(self.range_max, max_range) if self.range_max > 0 else max_range
        with np.errstate(invalid='ignore'):
            idx = np.flatnonzero(np.isfinite(r) & (r >= max(self.range_min, 0.0)) & (r <= hi))
        return idx, r[idx], self.angle_min + self.angle_increment * idx

    def beam_times(self, idx: np.ndarray) -> np.ndarray:
        """
        Return when beams ``idx`` were measured, in s after the stamp (rotating lidar).

        Beam ``i`` is measured at ``stamp + i * time_increment``; a negative
        ``time_increment`` lists the beams in the reverse order of measurement
        (the stamp is then the time of the last one measured).
        """
        return self.time_increment * np.asarray(idx, dtype=float)

    def time_span(self) -> tuple[float, float]:
        """Return the times (s) of the first and the last beam measured (stamp time if none)."""
        end = self.t + self.time_increment * max(self.ranges.size - 1, 0)
        return min(self.t, end), max(self.t, end)

    def points(self) -> np.ndarray:
        """Return the valid beams as an (N, 2) array of x, y (m) in the scan frame."""
        _, r, a = self.beams()
        return np.column_stack((r * np.cos(a), r * np.sin(a)))


@dataclass(frozen=True, slots=True)
class JointStateSample:
    """Joint positions (rad) and velocities (rad/s), by name; NaN where absent."""

    t: float
    names: tuple
    position: np.ndarray
    velocity: np.ndarray
    stamp_ns: int = -1

    def get(self, name: str) -> tuple[float, float]:
        """Return (position rad, velocity rad/s) of a joint, NaN when missing."""
        try:
            i = self.names.index(name)
        except ValueError:
            return float('nan'), float('nan')
        return float(self.position[i]), float(self.velocity[i])


@dataclass(frozen=True, slots=True)
class TwistSample:
    """A velocity command or twist: vx, vy (m/s), wz (rad/s); t from the bag when unstamped."""

    t: float
    vx: float
    vy: float = 0.0
    wz: float = 0.0
    stamp_ns: int = -1


@dataclass(frozen=True, slots=True)
class StampedTwistSample:
    """A stamped velocity command (geometry_msgs/TwistStamped): vx, vy (m/s), wz (rad/s)."""

    t: float
    vx: float
    vy: float = 0.0
    wz: float = 0.0
    stamp_ns: int = -1
    frame_id: str = 'base_link'


@dataclass(frozen=True, slots=True)
class NavSatSample:
    """A GNSS fix: latitude, longitude (deg), altitude (m), status (-1 no fix)."""

    t: float
    latitude: float
    longitude: float
    altitude: float
    status: int = 0
    position_cov: np.ndarray = field(default_factory=lambda: _nan_cov(3))
    frame_id: str = 'gps'
    stamp_ns: int = -1


@dataclass(frozen=True, slots=True)
class StaticTransform:
    """
    A transform parent -> child: translation (m) and rotation (w, x, y, z).

    Fixed on ``/tf_static`` (a mounting); on ``/tf`` the transform at time ``t``
    (s) of a moving frame, such as ``odom -> base_link``.
    """

    parent: str
    child: str
    translation: np.ndarray
    rotation: np.ndarray
    t: float = 0.0
    stamp_ns: int = -1


@dataclass(frozen=True, slots=True)
class BoolSample:
    """A latched boolean such as the fall alert."""

    t: float
    value: bool
    stamp_ns: int = -1


@dataclass(frozen=True, slots=True)
class DiagnosticStatus:
    """One diagnostic status: level 0 OK, 1 WARN, 2 ERROR, 3 STALE; values as strings."""

    name: str
    level: int
    message: str
    hardware_id: str = ''
    values: tuple = ()


@dataclass(frozen=True, slots=True)
class DiagnosticSample:
    """A diagnostic array at time ``t`` (s)."""

    t: float
    statuses: tuple
    stamp_ns: int = -1


@dataclass(frozen=True, slots=True)
class Pose2D:
    """A planar pose: x, y (m) and yaw (rad)."""

    x: float
    y: float
    yaw: float

    def as_array(self) -> np.ndarray:
        """Return ``[x, y, yaw]``."""
        return np.array([self.x, self.y, self.yaw])


Sample = Union[ImuSample, OdomSample, ScanSample, JointStateSample, TwistSample,
               NavSatSample, StaticTransform, BoolSample, DiagnosticSample]


def imu_samples(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray,
                frame_id: str = 'imu_link') -> list[ImuSample]:
    """Return IMU samples from arrays: times (N,) s, rates (N, 3) rad/s, force (N, 3) m/s^2."""
    g = np.asarray(gyro, dtype=float)
    a = np.asarray(accel, dtype=float)
    return [ImuSample(tk, g[k], a[k], frame_id)
            for k, tk in enumerate(np.asarray(t, dtype=float).tolist())]
