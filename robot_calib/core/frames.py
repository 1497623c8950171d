# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Sensor frames, handled once: mountings from static transforms, and scans to points.

A mounting is the static transform ``base_frame -> sensor frame`` (REP-105:
x forward, y left, z up; translation m, rotation quaternion w, x, y, z).
Every method takes its mountings through ``set_mounting`` of
:mod:`robot_calib.core.estimator` and turns them into what it needs here:
a planar sensor pose (x m, y m, yaw rad) for a lidar, a rotation matrix
(sensor -> base) for an IMU. A lidar mounted upside down (its z axis pointing
down: a roll or pitch of pi) measures its beam at angle ``a`` along ``-a`` of
the same planar pose, so its scans are :func:`mirrored` before use.

:func:`scan_points` is the one way a laser scan becomes points: valid beams
(:meth:`robot_calib.core.types.ScanSample.beams`), optionally moved into the
base frame by the sensor pose, optionally de-skewed by the motion during the
scan (a rotating lidar measures beam ``i`` at ``stamp + i * time_increment``).

The other way, a planar pose becomes the transform a ``/tf`` entry carries
(:func:`pose_transform`), and a drift-corrected pose the REP-105 correction
``map -> odom`` (:func:`map_to_odom`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Optional, Sequence

import numpy as np
from robot_calib.core.geometry import (matrix_to_quat, quat_from_rpy, quat_to_matrix, se2_compose,
                                       se2_inverse, yaw_from_quat)
from robot_calib.core.types import OdomSample, ScanSample, StaticTransform


def planar_pose(transform: StaticTransform) -> tuple[float, float, float]:
    """Return the planar pose (x m, y m, yaw rad) of a mounting in the base frame."""
    return (float(transform.translation[0]), float(transform.translation[1]),
            float(yaw_from_quat(np.asarray(transform.rotation, dtype=float))))


def rotation_matrix(transform: StaticTransform) -> np.ndarray:
    """Return the 3x3 rotation sensor -> base of a mounting."""
    return quat_to_matrix(np.asarray(transform.rotation, dtype=float))


class StaticTree:
    """
    The static transforms seen so far, kept as tf keeps them: one parent per frame.

    :meth:`mounting` gives a sensor's mounting in the base frame through any chain
    of links (URDFs often put a sensor below a mount or plate link), composed from
    the base down; a direct link is returned as received.
    """

    MAX_DEPTH = 32
    """Longest chain followed (a longer one is taken as a cycle)."""

    def __init__(self) -> None:
        """Start with no transform."""
        self.by_child: dict[str, StaticTransform] = {}

    def add(self, transform: StaticTransform) -> None:
        """Keep ``transform`` (replacing an earlier one to the same child frame)."""
        self.by_child[transform.child] = transform

    def leaves(self) -> list[str]:
        """Return the child frames that are no frame's parent, in the order first seen."""
        parents = {tf.parent for tf in self.by_child.values()}
        return [child for child in self.by_child if child not in parents]

    def mounting(self, frame: str, base: Optional[str] = None) -> Optional[StaticTransform]:
        """
        Return the transform ``base -> frame`` through the tree, or None.

        Along the chain of parents when ``base`` is on it; through their common
        top when ``base`` sits on another branch (``base_footprint -> base_link``
        and ``base_footprint -> imu_link``); from the top of the frame's chain when
        ``base`` is None or in no transform at all (a tree whose body frame has
        another name). None when ``frame`` has no transform, or ``base`` is in a
        tree of its own.
        """
        chain = self._chain(frame, base)
        if chain is None:
            return None
        top = chain[-1].parent
        if base is not None and top != base:
            if self._known(base):
                up = self._chain(base, None)
                if up is None or up[-1].parent != top:
                    return None
                rot_b, pos_b = _compose(up)
                rot_f, pos_f = _compose(chain)
                rot = rot_b.T @ rot_f
                return StaticTransform(base, frame, rot_b.T @ (pos_f - pos_b),
                                       matrix_to_quat(rot), chain[0].t, chain[0].stamp_ns)
        if len(chain) == 1:
            return chain[0]
        rot, pos = _compose(chain)
        return StaticTransform(top, frame, pos, matrix_to_quat(rot), chain[0].t,
                               chain[0].stamp_ns)

    def _known(self, frame: str) -> bool:
        """Return True when ``frame`` is the parent or the child of a transform kept."""
        return frame in self.by_child or any(tf.parent == frame for tf in self.by_child.values())

    def _chain(self, frame: str, base: Optional[str]) -> Optional[list[StaticTransform]]:
        """Return the transforms from ``frame`` up to ``base`` or the top (child first)."""
        chain: list[StaticTransform] = []
        f = frame
        while f != base:
            tf = self.by_child.get(f)
            if tf is None:
                break
            if len(chain) >= self.MAX_DEPTH:
                return None
            chain.append(tf)
            f = tf.parent
        return chain or None


SENSOR_WORDS = {'imu': ('imu',), 'lidar': ('laser', 'scan', 'lidar')}
"""What a frame's name contains when it is a sensor of each kind (lower case)."""


@dataclasses.dataclass(frozen=True)
class FoundMounting:
    """
    What :func:`find_mounting` found: the transform (None: no mounting known) and what to say.

    ``frame`` is the frame whose transform is used (the sensor's own, or the one
    taken in its place); ``note`` is '' when the sensor's frame was found as named
    (or is the base frame itself), else the sentence a summary and the
    diagnostics say.
    """

    transform: Optional[StaticTransform]
    frame: str
    note: str


def find_mounting(tree: StaticTree, frame: str, base: Optional[str], kind: str,
                  fallback: str) -> FoundMounting:
    """
    Return the mounting of a sensor whose messages name ``frame``: the one rule of every node.

    1. ``frame`` is ``base``, or a frame other frames hang from but which has no
       mounting itself (the top of the tree: the data are in a body frame
       already): no transform, nothing to say.
    2. ``frame`` (or it without a leading ``/``) is in the tree and reaches
       ``base`` (:meth:`StaticTree.mounting`): its transform.
    3. Otherwise, when the tree holds exactly one frame of the sensor's ``kind``
       (a leaf whose name contains one of :data:`SENSOR_WORDS`) reaching ``base``,
       that frame's transform, saying so: a driver and a URDF that name the
       same sensor differently (``imu`` and ``imu_link``).
    4. Otherwise no mounting is known (None), saying so and what the method does
       instead (``fallback``, e.g. 'taken at base_link'); with no static
       transform at all as well.

    :param base: the base frame, or None for the top of the sensor's chain
    :param kind: 'imu' or 'lidar'
    """
    if base is not None and frame == base:
        return FoundMounting(None, frame, '')
    for name in (frame, frame.lstrip('/')):
        if name:
            found = tree.mounting(name, base)
            if found is not None:
                return FoundMounting(found, name, '')
    if frame and any(tf.parent == frame for tf in tree.by_child.values()):
        return FoundMounting(None, frame, '')  # a body frame (the top of the tree): no mounting
    what = 'IMU' if kind == 'imu' else kind
    shown = repr(frame) if frame else '(empty)'
    if not tree.by_child:
        return FoundMounting(None, frame, f'{what} frame {shown}: no static transform '
                                          f'(/tf_static) known, no mounting: {fallback}')
    words = SENSOR_WORDS[kind]
    candidates = [leaf for leaf in tree.leaves()
                  if any(w in leaf.lower() for w in words) and tree.mounting(leaf, base)]
    if len(candidates) == 1:
        leaf = candidates[0]
        found = tree.mounting(leaf, base)
        return FoundMounting(found, leaf, f'{what} frame {shown} is not in /tf_static: using '
                                          f'its only {what} frame {leaf!r} '
                                          f'({found.parent} -> {leaf})')
    there = ', '.join(repr(c) for c in candidates[:4]) if candidates else f'no {what} frame'
    return FoundMounting(None, frame, f'{what} frame {shown} is not in /tf_static ({there} '
                                      f'there): no mounting known, {fallback}')


def _compose(chain: list[StaticTransform]) -> tuple[np.ndarray, np.ndarray]:
    """Return the rotation and translation of a chain (child first) composed from its top."""
    rot, pos = np.eye(3), np.zeros(3)
    for tf in reversed(chain):
        pos = pos + rot @ np.asarray(tf.translation, dtype=float)
        rot = rot @ rotation_matrix(tf)
    return rot, pos


def upside_down(transform: StaticTransform) -> bool:
    """Return True when the mounted sensor's z axis points down in the base frame."""
    return float(rotation_matrix(transform)[2, 2]) < 0.0


def mirrored(scan: ScanSample) -> ScanSample:
    """Return the scan of an upside-down lidar as an upright one at its planar pose sees it."""
    return dataclasses.replace(scan, angle_min=-scan.angle_min,
                               angle_increment=-scan.angle_increment)


MAX_BEAMS = 4096
"""Most beams a scan keeps: a denser one is thinned (:func:`thinned`) before any method.

Planar lidars give 360 to about 3,200 beams a turn (1,081 and 1,141 for the
common 0.25 deg scanners); a scan made from a 3D lidar or a depth camera can
give 100,000. Every method here works on a few thousand at most; memory and
time then stay those of such a scan whatever the beam count."""


def thinned(scan: ScanSample, max_beams: int = MAX_BEAMS) -> ScanSample:
    """
    Return ``scan`` with one beam in ``k`` kept when it has more than ``max_beams``.

    ``k = ceil(n / max_beams)``: beams ``0, k, 2k ...`` over the whole field of
    view (the angle and time increments times ``k``); a scan of ``max_beams``
    or fewer is returned as it is.
    """
    n = scan.ranges.size
    if n <= max_beams:
        return scan
    k = -(-n // max_beams)
    inten = scan.intensities
    return dataclasses.replace(
        scan, ranges=np.ascontiguousarray(scan.ranges[::k]),
        angle_increment=scan.angle_increment * k, time_increment=scan.time_increment * k,
        intensities=None if inten is None or np.size(inten) != n
        else np.ascontiguousarray(np.asarray(inten)[::k]))


def pose_transform(parent: str, child: str, pose: Sequence[float], t: float,
                   stamp_ns: int = -1) -> StaticTransform:
    """
    Return the transform ``parent -> child`` of a planar pose of ``child`` in ``parent``.

    ``pose`` is (x m, y m, yaw rad); the transform has z = 0 and a rotation about
    z only (REP-103), stamped ``t`` (s) or exactly ``stamp_ns`` (ns) when >= 0.
    """
    x, y, yaw = (float(v) for v in pose)
    return StaticTransform(parent, child, np.array([x, y, 0.0]), quat_from_rpy(0.0, 0.0, yaw),
                           t, stamp_ns)


def map_to_odom(corrected: Sequence[float], odom: Sequence[float]) -> np.ndarray:
    """
    Return the correction ``map -> odom`` (x m, y m, yaw rad) of a drift-corrected pose.

    ``corrected`` is the robot's pose in the corrected (map) frame and ``odom``
    its odometry pose at the same time: T_map_odom = T_map_base (+) T_odom_base^-1
    (REP-105: the map frame's pose estimate published as the transform to odom).
    """
    return se2_compose(corrected, se2_inverse(odom))


def correction_transform(corrected: OdomSample, odom: OdomSample) -> StaticTransform:
    """
    Return the ``/tf`` entry ``corrected.frame_id -> odom.frame_id`` of the correction.

    ``corrected`` and ``odom`` are poses of the same body at the same stamp (the
    corrected output and the odometry input that produced it); an odometry
    without a frame name is taken as ``odom``.
    """
    pose = map_to_odom((corrected.x, corrected.y, corrected.yaw), (odom.x, odom.y, odom.yaw))
    return pose_transform(corrected.frame_id, odom.frame_id or 'odom', pose, corrected.t,
                          corrected.stamp_ns)


class ConstantMotion:
    """
    A robot at constant forward speed ``v`` (m/s) and yaw rate ``w`` (rad/s) during one scan.

    ``vy`` (m/s) is a sideways speed (a holonomic robot's; 0 otherwise). Called
    with times after the stamp (s) it gives the poses (N, 3) relative to the pose
    at the stamp, to first order (``(v dt, vy dt, w dt)``); :meth:`apply` de-skews
    points with it directly.
    """

    def __init__(self, v: float, w: float, vy: float = 0.0):
        """Keep the speeds (m/s) and the yaw rate (rad/s)."""
        self.v = float(v)
        self.w = float(w)
        self.vy = float(vy)

    def __call__(self, dt: np.ndarray) -> np.ndarray:
        """Return the relative poses (N, 3) at times ``dt`` (s) after the stamp."""
        dt = np.asarray(dt, dtype=float)
        return np.column_stack((self.v * dt, self.vy * dt, self.w * dt))

    def apply(self, points: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """Return ``R(w dt) p + (v, vy) dt``: points measured ``dt`` s after the stamp, at it."""
        return np.column_stack(self._apply_xy(points[:, 0], points[:, 1], dt))

    def _apply_xy(self, x: np.ndarray, y: np.ndarray, dt: np.ndarray) -> tuple:
        """Return :meth:`apply` of points given as x and y arrays (m), as x and y arrays."""
        th = self.w * dt
        c, s = np.cos(th), np.sin(th)
        if self.vy:
            return c * x - s * y + self.v * dt, s * x + c * y + self.vy * dt
        return c * x - s * y + self.v * dt, s * x + c * y


def constant_motion(v: float, w: float, vy: float = 0.0) -> ConstantMotion:
    """Return the motion at constant speeds ``v``, ``vy`` (m/s) and yaw rate ``w`` (rad/s)."""
    return ConstantMotion(v, w, vy)


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
    x, y = r * np.cos(ang), r * np.sin(ang)
    if sensor_pose is not None and len(x):
        # deskew() with one pose for every point, its cosine and sine computed once
        px, py, yaw = (float(v) for v in sensor_pose)
        c, s = np.cos(np.float64(yaw)), np.sin(np.float64(yaw))
        x, y = px + c * x - s * y, py + s * x + c * y
    if motion is not None and len(x) and scan.time_increment != 0.0 \
            and math.isfinite(scan.time_increment):
        dt = scan.beam_times(idx)
        if isinstance(motion, ConstantMotion):
            x, y = motion._apply_xy(x, y, dt)
        else:
            return deskew(np.column_stack((x, y)), motion(dt)), idx
    return np.column_stack((x, y)), idx
