# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Fast paths of the codec for the message types other than Imu and Odometry.

LaserScan, JointState, Twist, TwistStamped, NavSatFix, Bool, DiagnosticArray
and TFMessage in little-endian ROS 2 CDR, read and written with :mod:`struct`
and numpy: the samples the generic converters of
:mod:`robot_calib.codec.messages` give, and bytes identical to rosbags'
``serialize_cdr`` (the tests check both). Besides speed (scans and joint states
are a large share of a recording), a replay of a bag of these types no longer
needs rosbags' ROS 2 type store, a tenth of a short replay to import.
Alignment follows the ROS 2 CDR rules: from the end of the 4-byte encapsulation
header, each primitive aligned to its size, and a sequence of 8-byte values
aligned only when it is not empty.
"""

from __future__ import annotations

import struct
from typing import Any, Optional

import numpy as np

from robot_calib.codec.cdr import _cdr_header, _CDR_LE, _pad, _U32
from robot_calib.codec.table import register_fast
from robot_calib.core import types as T
from robot_calib.core.geometry import quat_normalize

_SEC_NSEC = struct.Struct('<iI')
_F7 = struct.Struct('<7f')
_D6 = struct.Struct('<6d')
_D7 = struct.Struct('<7d')
_NAVSAT = struct.Struct('<3d9dB')


class _Reader:
    """A cursor over little-endian CDR bytes; offsets aligned from the encapsulation's end."""

    __slots__ = ('raw', 'pos')

    def __init__(self, raw: bytes):
        self.raw = raw
        self.pos = 4

    def align(self, size: int) -> None:
        self.pos += -(self.pos - 4) % size

    def u32(self) -> int:
        self.align(4)
        value = _U32.unpack_from(self.raw, self.pos)[0]
        self.pos += 4
        return value

    def string(self) -> str:
        n = self.u32()
        text = bytes(self.raw[self.pos:self.pos + n - 1]).decode()
        self.pos += n
        return text

    def header(self) -> tuple[int, str]:
        """Return (stamp ns, frame_id) of a std_msgs/Header."""
        self.align(4)
        sec, nsec = _SEC_NSEC.unpack_from(self.raw, self.pos)
        self.pos += 8
        return sec * 1_000_000_000 + nsec, self.string()

    def array(self, dtype: str, n: int) -> np.ndarray:
        """Return ``n`` values of ``dtype`` ('<f8' or '<f4') as float64 (a copy)."""
        if n == 0:
            return np.zeros(0)
        size = 8 if dtype == '<f8' else 4
        self.align(size)
        out = np.frombuffer(self.raw, dtype, n, self.pos).astype(float)
        self.pos += size * n
        return out

    def sequence(self, dtype: str) -> np.ndarray:
        return self.array(dtype, self.u32())

    def unpack(self, fmt: struct.Struct, align: int) -> tuple:
        self.align(align)
        values = fmt.unpack_from(self.raw, self.pos)
        self.pos += fmt.size
        return values


# ---------------------------------------------------------------------------------------
# decoders: (raw bytes, receive time ns) -> samples, as codec.from_msg gives them
# ---------------------------------------------------------------------------------------
def scan_from_cdr(raw: bytes, time_ns: Optional[int] = None) -> list:
    """Decode a sensor_msgs/LaserScan."""
    r = _Reader(raw)
    ns, frame = r.header()
    a_min, _, a_inc, t_inc, scan_time, r_min, r_max = r.unpack(_F7, 4)
    ranges = r.sequence('<f4')
    intens = r.sequence('<f4')
    return [T.ScanSample(ns * 1e-9, a_min, a_inc, ranges, r_min, r_max, frame,
                         intens if intens.size else None, t_inc, scan_time, ns)]


