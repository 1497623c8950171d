# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Angles, planar rigid transforms (SE(2)) and quaternions (w, x, y, z).

Conventions: REP-103 (x forward, y left, z up), right-handed, angles in rad.
Euler angles are the ROS ``rpy`` convention: R = Rz(yaw) Ry(pitch) Rx(roll).
"""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(angle):
    """Wrap an angle or array of angles (rad) to (-pi, pi]."""
    if isinstance(angle, float) and math.isfinite(angle):  # one angle, without numpy
        wrapped = math.fmod(angle + math.pi, 2.0 * math.pi)
        if wrapped <= 0.0:
            wrapped += 2.0 * math.pi
        return wrapped - math.pi
    wrapped = np.mod(np.asarray(angle, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    wrapped = np.where(wrapped == -np.pi, np.pi, wrapped)
    if np.ndim(wrapped) == 0:
        return float(wrapped)
    return wrapped


def wrap_scalar(a: float) -> float:
    """
    Wrap one angle (rad, a Python float) to (-pi, pi], returning one already there unchanged.

    :func:`wrap_angle` computes ``(a + pi) mod 2 pi - pi`` even inside the range,
    which may move the last bit; the fusion filter's state keeps its angle as is.
    """
    if -math.pi < a <= math.pi:
        return a
    a = math.fmod(a + math.pi, 2.0 * math.pi)
    a = a + math.pi if a <= 0.0 else a - math.pi
    return a if a != -math.pi else math.pi


def wrap_half_pi(angle):
    """Wrap an undirected line angle (rad) to (-pi/2, pi/2]: lines are equal modulo pi."""
    if isinstance(angle, float) and math.isfinite(angle):  # one angle, without numpy
        wrapped = (angle + math.pi / 2) % math.pi - math.pi / 2
        return math.pi / 2 if wrapped == -math.pi / 2 else wrapped
    wrapped = np.mod(np.asarray(angle, dtype=float) + np.pi / 2, np.pi) - np.pi / 2
    wrapped = np.where(wrapped == -np.pi / 2, np.pi / 2, wrapped)
    if np.ndim(wrapped) == 0:
        return float(wrapped)
    return wrapped


def rot2(theta: float) -> np.ndarray:
    """Return the 2x2 rotation matrix of angle ``theta`` (rad)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def se2_compose(a, b) -> np.ndarray:
    """Return a (+) b for poses [x, y, yaw]: b expressed in a's frame, result in a's parent."""
    ax, ay, ath = a
    bx, by, bth = b
    c, s = math.cos(ath), math.sin(ath)
    return np.array([ax + c * bx - s * by, ay + s * bx + c * by, wrap_angle(ath + bth)])


def se2_inverse(a) -> np.ndarray:
    """Return the inverse of pose [x, y, yaw] (m, m, rad)."""
    ax, ay, ath = a
    c, s = math.cos(ath), math.sin(ath)
    return np.array([-c * ax - s * ay, s * ax - c * ay, wrap_angle(-ath)])


def se2_between(a, b) -> np.ndarray:
    """Return the relative pose a^-1 (+) b: b seen from a."""
    return se2_compose(se2_inverse(a), b)


def se2_apply(pose, points: np.ndarray) -> np.ndarray:
    """Transform (N, 2) points (m) by pose [x, y, yaw]."""
    x, y, th = pose
    return np.asarray(points) @ rot2(th).T + np.array([x, y])


