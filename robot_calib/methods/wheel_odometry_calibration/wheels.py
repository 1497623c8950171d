# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The wheel data of a calibration drive: positions, their steps and the nominal odometry.

A traction or wheel position that jumps by about 2 pi is unwrapped (using
the joint velocity when present), a steering reading is wrapped to (-pi, pi].
Only the recent part of the drive is kept (8 bytes a value): each key-frame
scan takes the wheel samples around it along (:class:`WheelWindow`) for the
final re-deskew, so memory does not grow with the length of the drive.
"""

from __future__ import annotations

from array import array
import bisect
from dataclasses import dataclass
import math
from typing import Any, Callable, Optional

import numpy as np
from robot_calib.core import kinematics as K
from robot_calib.core.geometry import wrap_angle
from robot_calib.core.series import Rows

TRIM_MARGIN = 10.0
"""Wheel data kept before the oldest time still needed (s): scans that arrive late."""
TRIM_MIN_SAMPLES = 4096
"""Samples dropped at once at least (the deletion moves the rest of the arrays)."""


@dataclass(frozen=True)
class WheelWindow:
    """
    The wheel samples around one scan: times (s) and positions (rad), one before and after.

    What the re-deskew of that scan needs once the history has moved on.
    """

    t: np.ndarray
    a: np.ndarray
    b: np.ndarray


class WheelHistory:
    """
    Wheel positions of one drive type and the odometry they integrate to.

    Differential drive: (phi_l, phi_r) (rad); steered drive wheel: (traction
    rad, steering reading rad). ``x_nom`` holds the nominal parameters in
    :func:`robot_calib.methods.wheel_odometry_calibration.params.keys_of`
    order (read, never written).
    """

    def __init__(self, drive: str, x_nom: np.ndarray, max_wheel_gap: float):
        """Start an empty history for ``drive``; steps over gaps > ``max_wheel_gap`` (s) fail."""
        self.drive = drive
        self.x_nom = x_nom
        self.max_wheel_gap = max_wheel_gap
        self.t, self.a, self.b = array('d'), array('d'), array('d')
        self.pose = Rows(3)
        self._last_raw: Optional[tuple] = None
        self._last_pose = (0.0, 0.0, 0.0)

    def _step_pose(self, da: float, b0: float, b1: float) -> tuple[float, float, float]:
        """Return the nominal base motion of one wheel step (floats: a few per sample)."""
        x = self.x_nom
        if self.drive == 'differential':          # K.diff_arc, K.steered_arc for one step
            dl, dr = float(x[0]) * da, float(x[1]) * (b1 - b0)
            ds, dth = 0.5 * (dr + dl), (dr - dl) / float(x[2])
        else:
            alpha = float(x[1]) * (0.5 * (b0 + b1)) + float(x[0])
            dw = float(x[2]) * da
            ds, dth = dw * math.cos(alpha), dw * math.sin(alpha) / float(x[3])
        return K.arc_pose_scalar(ds, dth)

    def add(self, t: float, a: float, b: float, va: float = math.nan,
            vb: float = math.nan) -> int:
        """
        Add one wheel sample; return how many of its positions were unwrapped (0 to 2).

        :param t: time (s)
        :param a: left wheel / traction joint position (rad)
        :param b: right wheel position / steering reading (rad)
        :param va: velocity of ``a`` (rad/s, NaN when unknown), used to unwrap
        :param vb: velocity of ``b`` (rad/s, NaN when unknown)
        """
        if self.drive == 'steered_wheel':
            b = wrap_angle(b)
        if self._last_raw is None:
            self.t.append(t)
            self.a.append(a)
            self.b.append(b)
            self._last_pose = (0.0, 0.0, 0.0)
            self.pose.append(self._last_pose)
            self._last_raw = (t, a, b)
            return 0
        t0, a0, b0 = self._last_raw
        da, ka = _unwrap(a - a0, va, t - t0)
        db, kb = _unwrap(b - b0, vb, t - t0) if self.drive == 'differential' else (0.0, 0)
        self._last_raw = (t, a, b)
        na = self.a[-1] + da
        nb = self.b[-1] + db if self.drive == 'differential' else b
        step = self._step_pose(da, self.b[-1], nb)
        self._last_pose = K.compose_scalar(self._last_pose, step)
        self.pose.append(self._last_pose)
        self.t.append(t)
        self.a.append(na)
        self.b.append(nb)
        return int(ka != 0) + int(kb != 0)

    def virtual_rotations(self, rel: np.ndarray, nominal: dict) -> tuple[float, float]:
        """
        Return the wheel positions (rad) after a base motion ``rel`` (m, m, rad) (odometry).

        The nominal geometry inverts the motion into wheel rotations (so the
        nominal parameters must be those the odometry source uses).
        """
        dth = wrap_angle(rel[2])
        chord = math.hypot(rel[0], rel[1])
        arc = 1.0 if abs(dth) < 1e-9 else (dth / 2) / math.sin(dth / 2)
        ds = math.copysign(chord, rel[0]) * arc
        n = nominal
        if self.drive == 'differential':
            dl = (ds - n['track_width'] * dth / 2) / n['left_wheel_radius']
            dr = (ds + n['track_width'] * dth / 2) / n['right_wheel_radius']
            return self.a[-1] + dl, self.b[-1] + dr
        lat = n['wheel_base'] * dth
        dw = math.copysign(math.hypot(ds, lat), ds if ds != 0 else 1.0)
        if abs(dw) < 1e-12:
            reading = self.b[-1]
        else:
            alpha = math.atan2(lat / dw, ds / dw)
            reading = (alpha - n['steering_offset']) / n['steering_scale']
        return self.a[-1] + dw / n['wheel_radius'], reading

    def odom_at(self, t: float) -> tuple[np.ndarray, int]:
        """Return the nominal odometry pose interpolated at ``t`` and the sample index after."""
        i = bisect.bisect_left(self.t, t)
        if i == 0:
            return self.pose[0].copy(), 0
        if i >= len(self.t):
            return self.pose[-1].copy(), len(self.t) - 1
        t0, t1 = self.t[i - 1], self.t[i]
        w = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        p0, p1 = self.pose[i - 1], self.pose[i]
        return p0 + w * (p1 - p0), i

    def _wheel_at(self, t: float) -> tuple[float, float]:
        i = min(max(bisect.bisect_left(self.t, t), 1), len(self.t) - 1)
        t0, t1 = self.t[i - 1], self.t[i]
        w = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        a = self.a[i - 1] + w * (self.a[i] - self.a[i - 1])
        b = self.b[i - 1] + w * (self.b[i] - self.b[i - 1])
        return a, b

    def steps(self, t0: float, t1: float) -> Optional[np.ndarray]:
        """Return the wheel steps between t0 and t1 (s) (None over a data gap)."""
        i0, i1 = bisect.bisect_right(self.t, t0), bisect.bisect_left(self.t, t1)
        times = np.concatenate(([t0], self.t[i0:i1], [t1]))
        if np.max(np.diff(times)) > self.max_wheel_gap:
            return None
        a0, b0 = self._wheel_at(t0)
        a1, b1 = self._wheel_at(t1)
        aa = np.concatenate(([a0], self.a[i0:i1], [a1]))
        bb = np.concatenate(([b0], self.b[i0:i1], [b1]))
        if self.drive == 'differential':
            return np.column_stack((np.diff(aa), np.diff(bb)))
        return np.column_stack((np.diff(aa), 0.5 * (bb[1:] + bb[:-1])))

    def window(self, scan: Any) -> WheelWindow:
        """Return the samples around ``scan`` (first beam to last, one more on each side)."""
        lo, hi = self._around(scan)
        return WheelWindow(np.asarray(self.t[lo:hi]), np.asarray(self.a[lo:hi]),
                           np.asarray(self.b[lo:hi]))

    def _around(self, scan: Any) -> tuple[int, int]:
        """Return the index range of the samples around ``scan``'s beams."""
        first, last = scan.time_span()
        return (max(bisect.bisect_left(self.t, first) - 1, 0),
                bisect.bisect_right(self.t, last) + 1)

    def trim_before(self, t: float) -> int:
        """
        Forget samples older than ``t`` - ``TRIM_MARGIN`` (s), keeping one before; return how many.

        Nothing is dropped until at least ``TRIM_MIN_SAMPLES`` can go at once.
        """
        k = bisect.bisect_left(self.t, t - TRIM_MARGIN) - 1
        if k < TRIM_MIN_SAMPLES:
            return 0
        del self.t[:k], self.a[:k], self.b[:k]
        self.pose.drop_first(k)
        return k

    def sensor_motion_during(self, scan: Any, sensor_pose: np.ndarray,
                             ) -> Callable[[np.ndarray], np.ndarray]:
        """Return the sensor's motion during ``scan`` by the nominal odometry (:func:`motion`)."""
        lo, hi = self._around(scan)
        return motion(scan, np.asarray(self.t[lo:hi]), self.pose[lo:hi], sensor_pose)