class _JointLayout:
    """
    Where the values of a JointState are, for the messages that share its frame and names.

    ``prefix`` is the bytes from the frame id's length through the last name;
    a message starting with the same bytes has the same names, so its position
    and velocity sequences start at the same offsets when their lengths
    (``counts``, read at ``count_at``) are the same too.
    """

    __slots__ = ('prefix', 'names', 'count_at', 'counts', 'value_at')

    def __init__(self, raw: bytes, names: tuple, end: int, count_at: tuple[int, int],
                 counts: tuple[int, int], value_at: tuple[int, int]):
        """Record the layout of ``raw`` (its names end at offset ``end``)."""
        self.prefix = bytes(raw[12:end])
        self.names = names
        self.count_at, self.counts, self.value_at = count_at, counts, value_at

    def values(self, raw: bytes) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """Return (positions, velocities) of ``raw`` when it has this layout, else None."""
        if (raw[12:12 + len(self.prefix)] != self.prefix
                or _U32.unpack_from(raw, self.count_at[0])[0] != self.counts[0]
                or _U32.unpack_from(raw, self.count_at[1])[0] != self.counts[1]):
            return None
        return tuple(np.frombuffer(raw, '<f8', n, at).astype(float) if n else np.zeros(0)
                     for n, at in zip(self.counts, self.value_at))


_joint_layout: list[Optional[_JointLayout]] = [None]
"""The layout of the last JointState decoded (a recording repeats one)."""


def joint_state_from_cdr(raw: bytes, time_ns: Optional[int] = None) -> list:
    """Decode a sensor_msgs/JointState; missing positions or velocities become NaN."""
    sec, nsec = _SEC_NSEC.unpack_from(raw, 4)
    ns = sec * 1_000_000_000 + nsec
    layout = _joint_layout[0]
    values = None if layout is None else layout.values(raw)
    if values is None:
        layout = _read_joint_layout(raw)
        _joint_layout[0] = layout
        values = layout.values(raw)
    pos, vel = values
    names = layout.names
    n = len(names)
    if pos.size != n:
        pos = np.full(n, np.nan)
    if vel.size != n:
        vel = np.full(n, np.nan)
    return [T.JointStateSample(ns * 1e-9, names, pos, vel, ns)]


def _read_joint_layout(raw: bytes) -> _JointLayout:
    """Parse the header, names and sequence lengths of a JointState."""
    r = _Reader(raw)
    r.header()
    names = tuple(r.string() for _ in range(r.u32()))
    end = r.pos
    count_at, counts, value_at = [], [], []
    for _ in range(2):  # positions, velocities
        r.align(4)
        count_at.append(r.pos)
        counts.append(r.u32())
        if counts[-1]:
            r.align(8)
        value_at.append(r.pos)
        r.pos += 8 * counts[-1]
    if r.pos > len(raw):
        raise ValueError('JointState shorter than its sequences')
    return _JointLayout(raw, names, end, tuple(count_at), tuple(counts), tuple(value_at))


def twist_from_cdr(raw: bytes, time_ns: Optional[int] = None) -> list:
    """Decode a geometry_msgs/Twist; its time is the receive time."""
    vx, vy, _, _, _, wz = _D6.unpack_from(raw, 4)
    ns = int(time_ns or 0)
    return [T.TwistSample(ns * 1e-9, vx, vy, wz, ns)]


def twist_stamped_from_cdr(raw: bytes, time_ns: Optional[int] = None) -> list:
    """Decode a geometry_msgs/TwistStamped (as a TwistSample at its stamp)."""
    r = _Reader(raw)
    ns, _ = r.header()
    vx, vy, _, _, _, wz = r.unpack(_D6, 8)
    return [T.TwistSample(ns * 1e-9, vx, vy, wz, ns)]


def navsat_from_cdr(raw: bytes, time_ns: Optional[int] = None) -> list:
    """Decode a sensor_msgs/NavSatFix."""
    r = _Reader(raw)
    ns, frame = r.header()
    status = struct.unpack_from('<b', raw, r.pos)[0]
    r.pos += 1
    r.align(2)
    r.pos += 2  # the uint16 service, not kept
    values = r.unpack(_NAVSAT, 8)
    cov = np.array(values[3:12]).reshape(3, 3)
    return [T.NavSatSample(ns * 1e-9, values[0], values[1], values[2], status, cov, frame, ns)]


