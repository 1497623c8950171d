# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Planar wheel kinematics of the two drive types that wheel calibration handles.

Differential drive
    ``base_link`` midway between the two driven wheels, x forward. A step with
    wheel rotations ``dphi_l``, ``dphi_r`` (rad) moves the base by
    ``ds = (r_r dphi_r + r_l dphi_l) / 2`` along its arc and turns it by
    ``dtheta = (r_r dphi_r - r_l dphi_l) / b`` (``b`` track width, m).

Steered drive wheel (tricycle, AGV "steering wheel")
    ``base_link`` at the middle of the fixed (rear) axle, x forward. The
    steered traction wheel sits at ``(wheel_base, 0)`` in ``base_link``. Its
    true steering angle is ``alpha = steering_scale * reading +
    steering_offset`` (rad, counter-clockwise positive seen from above; the
    contract's sign convention: true = reading + offset for a unit scale).
    The wheel's contact point rolls ``dw = wheel_radius * dphi`` (m) in the
    direction ``alpha``; the rear axle has no lateral slip, so the base moves
    ``ds = dw cos(alpha)`` forward and turns ``dtheta = dw sin(alpha) /
    wheel_base``.

Both give per-step arc increments (ds, dtheta) that :func:`arc_pose` turns
into a relative pose assuming a constant curvature within the step (exact for
a constant steering angle or wheel-speed ratio).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Sequence

import numpy as np


def diff_arc(dphi_l, dphi_r, r_l: float, r_r: float, track: float):
    """
    Return arc increments (ds m, dtheta rad) of a differential drive step.

    :param dphi_l: left wheel rotation(s) (rad)
    :param dphi_r: right wheel rotation(s) (rad)
    :param r_l: left wheel radius (m)
    :param r_r: right wheel radius (m)
    :param track: track width (m)
    """
    dl = r_l * np.asarray(dphi_l, dtype=float)
    dr = r_r * np.asarray(dphi_r, dtype=float)
    return 0.5 * (dr + dl), (dr - dl) / track


def steered_arc(dphi, reading, radius: float, wheel_base: float, offset: float = 0.0,
                scale: float = 1.0):
    """
    Return arc increments (ds m, dtheta rad) of a steered-drive-wheel step.

    :param dphi: traction wheel rotation(s) (rad)
    :param reading: steering encoder reading(s) (rad), converted by ``scale * reading + offset``
    :param radius: traction wheel radius (m)
    :param wheel_base: distance from the rear axle to the steered wheel (m)
    :param offset: steering zero offset (rad, added to the scaled reading)
    :param scale: steering scale (multiplies the reading)
    """
    alpha = scale * np.asarray(reading, dtype=float) + offset
    dw = radius * np.asarray(dphi, dtype=float)
    return dw * np.cos(alpha), dw * np.sin(alpha) / wheel_base


def arc_pose(ds, dtheta) -> np.ndarray:
    """
    Return relative poses ``[..., 3]`` (x m, y m, yaw rad) of constant-curvature arcs.

    :param ds: arc length(s) travelled by the reference point (m)
    :param dtheta: heading change(s) over the arc (rad)
    """
    ds = np.asarray(ds, dtype=float)
    th = np.asarray(dtheta, dtype=float)
    small = np.abs(th) < 1e-9
    safe = np.where(small, 1.0, th)
    t1 = np.where(small, 1.0 - th ** 2 / 6.0, np.sin(safe) / safe)
    t2 = np.where(small, th / 2.0, (1.0 - np.cos(safe)) / safe)
    return np.stack((ds * t1, ds * t2, th), axis=-1)


def arc_pose_scalar(ds: float, dtheta: float) -> tuple[float, float, float]:
    """Return :func:`arc_pose` of one arc as floats (x m, y m, yaw rad), for per-sample use."""
    if abs(dtheta) < 1e-9:
        t1, t2 = 1.0 - dtheta * dtheta / 6.0, dtheta / 2.0
    else:
        t1, t2 = math.sin(dtheta) / dtheta, (1.0 - math.cos(dtheta)) / dtheta
    return ds * t1, ds * t2, dtheta


def off_arc(dx: float, dy: float, dtheta: float) -> float:
    """
    Return the sideways motion (m) of a planar step no rolling wheel gives (0 within it).

    ``dx``, ``dy`` (m) in the frame of the step's start, ``dtheta`` (rad). An arc's
    chord leaves the heading at half the turn, ``dy = dx tan(dtheta / 2)``; odometry
    integrated to first order puts it anywhere from 0 to the whole turn, so up to
    half the turn times the length counts as rolling. What is beyond (signed) is a
    holonomic robot's sideways motion.
    """
    side = dy - dx * math.tan(0.5 * dtheta)
    allowance = 0.5 * abs(dtheta) * math.hypot(dx, dy) + 1e-6
    return side if abs(side) > allowance else 0.0


def compose_scalar(a: tuple, b: tuple) -> tuple[float, float, float]:
    """Return :func:`compose` of two single poses as floats (b expressed in a)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]


def between_scalar(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float]:
    """Return ``compose(inverse(a), b)`` of two single poses as floats (b seen from a)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    ix, iy, ith = -c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]
    return compose_scalar((ix, iy, ith), b)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return ``a (+) b`` for arrays of planar poses ``[..., 3]`` (b expressed in a)."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack((a[..., 0] + c * b[..., 0] - s * b[..., 1],
                     a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     a[..., 2] + b[..., 2]), axis=-1)