def integrate(drive: str, a: np.ndarray, b: np.ndarray, x: np.ndarray) -> np.ndarray:
    """
    Return the odometry poses (N, 3) (m, m, rad) of wheel positions ``a``, ``b`` under ``x``.

    ``x`` holds the parameters in :func:`keys_of` order; the first pose is the origin.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if drive == 'differential':
        ds, dth = K.diff_arc(np.diff(a), np.diff(b), x[0], x[1], x[2])
    else:
        ds, dth = K.steered_arc(np.diff(a), 0.5 * (b[1:] + b[:-1]), x[2], x[3], x[0], x[1])
    arcs = K.arc_pose(ds, dth)
    # p_k+1 = p_k (+) arc_k: the heading is a running sum, each arc turned by the one before
    poses = np.zeros((len(arcs) + 1, 3))
    poses[1:, 2] = np.cumsum(arcs[:, 2])
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    poses[1:, 0] = np.cumsum(c * arcs[:, 0] - s * arcs[:, 1])
    poses[1:, 1] = np.cumsum(s * arcs[:, 0] + c * arcs[:, 1])
    return poses


def motion(scan: Any, times: np.ndarray, poses: np.ndarray, sensor_pose: np.ndarray,
           ) -> Callable[[np.ndarray], np.ndarray]:
    """
    Return the sensor's motion during ``scan`` for :func:`robot_calib.core.frames.scan_points`.

    The returned function maps times after the stamp (s) to the sensor poses
    (N, 3) (m, m, rad) relative to the sensor at the stamp, from the odometry
    ``poses`` (N, 3) at ``times`` (N,) (samples around the scan) interpolated
    at each time and the sensor pose (x m, y m, yaw rad) in base_link.
    """
    lx, ly, lyaw = (float(v) for v in sensor_pose)
    cl, sl = math.cos(lyaw), math.sin(lyaw)

    def during(dt: np.ndarray) -> np.ndarray:
        ti = scan.t + dt
        x0, y0, yaw0 = (float(np.interp(scan.t, times, poses[:, j])) for j in range(3))
        # odometry at each beam time relative to the stamp: a0^-1 (+) a(t), a0 at the stamp
        c0, s0 = math.cos(yaw0), math.sin(yaw0)
        dx, dy = np.interp(ti, times, poses[:, 0]) - x0, np.interp(ti, times, poses[:, 1]) - y0
        rx, ry = c0 * dx + s0 * dy, c0 * dy - s0 * dx
        ryaw = np.interp(ti, times, poses[:, 2]) - yaw0
        # the sensor's own motion l^-1 (+) rel (+) l (kinematics.sensor_motion, expanded)
        c, s = np.cos(ryaw), np.sin(ryaw)
        qx, qy = rx + c * lx - s * ly - lx, ry + s * lx + c * ly - ly
        out = np.empty((len(ti), 3))
        out[:, 0] = cl * qx + sl * qy
        out[:, 1] = cl * qy - sl * qx
        out[:, 2] = ryaw
        return out
    return during


def _unwrap(d: float, v: float, dt: float) -> tuple[float, int]:
    """Return a position step (rad) without its whole turns, and the turns removed."""
    two_pi = 2 * math.pi
    if math.isfinite(v):
        k = round((d - v * dt) / two_pi)
    else:
        k = round(d / two_pi) if abs(d) > math.pi else 0
    return d - k * two_pi, k
