# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Fast paths of the codec: serialized sensor_msgs/Imu and nav_msgs/Odometry, without rosbags.

Little-endian ROS 2 CDR and ROS 1 bytes are decoded with :mod:`struct` and
numpy into exactly the samples the generic converters of
:mod:`robot_calib.codec.messages` give (the tests check that both agree), and
encoded into bytes identical to rosbags' ``serialize_cdr``; this is what lets
replay read well above 50k messages/s. They register into the one table of
:mod:`robot_calib.codec` at the end of this module.
"""

from __future__ import annotations

import math
import struct
from typing import Optional

import numpy as np

from robot_calib.codec.messages import cov3, POSE_IDX
from robot_calib.codec.table import register_fast
from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy, quat_to_rpy, quat_tuple_from_rpy

_U32 = struct.Struct('<I')
_STAMP2 = struct.Struct('<iII')  # CDR: sec, nanosec, frame_id length (incl. NUL)
_STAMP1 = struct.Struct('<IIII')  # ROS 1: seq, secs, nsecs, frame_id length (no NUL)
_D7 = struct.Struct('<7d')  # position x y z, orientation x y z w
_NAN33 = np.full((3, 3), np.nan)
_NAN33.setflags(write=False)


def _imu_sample(ns: int, frame: str, v: np.ndarray) -> T.ImuSample:
    """Build an ImuSample from the 37 doubles of a sensor_msgs/Imu after its header."""
    # v: orientation x y z w (0:4), orientation cov (4:13), gyro (13:16), gyro cov (16:25),
    # accel (25:28), accel cov (28:37)
    orientation = ocov = None
    if v[4] >= 0 and (v[0] != 0.0 or v[1] != 0.0 or v[2] != 0.0 or v[3] != 0.0):
        orientation = np.array((v[3], v[0], v[1], v[2]))
        ocov = v[4:13].reshape(3, 3)
    return T.ImuSample(ns * 1e-9, v[13:16], v[25:28], frame, orientation, ocov,
                       cov3(v[16:25]), cov3(v[28:37]), ns)


def imu_from_cdr(raw: bytes) -> T.ImuSample:
    """Decode a little-endian CDR sensor_msgs/Imu into an :class:`ImuSample`."""
    sec, nsec, n = _STAMP2.unpack_from(raw, 4)
    frame = bytes(raw[16:15 + n]).decode()
    off = 4 + ((12 + n + 7) & ~7)
    v = np.frombuffer(raw, '<f8', 37, off).copy()
    return _imu_sample(sec * 1_000_000_000 + nsec, frame, v)


def imu_from_ros1(raw: bytes) -> T.ImuSample:
    """Decode a ROS 1 serialized sensor_msgs/Imu into an :class:`ImuSample`."""
    _, sec, nsec, n = _STAMP1.unpack_from(raw, 0)
    frame = bytes(raw[16:16 + n]).decode()
    v = np.frombuffer(raw, '<f8', 37, 16 + n).copy()
    return _imu_sample(sec * 1_000_000_000 + nsec, frame, v)


_POSE_COV = np.ravel_multi_index(POSE_IDX, (6, 6)).astype(np.intp) + 7
"""Where the (x, y, yaw) covariance is in the doubles of an Odometry (pose covariance at 7)."""
_TWIST_COV = _POSE_COV + 42
"""Where the (vx, vy, wz) covariance is (twist covariance at 49)."""


def _odom_sample(ns: int, frame: str, child: str, v: np.ndarray) -> T.OdomSample:
    """Build an OdomSample from the 85 doubles of a nav_msgs/Odometry after its frames."""
    # v: position (0:3), orientation x y z w (3:7), pose cov 6x6 (7:43), linear (43:46),
    # angular (46:49), twist cov 6x6 (49:85)
    x, y, z, qx, qy, qz, qw = v[:7].tolist()
    q = (qw, qx, qy, qz)
    roll, pitch, yaw = quat_to_rpy(_unit_quat(q))
    return T.OdomSample(ns * 1e-9, x, y, yaw, float(v[43]), float(v[44]), float(v[48]), frame,
                        child, v[_POSE_COV], v[_TWIST_COV], z, roll, pitch, ns, math.hypot(*q))


def _unit_quat(q: tuple[float, float, float, float]) -> tuple[float, ...]:
    """
    Return ``q`` (w, x, y, z) over its norm: :func:`quat_normalize` without choosing the sign.

    The same values (the norm is taken as np.linalg.norm takes it), up to the
    sign, which :func:`quat_to_rpy` does not depend on (products of two terms).
    """
    a = np.array(q)
    n = math.sqrt(a.dot(a))
    if not math.isfinite(n) or n == 0.0:
        return (1.0, 0.0, 0.0, 0.0)
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def odom_from_cdr(raw: bytes) -> T.OdomSample:
    """Decode a little-endian CDR nav_msgs/Odometry into an :class:`OdomSample`."""
    sec, nsec, n = _STAMP2.unpack_from(raw, 4)
    frame = bytes(raw[16:15 + n]).decode()
    pos = 4 + ((12 + n + 3) & ~3)
    m = _U32.unpack_from(raw, pos)[0]
    child = bytes(raw[pos + 4:pos + 3 + m]).decode()
    off = 4 + ((pos - 4 + 4 + m + 7) & ~7)
    v = np.frombuffer(raw, '<f8', 85, off)
    return _odom_sample(sec * 1_000_000_000 + nsec, frame, child, v)


def odom_pose_from_cdr(raw: bytes) -> tuple[float, float, float, float]:
    """
    Return (t s, x m, y m, yaw rad) of a little-endian CDR nav_msgs/Odometry.

    The values :func:`odom_from_cdr` gives (same operations), without the rest
    of the message: for trajectories drawn, not used.
    """
    sec, nsec, n = _STAMP2.unpack_from(raw, 4)
    pos = 4 + ((12 + n + 3) & ~3)
    m = _U32.unpack_from(raw, pos)[0]
    off = 4 + ((pos - 4 + 4 + m + 7) & ~7)
    x, y, _, qx, qy, qz, qw = _D7.unpack_from(raw, off)
    yaw = quat_to_rpy(_unit_quat((qw, qx, qy, qz)))[2]
    return (sec * 1_000_000_000 + nsec) * 1e-9, x, y, yaw


def odom_from_ros1(raw: bytes) -> T.OdomSample:
    """Decode a ROS 1 serialized nav_msgs/Odometry into an :class:`OdomSample`."""
    _, sec, nsec, n = _STAMP1.unpack_from(raw, 0)
    frame = bytes(raw[16:16 + n]).decode()
    pos = 16 + n
    m = _U32.unpack_from(raw, pos)[0]
    child = bytes(raw[pos + 4:pos + 4 + m]).decode()
    v = np.frombuffer(raw, '<f8', 85, pos + 4 + m)
    return _odom_sample(sec * 1_000_000_000 + nsec, frame, child, v)


# ---------------------------------------------------------------------------------------
# fast encoders (little-endian CDR), byte-identical to the generic path
# ---------------------------------------------------------------------------------------
_CDR_LE = b'\x00\x01\x00\x00'
_POSE_FLAT = np.ravel_multi_index(POSE_IDX, (6, 6)).ravel().tolist()
_D37 = struct.Struct('<37d')
_D85 = struct.Struct('<85d')


def _cdr_header(ns: int, frame: str) -> bytearray:
    """Return encapsulation + std_msgs/Header (stamp, frame_id) without trailing padding."""
    fb = frame.encode()
    out = bytearray(_CDR_LE)
    out += _STAMP2.pack(ns // 1_000_000_000, ns % 1_000_000_000, len(fb) + 1)
    out += fb
    out += b'\x00'
    return out


def _pad(buf: bytearray, align: int) -> None:
    buf += bytes(-(len(buf) - 4) % align)


def _cov9(cov: Optional[np.ndarray], unknown: float) -> list:
    """Return 9 covariance values as messages._cov_out does (unknown in [0] when absent)."""
    if cov is not None:
        c = np.asarray(cov, dtype=float).ravel().tolist()
        if len(c) == 9 and all(map(math.isfinite, c)):
            return c
    return [unknown, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]


def _cov36(cov3: np.ndarray) -> list:
    """Return a 6x6 covariance as messages._cov6 builds it (1e6 on z, roll, pitch)."""
    out = [0.0] * 36
    out[14] = out[21] = out[28] = 1e6
    isf = math.isfinite
    for i, v in zip(_POSE_FLAT, np.asarray(cov3, dtype=float).ravel().tolist()):
        out[i] = v if isf(v) else 0.0
    return out


def _imu_to_cdr_any(s: T.ImuSample) -> bytes:
    """Serialize an :class:`ImuSample` of any field types, field by field."""
    buf = _cdr_header(T.stamp_of(s.t, s.stamp_ns), s.frame_id)
    _pad(buf, 8)
    if s.orientation is None:
        q, ocov = (1.0, 0.0, 0.0, 0.0), _cov9(None, -1.0)
    else:
        q, ocov = s.orientation, _cov9(s.orientation_cov, 0.0)
    g, a = s.gyro, s.accel
    buf += _D37.pack(float(q[1]), float(q[2]), float(q[3]), float(q[0]), *ocov,
                     float(g[0]), float(g[1]), float(g[2]), *_cov9(s.gyro_cov, 0.0),
                     float(a[0]), float(a[1]), float(a[2]), *_cov9(s.accel_cov, 0.0))
    return bytes(buf)


def _odom_to_cdr_any(s: T.OdomSample) -> bytes:
    """Serialize an :class:`OdomSample` of any field types, field by field."""
    buf = _cdr_header(T.stamp_of(s.t, s.stamp_ns), s.frame_id)
    _pad(buf, 4)
    cb = s.child_frame_id.encode()
    buf += _U32.pack(len(cb) + 1)
    buf += cb
    buf += b'\x00'
    _pad(buf, 8)
    q = quat_from_rpy(s.roll, s.pitch, s.yaw)
    buf += _D85.pack(float(s.x), float(s.y), float(s.z), float(q[1]), float(q[2]), float(q[3]),
                     float(q[0]), *_cov36(s.pose_cov), float(s.vx), float(s.vy), 0.0, 0.0, 0.0,
                     float(s.wz), *_cov36(s.twist_cov))
    return bytes(buf)


# Whole messages in one pack call: a struct layout per frame id (pair of frame ids for
# Odometry), header and padding included; zeros of the covariances are pad bytes (+0.0).
_F8 = np.dtype('float64')
_MAX_LAYOUTS = 256
"""Frame ids (pairs) whose layouts are kept; others are built per message."""
_IMU_LAYOUTS: dict = {}
_ODOM_LAYOUTS: dict = {}
_COV36 = '2d24xd2d24xd16xd48xd48xd8x2d24xd'
"""A 6x6 covariance from a 3x3 one of (x, y, yaw) and 1e6 on z, roll, pitch (_cov36)."""
_ORIENTATION_UNKNOWN = (1.0, 0.0, 0.0, 0.0, *_cov9(None, -1.0))
"""Quaternion (w, x, y, z) and covariance of an Imu without orientation (w first)."""


def _imu_layout(frame: str) -> tuple:
    """Return (pack, frame length, frame bytes) of a whole sensor_msgs/Imu in ``frame``."""
    fb = frame.encode()
    layout = (struct.Struct(f'<4siII{len(fb) + 1}s{-(13 + len(fb)) % 8}x37d').pack,
              len(fb) + 1, fb)
    if len(_IMU_LAYOUTS) < _MAX_LAYOUTS:
        _IMU_LAYOUTS[frame] = layout
    return layout


def _odom_layout(frames: tuple[str, str]) -> tuple:
    """Return (pack, frame length, bytes, child frame length, bytes) of a nav_msgs/Odometry."""
    fb, cb = frames[0].encode(), frames[1].encode()
    pad1 = -(13 + len(fb)) % 4
    pad2 = -(13 + len(fb) + pad1 + 5 + len(cb)) % 8
    fmt = f'<4siII{len(fb) + 1}s{pad1}xI{len(cb) + 1}s{pad2}x7d{_COV36}2d24xd{_COV36}'
    layout = (struct.Struct(fmt).pack, len(fb) + 1, fb, len(cb) + 1, cb)
    if len(_ODOM_LAYOUTS) < _MAX_LAYOUTS:
        _ODOM_LAYOUTS[frames] = layout
    return layout


def _is_cov(cov: object) -> bool:
    """Return whether ``cov`` is a float64 array of 9 values (a 3x3 covariance)."""
    return type(cov) is np.ndarray and (cov.dtype is _F8 or cov.dtype == _F8) and cov.size == 9


_Q_UNKNOWN = (*_ORIENTATION_UNKNOWN[1:4], _ORIENTATION_UNKNOWN[0], *_ORIENTATION_UNKNOWN[4:])
"""The same, in message order: x, y, z, w, then the covariance."""


def imu_to_cdr(s: T.ImuSample) -> bytes:
    """Serialize an :class:`ImuSample` as the generic path does, without building a message."""
    g, a, q = s.gyro, s.accel, s.orientation
    gc, ac = s.gyro_cov, s.accel_cov
    if (type(g) is not np.ndarray or type(a) is not np.ndarray or not _is_cov(gc)
            or not _is_cov(ac)):
        return _imu_to_cdr_any(s)
    if q is not None and (type(q) is not np.ndarray or not _is_cov(s.orientation_cov)):
        return _imu_to_cdr_any(s)
    sec, nsec = divmod(T.stamp_of(s.t, s.stamp_ns), 1_000_000_000)
    isfinite = math.isfinite
    try:
        pack, nf, fb = _IMU_LAYOUTS.get(s.frame_id) or _imu_layout(s.frame_id)
        g0, g1, g2 = g.tolist()
        a0, a1, a2 = a.tolist()
        gl, al = gc.ravel().tolist(), ac.ravel().tolist()
        # a sum is finite only when every term is (an overflow just takes the slower check)
        if not isfinite(sum(gl)):
            gl = _cov9(gc, 0.0)
        if not isfinite(sum(al)):
            al = _cov9(ac, 0.0)
        if q is None:
            return pack(_CDR_LE, sec, nsec, nf, fb, *_Q_UNKNOWN, g0, g1, g2, *gl, a0, a1, a2,
                        *al)
        qw, qx, qy, qz = q.tolist()
        ol = s.orientation_cov.ravel().tolist()
        if not isfinite(sum(ol)):
            ol = _cov9(s.orientation_cov, 0.0)
        return pack(_CDR_LE, sec, nsec, nf, fb, qx, qy, qz, qw, *ol, g0, g1, g2, *gl,
                    a0, a1, a2, *al)
    except (ValueError, TypeError, AttributeError, struct.error):  # odd fields: one by one
        return _imu_to_cdr_any(s)


_E6 = (1e6, 1e6, 1e6)
"""The variances of z, roll and pitch in a 6x6 covariance (_cov36), between values 6 and 7."""


def _cov_terms(cov: np.ndarray) -> list:
    """Return the pack arguments of _COV36 from a 3x3 float64 covariance (non-finite: 0)."""
    out = cov.ravel().tolist()
    if not math.isfinite(sum(out)):  # non-finite values are written as 0 (_cov36)
        out = [v if math.isfinite(v) else 0.0 for v in out]
    out[6:6] = _E6
    return out


def odom_to_cdr(s: T.OdomSample) -> bytes:
    """Serialize an :class:`OdomSample` as the generic path does, without building a message."""
    pc, tc = s.pose_cov, s.twist_cov
    if not _is_cov(pc) or not _is_cov(tc):
        return _odom_to_cdr_any(s)
    sec, nsec = divmod(T.stamp_of(s.t, s.stamp_ns), 1_000_000_000)
    try:
        frames = (s.frame_id, s.child_frame_id)
        pack, nf, fb, nc, cb = _ODOM_LAYOUTS.get(frames) or _odom_layout(frames)
        qw, qx, qy, qz = quat_tuple_from_rpy(s.roll, s.pitch, s.yaw)
        return pack(_CDR_LE, sec, nsec, nf, fb, nc, cb, s.x, s.y, s.z, qx, qy, qz, qw,
                    *_cov_terms(pc), s.vx, s.vy, s.wz, *_cov_terms(tc))
    except (ValueError, TypeError, AttributeError, struct.error):  # odd fields: one by one
        return _odom_to_cdr_any(s)


def imu_batch_from_cdr(raws: list) -> list:
    """
    Decode many little-endian CDR sensor_msgs/Imu of one topic at once: a list of [ImuSample].

    Vectorized over the batch (stamps, the 37 doubles, the covariance flags); each
    sample gets views into one array of the batch. Gives exactly what
    :func:`imu_from_cdr` gives per message. Raises ValueError when the messages
    differ in layout (length, frame id, byte order): decode them one by one then.
    """
    n = len(raws)
    size = len(raws[0])
    if any(len(r) != size for r in raws):
        raise ValueError('messages of different lengths')
    a = np.frombuffer(b''.join(raws), np.uint8).reshape(n, size)
    fl = int(_U32.unpack_from(raws[0], 12)[0])
    off = 4 + ((12 + fl + 7) & ~7)
    if off + 296 > size or not (a[:, 1] == 1).all() or not (
            a[:, 12:15 + fl] == a[0, 12:15 + fl]).all():
        raise ValueError('messages of different layouts')
    frame = bytes(raws[0][16:15 + fl]).decode()
    stamp = a[:, 4:12].copy().view('<u4')
    ns = (stamp[:, 0].view('<i4').astype(np.int64) * 1_000_000_000
          + stamp[:, 1].astype(np.int64)).tolist()
    v = a[:, off:off + 296].copy().view('<f8')  # (n, 37), rows as in _imu_sample
    gyro, accel = v[:, 13:16], v[:, 25:28]
    gcov, acov, ocov = (v[:, 16:25].reshape(n, 3, 3), v[:, 28:37].reshape(n, 3, 3),
                        v[:, 4:13].reshape(n, 3, 3))
    has_q = ((v[:, 4] >= 0) & (v[:, :4] != 0).any(axis=1)).tolist()
    g_ok = (v[:, 16] >= 0).tolist()
    a_ok = (v[:, 28] >= 0).tolist()
    imu = T.ImuSample
    out = []
    for i in range(n):
        t_ns = ns[i]
        if has_q[i]:
            q = v[i]
            orientation, oc = np.array((q[3], q[0], q[1], q[2])), ocov[i]
        else:
            orientation = oc = None
        out.append([imu(t_ns * 1e-9, gyro[i], accel[i], frame, orientation, oc,
                        gcov[i] if g_ok[i] else np.full((3, 3), np.nan),
                        acov[i] if a_ok[i] else np.full((3, 3), np.nan), t_ns)])
    return out


register_fast('sensor_msgs/msg/Imu', decode_cdr=imu_from_cdr, decode_ros1=imu_from_ros1,
              decode_cdr_batch=imu_batch_from_cdr, encode_cdr=imu_to_cdr)
register_fast('nav_msgs/msg/Odometry', decode_cdr=odom_from_cdr, decode_ros1=odom_from_ros1,
              encode_cdr=odom_to_cdr)
