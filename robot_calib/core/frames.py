# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Sensor frames, handled once: mountings from static transforms, and scans to points.

A mounting is the static transform ``base_frame -> sensor frame`` (REP-105:
x forward, y left, z up; translation m, rotation quaternion w, x, y, z).
Every method takes its mountings through ``set_mounting`` of
:mod:`robot_calib.core.estimator` and turns them into what it needs here:
a planar sensor pose (x m, y m, yaw rad) for a lidar, a rotation matrix
(sensor -> base) for an IMU.

:func:`scan_points` is the one way a laser scan becomes points: valid beams
(:meth:`robot_calib.core.types.ScanSample.beams`), optionally moved into the
base frame by the sensor pose, optionally de-skewed by the motion during the
scan (a rotating lidar measures beam ``i`` at ``stamp + i * time_increment``).
"""

from __future__ import annotations

import math
from typing import Callable, Optional, Sequence

import numpy as np
from robot_calib.core.geometry import quat_to_matrix, yaw_from_quat
from robot_calib.core.types import ScanSample, StaticTransform


def planar_pose(transform: StaticTransform) -> tuple[float, float, float]:
    """Return the planar pose (x m, y m, yaw rad) of a mounting in the base frame."""
    return (float(transform.translation[0]), float(transform.translation[1]),
            float(yaw_from_quat(np.asarray(transform.rotation, dtype=float))))


def rotation_matrix(transform: StaticTransform) -> np.ndarray:
    """Return the 3x3 rotation sensor -> base of a mounting."""
    return quat_to_matrix(np.asarray(transform.rotation, dtype=float))


class ConstantMotion:
    """
    A robot at constant forward speed ``v`` (m/s) and yaw rate ``w`` (rad/s) during one scan.

    Called with times after the stamp (s) it gives the poses (N, 3) relative to
    the pose at the stamp, to first order (``(v dt, 0, w dt)``); :meth:`apply`
    de-skews points with it directly.
    """

    def __init__(self, v: float, w: float):
        """Keep the speed (m/s) and yaw rate (rad/s)."""
        self.v = float(v)
        self.w = float(w)

    def __call__(self, dt: np.ndarray) -> np.ndarray:
        """Return the relative poses (N, 3) at times ``dt`` (s) after the stamp."""
        dt = np.asarray(dt, dtype=float)
        return np.column_stack((self.v * dt, np.zeros_like(dt), self.w * dt))

    def apply(self, points: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """Return ``R(w dt) p + (v dt, 0)``: points measured ``dt`` s after the stamp, at it."""
        th = self.w * dt
        c, s = np.cos(th), np.sin(th)
        x, y = points[:, 0], points[:, 1]
        return np.column_stack((c * x - s * y + self.v * dt, s * x + c * y))


def constant_motion(v: float, w: float) -> ConstantMotion:
    """Return the motion of a robot at constant speed ``v`` (m/s) and yaw rate ``w`` (rad/s)."""
    return ConstantMotion(v, w)


def deskew(points: np.ndarray, relative: np.ndarray) -> np.ndarray:
    """
    Move points into the frame at the stamp: ``R(th_i) p_i + (x_i, y_i)``.

    ``points`` (N, 2) are each expressed in the frame at the moment it was
    measured, ``relative`` (N, 3) is that frame's pose (x m, y m, yaw rad) in
    the frame at the stamp.
    """
    c, s = np.cos(relative[:, 2]), np.sin(relative[:, 2])
    x, y = points[:, 0], points[:, 1]
    return np.column_stack((relative[:, 0] + c * x - s * y, relative[:, 1] + s * x + c * y))


def scan_points(scan: ScanSample, sensor_pose: Optional[Sequence[float]] = None,
                max_range: float = math.inf,
                motion: Optional[Callable[[np.ndarray], np.ndarray]] = None,
                ) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the valid beams of ``scan`` as points (N, 2) (m) and their beam indices.

    With ``sensor_pose`` (x m, y m, yaw rad of the sensor in the base frame) the
    points are in the base frame, else in the sensor frame. With ``motion``
    (times after the stamp s -> poses (N, 3) of that same frame relative to the
    stamp, see :func:`constant_motion`) and beam times (``time_increment`` not
    0), each point is de-skewed into the frame at the stamp.
    """
    idx, r, ang = scan.beams(max_range)
    pts = np.column_stack((r * np.cos(ang), r * np.sin(ang)))
    if sensor_pose is not None and len(pts):
        x, y, yaw = (float(v) for v in sensor_pose)
        pts = deskew(pts, np.broadcast_to(np.array([x, y, yaw]), (len(pts), 3)))
    if motion is not None and len(pts) and scan.time_increment != 0.0 \
            and math.isfinite(scan.time_increment):
        dt = scan.beam_times(idx)
        pts = motion.apply(pts, dt) if isinstance(motion, ConstantMotion) else deskew(
            pts, motion(dt))
    return pts, idx