def inverse(a: np.ndarray) -> np.ndarray:
    """Return the inverse of planar poses ``[..., 3]``."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack((-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1],
                     -a[..., 2]), axis=-1)


def integrate_steps(steps: np.ndarray) -> np.ndarray:
    """
    Compose padded step poses ``[S, K, 3]`` along K into segment motions ``[S, 3]``.

    Padding steps must be zero poses. Yaw is not wrapped (segments stay short).
    """
    steps = np.asarray(steps, dtype=float)
    # a (+) b (+) c ... : step k is rotated by the heading summed over the steps before it
    heading = np.cumsum(steps[..., 2], axis=1)
    before = heading - steps[..., 2]
    c, s = np.cos(before), np.sin(before)
    x = np.sum(c * steps[..., 0] - s * steps[..., 1], axis=1)
    y = np.sum(s * steps[..., 0] + c * steps[..., 1], axis=1)
    return np.stack((x, y, heading[:, -1] if steps.shape[1] else np.zeros(len(steps))),
                    axis=-1)


def integrate_arcs(ds: np.ndarray, dtheta: np.ndarray) -> np.ndarray:
    """
    Return ``integrate_steps(arc_pose(ds, dtheta))`` for padded arcs ``[S, K]``, in fewer passes.

    An arc of length ``ds`` turning ``dtheta`` moves the chord ``ds sinc(dtheta / 2)``
    along the heading at its middle (the heading before it plus ``dtheta / 2``), so a
    segment's motion is the sum of its chords rotated by their middle headings;
    padding arcs (zeros) add nothing.
    """
    ds = np.asarray(ds, dtype=float)
    th = np.asarray(dtheta, dtype=float)
    heading = np.cumsum(th, axis=1)
    middle = heading - 0.5 * th
    chord = ds * np.sinc(th / (2.0 * np.pi))          # np.sinc(x) = sin(pi x) / (pi x)
    x = np.sum(chord * np.cos(middle), axis=1)
    y = np.sum(chord * np.sin(middle), axis=1)
    return np.stack((x, y, heading[:, -1] if th.shape[1] else np.zeros(len(th))), axis=-1)


def integrate_arcs_packed(ds: np.ndarray, dtheta: np.ndarray, segment: np.ndarray,
                          n: int) -> np.ndarray:
    """
    Return :func:`integrate_arcs` of arcs stored end to end: no padding, ``[n, 3]``.

    ``ds`` (m) and ``dtheta`` (rad) are flat ``[N]``; ``segment`` ``[N]`` gives the
    segment (0 to n - 1, non-decreasing) of each arc. The heading inside a segment
    is the running sum over the whole array minus its value before the segment
    (a difference of 1e-13 rad to a per-segment sum over an hour of driving).
    """
    ds = np.asarray(ds, dtype=float)
    th = np.asarray(dtheta, dtype=float)
    heading = np.cumsum(th)
    start = np.searchsorted(segment, np.arange(n))
    before = np.concatenate(([0.0], heading))[start]
    middle = heading - before[segment] - 0.5 * th
    half = 0.5 * th
    with np.errstate(invalid='ignore', divide='ignore'):
        sinc = np.sin(half) / half                    # chord / arc length
    sinc[half == 0.0] = 1.0
    chord = ds * sinc
    return np.stack((np.bincount(segment, chord * np.cos(middle), minlength=n),
                     np.bincount(segment, chord * np.sin(middle), minlength=n),
                     np.bincount(segment, th, minlength=n)), axis=-1)


def sensor_motion(base_motion: np.ndarray, sensor_pose) -> np.ndarray:
    """
    Return the sensor's own motion ``l^-1 (+) o (+) l`` for base motions ``o`` [..., 3].

    :param base_motion: relative motion(s) of ``base_link`` (x m, y m, yaw rad)
    :param sensor_pose: sensor pose in ``base_link`` (x m, y m, yaw rad)
    """
    lp = np.broadcast_to(np.asarray(sensor_pose, dtype=float), np.shape(base_motion))
    return compose(inverse(lp), compose(base_motion, lp))


def base_motion_from_sensor(sensor_motion_: np.ndarray, sensor_pose) -> np.ndarray:
    """Return the base motion ``l (+) s (+) l^-1`` from sensor motions ``s`` [..., 3]."""
    lp = np.broadcast_to(np.asarray(sensor_pose, dtype=float), np.shape(sensor_motion_))
    return compose(lp, compose(sensor_motion_, inverse(lp)))


@dataclass
class Segment:
    """
    Wheel steps between two key frames and the sensor motion measured between them.

    ``steps`` is (K, 2): differential ``(dphi_l, dphi_r)`` rad; steered wheel
    ``(dphi, reading)`` (traction rotation rad, steering reading rad).
    ``sensor_motion`` is (x m, y m, yaw rad) of the sensor in its own frame at ``t0``.
    """

    t0: float
    t1: float
    steps: np.ndarray
    sensor_motion: np.ndarray
    info: dict = field(default_factory=dict)
