# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Small quaternion helpers on tuples of Python floats (fast for one sample at a time).

Quaternions are ``(w, x, y, z)``; angles rad. Both estimator variants use
these (the NumPy versions of :mod:`robot_calib.core.geometry` are slower for
single samples and would not round the same way); roll, pitch and yaw to a
quaternion is :func:`robot_calib.core.geometry.quat_tuple_from_rpy`.
"""

from __future__ import annotations

import math

IDENTITY = (1.0, 0.0, 0.0, 0.0)
"""The identity rotation (w, x, y, z)."""


def qmul(a: tuple, b: tuple) -> tuple:
    """Return the quaternion product ``a b``."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def qrot(q: tuple, x: float, y: float, z: float) -> tuple:
    """Rotate (x, y, z) by unit quaternion q: R(q) v."""
    w, a, b, c = q
    # t = 2 * (q_vec x v); v' = v + w t + q_vec x t
    tx = 2.0 * (b * z - c * y)
    ty = 2.0 * (c * x - a * z)
    tz = 2.0 * (a * y - b * x)
    return (x + w * tx + b * tz - c * ty,
            y + w * ty + c * tx - a * tz,
            z + w * tz + a * ty - b * tx)


def qnorm(q: tuple) -> tuple:
    """Return q scaled to unit length."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def align_up(x: float, y: float, z: float) -> tuple:
    """Return the smallest rotation taking unit vector (x, y, z) to (0, 0, 1)."""
    if z > -0.999999:
        s = math.sqrt(2.0 * (1.0 + z))
        return (0.5 * s, y / s, -x / s, 0.0)
    return (0.0, 1.0, 0.0, 0.0)  # upside down: half turn about x


def tilt_of(q: tuple) -> float:
    """Return the tilt (rad, [0, pi]) of sensor-to-earth quaternion q: body z vs world up."""
    c = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])
    return math.acos(-1.0 if c < -1.0 else (1.0 if c > 1.0 else c))


def positive_w(q: tuple) -> tuple:
    """Return q or -q, whichever has ``w >= 0`` (the same rotation)."""
    if q[0] < 0.0:
        return (-q[0], -q[1], -q[2], -q[3])
    return q