def bool_from_cdr(raw: bytes, time_ns: Optional[int] = None) -> list:
    """Decode a std_msgs/Bool; its time is the receive time."""
    ns = int(time_ns or 0)
    return [T.BoolSample(ns * 1e-9, raw[4] != 0, ns)]


def diagnostics_from_cdr(raw: bytes, time_ns: Optional[int] = None) -> list:
    """Decode a diagnostic_msgs/DiagnosticArray."""
    r = _Reader(raw)
    ns, _ = r.header()
    statuses = []
    for _ in range(r.u32()):
        level = raw[r.pos]
        r.pos += 1
        name, message, hardware_id = r.string(), r.string(), r.string()
        values = tuple((r.string(), r.string()) for _ in range(r.u32()))
        statuses.append(T.DiagnosticStatus(name, level, message, hardware_id, values))
    return [T.DiagnosticSample(ns * 1e-9, tuple(statuses), ns)]


def transforms_from_cdr(raw: bytes, time_ns: Optional[int] = None) -> list:
    """Decode a tf2_msgs/TFMessage into static transforms."""
    r = _Reader(raw)
    out = []
    for _ in range(r.u32()):
        ns, parent = r.header()
        child = r.string()
        v = r.unpack(_D7, 8)
        out.append(T.StaticTransform(parent.lstrip('/'), child.lstrip('/'), np.array(v[:3]),
                                     quat_normalize((v[6], v[3], v[4], v[5])), ns * 1e-9, ns))
    return out


# ---------------------------------------------------------------------------------------
# encoders, byte-identical to the generic path (messages.*_to_msg + rosbags)
# ---------------------------------------------------------------------------------------
def _string(buf: bytearray, text: str) -> None:
    _pad(buf, 4)
    data = text.encode()
    buf += _U32.pack(len(data) + 1)
    buf += data
    buf += b'\x00'


def _doubles(buf: bytearray, values: Any) -> None:
    """Append a sequence of float64 (length, then the values aligned to 8 when any)."""
    arr = np.ascontiguousarray(values, dtype='<f8').ravel()
    _pad(buf, 4)
    buf += _U32.pack(arr.size)
    if arr.size:
        _pad(buf, 8)
        buf += arr.tobytes()


def _floats(buf: bytearray, values: Any) -> None:
    arr = np.ascontiguousarray(values, dtype='<f4').ravel()
    _pad(buf, 4)
    buf += _U32.pack(arr.size)
    buf += arr.tobytes()


def _stamp(s: Any) -> int:
    return T.stamp_of(s.t, s.stamp_ns)


def scan_to_cdr(s: T.ScanSample) -> bytes:
    """Serialize a :class:`ScanSample` as ``messages.scan_to_msg`` and rosbags do."""
    buf = _cdr_header(_stamp(s), s.frame_id)
    n = s.ranges.size
    _pad(buf, 4)
    buf += np.array((s.angle_min, s.angle_min + s.angle_increment * max(n - 1, 0),
                     s.angle_increment, s.time_increment, s.scan_time, s.range_min,
                     s.range_max), dtype='<f4').tobytes()
    _floats(buf, s.ranges)
    _floats(buf, s.intensities if s.intensities is not None else ())
    return bytes(buf)


def joint_state_to_cdr(s: T.JointStateSample) -> bytes:
    """Serialize a :class:`JointStateSample` (no efforts, empty frame id)."""
    buf = _cdr_header(_stamp(s), '')
    _pad(buf, 4)
    buf += _U32.pack(len(s.names))
    for name in s.names:
        _string(buf, name)
    _doubles(buf, s.position)
    _doubles(buf, s.velocity)
    _doubles(buf, ())
    return bytes(buf)