def quat_multiply(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Return the Hamilton product q1 * q2 of quaternions (w, x, y, z)."""
    w1, x1, y1, z1 = q1
    w2, x2, y2, z2 = q2
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Return the conjugate (inverse of a unit quaternion) of (w, x, y, z)."""
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Return q / |q|, with the sign chosen so that w >= 0."""
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    q = q / n
    return -q if q[0] < 0 else q


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Return the 3x3 rotation matrix of unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Return the unit quaternion (w, x, y, z) of a 3x3 rotation matrix (Shepperd's method)."""
    m = np.asarray(m, dtype=float)
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return quat_normalize(np.array(q))


SAME_ROTATION_TOLERANCE = 1e-6
"""
Rotations closer than this are the same (rad, 0.2 arcsecond).

Far above rounding (a quaternion typed to 4 digits, or one whose last bit moves
when normalised, is 1e-16 to 1e-5 from unit length, which normalising removes)
and far below any mounting angle one can measure.
"""


def rotation_angle(a, b) -> float:
    """
    Return the angle (rad, [0, pi]) of the rotation from quaternion ``a`` to ``b`` (w, x, y, z).

    Both are normalised first and ``q`` and ``-q`` are the same rotation; NaN when
    either has no finite, non-zero norm.
    """
    aw, ax, ay, az = (float(v) for v in a)
    bw, bx, by, bz = (float(v) for v in b)
    na = math.sqrt(aw * aw + ax * ax + ay * ay + az * az)
    nb = math.sqrt(bw * bw + bx * bx + by * by + bz * bz)
    if not (0.0 < na < math.inf and 0.0 < nb < math.inf):
        return math.nan
    aw, ax, ay, az = aw / na, ax / na, ay / na, az / na
    bw, bx, by, bz = bw / nb, bx / nb, by / nb, bz / nb
    if aw * bw + ax * bx + ay * by + az * bz < 0.0:
        bw, bx, by, bz = -bw, -bx, -by, -bz
    # a . b = cos(angle / 2) = cos(phi), phi the arc between a and b on the unit sphere;
    # phi = 2 atan2(|a - b|, |a + b|) stays accurate for small angles, unlike acos(a . b)
    diff = math.sqrt((aw - bw) ** 2 + (ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2)
    total = math.sqrt((aw + bw) ** 2 + (ax + bx) ** 2 + (ay + by) ** 2 + (az + bz) ** 2)
    return 4.0 * math.atan2(diff, total)


def same_rotation(a, b, tolerance: float = SAME_ROTATION_TOLERANCE) -> bool:
    """
    Return True when quaternions ``a`` and ``b`` (w, x, y, z) are the same rotation.

    The one comparison of mountings: normalised, ``q`` and ``-q`` equal, within
    ``tolerance`` (rad). False when either is not a rotation (zero or not finite).
    """
    return rotation_angle(a, b) <= tolerance


def quat_tuple_from_rpy(roll: float, pitch: float, yaw: float
                        ) -> tuple[float, float, float, float]:
    """Return (w, x, y, z) of R = Rz(yaw) Ry(pitch) Rx(roll) (rad) as a tuple of floats."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy)


def quat_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Return (w, x, y, z) of R = Rz(yaw) Ry(pitch) Rx(roll) (rad)."""
    return np.array(quat_tuple_from_rpy(roll, pitch, yaw))


def quat_to_rpy(q: np.ndarray) -> tuple[float, float, float]:
    """Return (roll, pitch, yaw) (rad) of unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    sinp = max(-1.0, min(1.0, 2 * (w * y - z * x)))
    pitch = math.asin(sinp)
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def yaw_from_quat(q: np.ndarray) -> float:
    """Return the yaw (rad) of unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def quat_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Return (w, x, y, z) of a rotation vector (axis * angle, rad)."""
    rotvec = np.asarray(rotvec, dtype=float)
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return quat_normalize(np.array([1.0, *(0.5 * rotvec)]))
    axis = rotvec / angle
    return np.array([math.cos(angle / 2), *(math.sin(angle / 2) * axis)])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vector ``v`` by unit quaternion ``q`` (w, x, y, z): returns R(q) v."""
    return quat_to_matrix(q) @ np.asarray(v, dtype=float)


def tilt_from_quat(q: np.ndarray) -> float:
    """Return the tilt (rad): angle between the body z axis and world up, in [0, pi]."""
    w, x, y, z = q
    cos_tilt = 1.0 - 2.0 * (x * x + y * y)
    return math.acos(max(-1.0, min(1.0, cos_tilt)))


def tilt_from_gravity(accel: np.ndarray) -> float:
    """Return the tilt (rad) implied by a specific-force vector at rest (m/s^2)."""
    a = np.asarray(accel, dtype=float)
    n = float(np.linalg.norm(a))
    if n == 0.0 or not np.isfinite(n):
        return float('nan')
    return math.acos(max(-1.0, min(1.0, a[2] / n)))