def twist_to_cdr(s: T.TwistSample) -> bytes:
    """Serialize a :class:`TwistSample` as an unstamped geometry_msgs/Twist."""
    return _CDR_LE + _D6.pack(float(s.vx), float(s.vy), 0.0, 0.0, 0.0, float(s.wz))


def twist_stamped_to_cdr(s: T.StampedTwistSample) -> bytes:
    """Serialize a :class:`StampedTwistSample` as a geometry_msgs/TwistStamped."""
    buf = _cdr_header(_stamp(s), s.frame_id)
    _pad(buf, 8)
    buf += _D6.pack(float(s.vx), float(s.vy), 0.0, 0.0, 0.0, float(s.wz))
    return bytes(buf)


def navsat_to_cdr(s: T.NavSatSample) -> bytes:
    """Serialize a :class:`NavSatSample` (covariance type 2 when finite, else 0)."""
    buf = _cdr_header(_stamp(s), s.frame_id)
    buf += struct.pack('<b', int(s.status))
    _pad(buf, 2)
    buf += struct.pack('<H', 1)
    _pad(buf, 8)
    finite = np.isfinite(s.position_cov)
    cov = np.where(finite, s.position_cov, 0.0).reshape(9).tolist()
    buf += _NAVSAT.pack(float(s.latitude), float(s.longitude), float(s.altitude), *cov,
                        2 if finite.all() else 0)
    return bytes(buf)


def bool_to_cdr(s: T.BoolSample) -> bytes:
    """Serialize a :class:`BoolSample` as a std_msgs/Bool."""
    return _CDR_LE + (b'\x01' if s.value else b'\x00')


def diagnostics_to_cdr(s: T.DiagnosticSample) -> bytes:
    """Serialize a :class:`DiagnosticSample` as a diagnostic_msgs/DiagnosticArray."""
    buf = _cdr_header(_stamp(s), '')
    _pad(buf, 4)
    buf += _U32.pack(len(s.statuses))
    for st in s.statuses:
        buf += struct.pack('<B', int(st.level))
        for text in (st.name, st.message, st.hardware_id):
            _string(buf, text)
        _pad(buf, 4)
        buf += _U32.pack(len(st.values))
        for key, value in st.values:
            _string(buf, str(key))
            _string(buf, str(value))
    return bytes(buf)


def transforms_to_cdr(transforms: list) -> bytes:
    """Serialize a list of :class:`StaticTransform` as a tf2_msgs/TFMessage."""
    buf = bytearray(_CDR_LE)
    buf += _U32.pack(len(transforms))
    for tf in transforms:
        _pad(buf, 4)
        ns = _stamp(tf)
        buf += _SEC_NSEC.pack(ns // 1_000_000_000, ns % 1_000_000_000)
        _string(buf, tf.parent)
        _string(buf, tf.child)
        _pad(buf, 8)
        tr, q = tf.translation, tf.rotation
        buf += _D7.pack(float(tr[0]), float(tr[1]), float(tr[2]), float(q[1]), float(q[2]),
                        float(q[3]), float(q[0]))
    return bytes(buf)


for _msgtype, _decode, _encode in (
        ('sensor_msgs/msg/LaserScan', scan_from_cdr, scan_to_cdr),
        ('sensor_msgs/msg/JointState', joint_state_from_cdr, joint_state_to_cdr),
        ('geometry_msgs/msg/Twist', twist_from_cdr, twist_to_cdr),
        ('geometry_msgs/msg/TwistStamped', twist_stamped_from_cdr, twist_stamped_to_cdr),
        ('sensor_msgs/msg/NavSatFix', navsat_from_cdr, navsat_to_cdr),
        ('std_msgs/msg/Bool', bool_from_cdr, bool_to_cdr),
        ('diagnostic_msgs/msg/DiagnosticArray', diagnostics_from_cdr, diagnostics_to_cdr),
        ('tf2_msgs/msg/TFMessage', transforms_from_cdr, transforms_to_cdr)):
    register_fast(_msgtype, decode=_decode, encode_cdr=_encode)
