# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Read ROS 1 and ROS 2 bags into core samples, and write ROS 2 bags (mcap or sqlite3).

Reading merges any number of bags in time order (bag receive time) and turns
every supported message into core samples with :mod:`robot_calib.io.convert`.
``sensor_msgs/Imu`` and ``nav_msgs/Odometry`` take a fast path: their
serialized bytes (ROS 2 CDR or ROS 1) are decoded directly with
:mod:`struct`/numpy into the same samples the generic path gives (the tests
check that both agree), which is what lets replay read well above 50k
messages/s. Everything else goes through rosbags' deserializer. mcap chunks
are read by :mod:`robot_calib.io.mcap`: a chunk that fails its CRC is skipped
whole and listed in :attr:`BagSet.corrupt_chunks`.

Writing goes to a temporary folder that is renamed into place only when the
bag is closed cleanly, so an interrupted run never leaves a bag that looks
complete; every mcap chunk written carries its CRC-32.
"""

from __future__ import annotations

from dataclasses import dataclass
import heapq
from itertools import islice
import math
from operator import itemgetter
import os
from pathlib import Path
import shutil
import struct
from typing import Any, Callable, Iterable, Iterator, Optional

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy, quat_normalize, quat_to_rpy
from robot_calib.io import convert, mcap


class BagError(RuntimeError):
    """A bag that is missing, unreadable or not what was expected (one-line message)."""


@dataclass(frozen=True)
class BagMessage:
    """One message read from a bag: topic, ROS 2 type, receive time (ns) and core samples."""

    topic: str
    msgtype: str
    time_ns: int
    samples: list


def normalize_topic(topic: str) -> str:
    """Return ``topic`` with exactly one leading slash."""
    return '/' + topic.lstrip('/')


def _one_line(exc: BaseException) -> str:
    text = ' '.join(str(exc).split())
    return text or type(exc).__name__


def _reader_paths(paths: Iterable[os.PathLike | str]) -> list[Path]:
    out = []
    for p in paths:
        path = Path(p)
        if not path.exists():
            raise BagError(f'bag not found: {path} (expected a ROS 2 bag folder with '
                           'metadata.yaml, a ROS 2 .mcap file or a ROS 1 .bag file)')
        if path.is_file() and path.suffix in ('.mcap', '.db3'):
            if (path.parent / 'metadata.yaml').exists():
                path = path.parent
            elif path.suffix == '.db3':
                raise BagError(f'{path}: a ROS 2 sqlite3 bag is a folder with metadata.yaml; '
                               'give the folder')
            # else: a bare ROS 2 .mcap file (its own index names the topics)
        if path.is_dir() and not (path / 'metadata.yaml').exists():
            raise BagError(f'{path}: not a ROS 2 bag (no metadata.yaml in the folder)')
        out.append(path)
    if not out:
        raise BagError('no bag given')
    return out


def open_reader(paths: Iterable[os.PathLike | str]) -> Any:
    """Open bags with rosbags' AnyReader (caller closes); BagError when unreadable."""
    from rosbags.highlevel import AnyReader
    bag_paths = _reader_paths(paths)
    reader = AnyReader(bag_paths, default_typestore=convert.typestore())
    try:
        reader.open()
    except Exception as exc:  # noqa: B902 - rosbags raises several error types
        raise BagError(f'cannot read {", ".join(map(str, bag_paths))}: '
                       f'{_one_line(exc)}') from None
    return reader


# ---------------------------------------------------------------------------------------
# fast decoders (ROS 2 CDR little endian, and ROS 1)
# ---------------------------------------------------------------------------------------
_U32 = struct.Struct('<I')
_STAMP2 = struct.Struct('<iII')  # CDR: sec, nanosec, frame_id length (incl. NUL)
_STAMP1 = struct.Struct('<IIII')  # ROS 1: seq, secs, nsecs, frame_id length (no NUL)
_NAN33 = np.full((3, 3), np.nan)
_NAN33.setflags(write=False)


def _cov3(v: np.ndarray) -> np.ndarray:
    """Return a 3x3 covariance view, NaN-filled when ``v[0] < 0`` (as convert._cov3)."""
    if v[0] < 0:
        return np.full((3, 3), np.nan)
    return v.reshape(3, 3)


def _imu_sample(ns: int, frame: str, v: np.ndarray) -> T.ImuSample:
    """Build an ImuSample from the 37 doubles of a sensor_msgs/Imu after its header."""
    # v: orientation x y z w (0:4), orientation cov (4:13), gyro (13:16), gyro cov (16:25),
    # accel (25:28), accel cov (28:37)
    orientation = ocov = None
    if v[4] >= 0 and (v[0] != 0.0 or v[1] != 0.0 or v[2] != 0.0 or v[3] != 0.0):
        orientation = np.array((v[3], v[0], v[1], v[2]))
        ocov = v[4:13].reshape(3, 3)
    return T.ImuSample(ns * 1e-9, v[13:16], v[25:28], frame, orientation, ocov,
                       _cov3(v[16:25]), _cov3(v[28:37]), ns)


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


def _odom_sample(ns: int, frame: str, child: str, v: np.ndarray) -> T.OdomSample:
    """Build an OdomSample from the 85 doubles of a nav_msgs/Odometry after its frames."""
    # v: position (0:3), orientation x y z w (3:7), pose cov 6x6 (7:43), linear (43:46),
    # angular (46:49), twist cov 6x6 (49:85)
    q = (float(v[6]), float(v[3]), float(v[4]), float(v[5]))
    roll, pitch, yaw = quat_to_rpy(quat_normalize(q))
    pcov = v[7:43].reshape(6, 6)[convert._POSE_IDX]
    tcov = v[49:85].reshape(6, 6)[convert._POSE_IDX]
    return T.OdomSample(ns * 1e-9, float(v[0]), float(v[1]), yaw, float(v[43]), float(v[44]),
                        float(v[48]), frame, child, pcov, tcov, float(v[2]), roll, pitch, ns,
                        math.hypot(*q))


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
# fast encoders (little-endian CDR), byte-identical to convert.serialize
# ---------------------------------------------------------------------------------------
_CDR_LE = b'\x00\x01\x00\x00'
_POSE_FLAT = np.ravel_multi_index(convert._POSE_IDX, (6, 6)).ravel().tolist()
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
    """Return 9 covariance values as convert._cov_out does (unknown in [0] when absent)."""
    if cov is not None:
        c = np.asarray(cov, dtype=float).ravel().tolist()
        if len(c) == 9 and all(map(math.isfinite, c)):
            return c
    return [unknown, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]


def _cov36(cov3: np.ndarray) -> list:
    """Return a 6x6 covariance as convert._cov6 builds it (1e6 on z, roll, pitch)."""
    out = [0.0] * 36
    out[14] = out[21] = out[28] = 1e6
    isf = math.isfinite
    for i, v in zip(_POSE_FLAT, np.asarray(cov3, dtype=float).ravel().tolist()):
        out[i] = v if isf(v) else 0.0
    return out


def imu_to_cdr(s: T.ImuSample) -> bytes:
    """Serialize an :class:`ImuSample` as convert.serialize does, without building a message."""
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


def odom_to_cdr(s: T.OdomSample) -> bytes:
    """Serialize an :class:`OdomSample` as convert.serialize does, without building a message."""
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


_TO_CDR = {T.ImuSample: ('sensor_msgs/msg/Imu', imu_to_cdr),
           T.OdomSample: ('nav_msgs/msg/Odometry', odom_to_cdr)}


def serialize(sample: Any) -> tuple[str, bytes]:
    """Return (msgtype, CDR bytes) of a core sample: fast for Imu/Odometry, else convert's."""
    fast = _TO_CDR.get(type(sample))
    if fast is not None and sample.stamp_ns < 2**62 and (sample.stamp_ns >= 0 or (
            0 <= sample.t < 2**31)):
        return fast[0], fast[1](sample)
    return convert.serialize(sample)


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


_FAST_CDR = {'sensor_msgs/msg/Imu': imu_from_cdr, 'nav_msgs/msg/Odometry': odom_from_cdr}
FAST_DECODERS = _FAST_CDR
"""Direct decoders of little-endian CDR by message type (same samples as convert.deserialize)."""
_BATCH_CDR = {'sensor_msgs/msg/Imu': imu_batch_from_cdr}
_FAST_ROS1 = {'sensor_msgs/msg/Imu': imu_from_ros1, 'nav_msgs/msg/Odometry': odom_from_ros1}


def _fast_cdr(fn: Callable[[bytes], Any], generic: Callable[[bytes, int], list]
              ) -> Callable[[bytes, int], list]:
    def decode(raw: bytes, time_ns: int) -> list:
        if raw[1] != 1:  # big-endian CDR: rare, take the generic path
            return generic(raw, time_ns)
        return [fn(raw)]
    return decode


def _fast_ros1(fn: Callable[[bytes], Any]) -> Callable[[bytes, int], list]:
    def decode(raw: bytes, time_ns: int) -> list:
        return [fn(raw)]
    return decode


# ---------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------
class Stream:
    """
    One topic of one bag: its normalized name, ROS 2 type, count and decoders.

    ``decode(raw, time_ns)`` returns core samples (fast path when available);
    ``decode_generic`` always goes through rosbags; ``decode_batch(raws)`` (None
    when the type has none) decodes many messages at once; ``to_msg(raw)``
    returns the rosbags message and ``to_cdr(raw)`` ROS 2 CDR bytes (for live
    publishing).
    """

    __slots__ = ('topic', 'msgtype', 'count', 'bag', 'decode', 'decode_generic', 'to_msg',
                 'to_cdr', 'latched', 'conn', 'decode_batch')

    def __init__(self, topic: str, msgtype: str, count: int, bag: Path, conn: Any,
                 to_msg: Callable[[bytes], Any], to_cdr: Callable[[bytes], bytes],
                 fast: Optional[Callable[[bytes], Any]], ros1: bool, latched: bool):
        """Set up the decoders of one connection."""
        self.topic = topic
        self.msgtype = msgtype
        self.count = count
        self.bag = bag
        self.conn = conn
        self.to_msg = to_msg
        self.to_cdr = to_cdr
        self.latched = latched

        def generic(raw: bytes, time_ns: int) -> list:
            return convert.from_msg(msgtype, to_msg(raw), time_ns)

        self.decode_generic = generic
        self.decode_batch = None if ros1 else _BATCH_CDR.get(msgtype)
        if fast is None:
            self.decode = generic
        elif ros1:
            self.decode = _fast_ros1(fast)
        else:
            self.decode = _fast_cdr(fast, generic)


def _is_latched(conn: Any) -> bool:
    try:
        from rosbags.interfaces import QosDurability
        qos = getattr(conn.ext, 'offered_qos_profiles', None) or []
        return any(q.durability == QosDurability.TRANSIENT_LOCAL for q in qos)
    except Exception:  # noqa: B902 - QoS metadata is informative only
        return False


class BagSet:
    """
    Several ROS 1 / ROS 2 bags opened for reading, merged in receive-time order.

    Use as a context manager. :attr:`streams` lists every connection;
    :meth:`topics` summarizes them; :meth:`messages` yields
    ``(stream, time_ns, raw_bytes)``.
    """

    def __init__(self, paths: Iterable[os.PathLike | str]):
        """Open every bag; BagError (one line) when one is missing or unreadable."""
        self.paths = _reader_paths(paths)
        self._readers: list[tuple[Any, bool]] = []
        self.streams: list[Stream] = []
        self.corrupt_chunks: list[dict] = []
        """mcap chunks skipped while reading (see :func:`mcap.messages`), in reading order."""
        try:
            for path in self.paths:
                self._open(path)
        except BaseException:
            self.close()
            raise

    def _open(self, path: Path) -> None:
        ros1 = path.is_file() and path.suffix != '.mcap'
        try:
            if ros1:
                from rosbags.highlevel import AnyReader
                reader = AnyReader([path], default_typestore=convert.typestore())
            elif path.is_file():
                reader = mcap.BareMcap(path)
            else:
                from rosbags.rosbag2 import Reader
                reader = Reader(path)
            reader.open()
        except Exception as exc:  # noqa: B902 - rosbags raises several error types
            raise BagError(f'cannot read bag {path}: {_one_line(exc)} (expected a ROS 2 '
                           'bag folder or a ROS 1 .bag file)') from None
        self._readers.append((reader, ros1))
        store = convert.typestore()
        for conn in reader.connections:
            msgtype = convert.normalize_type(conn.msgtype)
            if ros1:
                def to_msg(raw: bytes, _r=reader, _t=conn.msgtype) -> Any:
                    return _r.typestore.deserialize_ros1(raw, _t)

                def to_cdr(raw: bytes, _m=to_msg, _t=msgtype) -> bytes:
                    return bytes(store.serialize_cdr(_m(raw), _t))
                fast = _FAST_ROS1.get(msgtype)
            else:
                known = msgtype in store.fielddefs

                def to_msg(raw: bytes, _t=msgtype, _known=known) -> Any:
                    if not _known:
                        raise KeyError(f'type {_t} is not in the ROS 2 Jazzy typestore')
                    return store.deserialize_cdr(raw, _t)

                def to_cdr(raw: bytes) -> bytes:
                    return bytes(raw)
                fast = _FAST_CDR.get(msgtype)
            self.streams.append(Stream(normalize_topic(conn.topic), msgtype, conn.msgcount or 0,
                                       path, conn, to_msg, to_cdr, fast, ros1,
                                       _is_latched(conn)))

    def __enter__(self) -> 'BagSet':
        """Return self."""
        return self

    def __exit__(self, *exc: Any) -> None:
        """Close every bag."""
        self.close()

    def close(self) -> None:
        """Close every bag (idempotent)."""
        readers, self._readers = self._readers, []
        for reader, _ in readers:
            try:
                reader.close()
            except Exception:  # noqa: B902 - closing a broken bag must not mask the cause
                pass

    def topics(self) -> dict[str, tuple[str, int]]:
        """Return ``{topic: (ROS 2 message type, message count)}`` over all bags."""
        out: dict[str, tuple[str, int]] = {}
        for s in self.streams:
            prev = out.get(s.topic)
            out[s.topic] = (prev[0] if prev else s.msgtype, (prev[1] if prev else 0) + s.count)
        return out

    def custom_data(self) -> dict[str, str]:
        """Return the ``custom_data`` of the bags' metadata, merged (ROS 2 bags; {} else)."""
        out: dict[str, str] = {}
        for reader, _ in self._readers:
            meta = getattr(getattr(reader, 'storage', None), 'metadata', None)
            out.update(getattr(meta, 'custom', None) or {})
        return out

    @property
    def start_ns(self) -> int:
        """Return the earliest receive time over all bags (ns), 0 when empty."""
        times = [r.start_time for r, _ in self._readers if r.message_count]
        return min(times) if times else 0

    @property
    def end_ns(self) -> int:
        """Return the latest receive time over all bags (ns), 0 when empty."""
        times = [r.end_time for r, _ in self._readers if r.message_count]
        return max(times) if times else 0

    def messages(self, streams: Optional[Iterable[Stream]] = None
                 ) -> Iterator[tuple[Stream, int, bytes]]:
        """
        Yield ``(stream, time_ns, raw)`` of ``streams`` (all when None) in time order.

        Raises BagError when a bag turns out truncated or corrupt while reading.
        """
        wanted = self.streams if streams is None else list(streams)
        iters = []
        for reader, _ in self._readers:
            mine = {id(s.conn): s for s in wanted if any(s.conn is c for c in reader.connections)}
            if mine:
                iters.append(self._iter(reader, mine, self.corrupt_chunks))
        if len(iters) == 1:
            return iters[0]
        return heapq.merge(*iters, key=itemgetter(1))

    def decoded(self, streams: Optional[Iterable[Stream]] = None, block: int = 512
                ) -> Iterator[tuple[Stream, int, bytes, Optional[list]]]:
        """
        Yield ``(stream, time_ns, raw, samples)`` like :meth:`messages`, decoded.

        ``samples`` is the list :meth:`Stream.decode` returns, or None when the
        message cannot be decoded. Messages are read ``block`` at a time so that
        streams with a batch decoder decode them together (same samples, faster;
        the samples of one batch share one array, so keeping one sample keeps at
        most ``block`` x 296 bytes alive).
        """
        it = self.messages(streams)
        while True:
            batch = list(islice(it, block))
            if not batch:
                return
            first = batch[0][0]
            if all(b[0] is first for b in batch):  # one topic only: the common case
                groups = [list(range(len(batch)))] if first.decode_batch is not None else []
            else:
                by_stream: dict[int, list[int]] = {}
                for i, b in enumerate(batch):
                    if b[0].decode_batch is not None:
                        by_stream.setdefault(id(b[0]), []).append(i)
                groups = list(by_stream.values())
            results: list = [None] * len(batch)
            for idx in groups:
                stream = batch[idx[0]][0]
                try:
                    decoded = stream.decode_batch([batch[i][2] for i in idx])
                except Exception:  # noqa: B902 - decode these one by one below
                    continue
                for i, samples in zip(idx, decoded):
                    results[i] = samples
            for i in [i for i, r in enumerate(results) if r is None]:
                stream, time_ns, raw = batch[i]
                try:
                    results[i] = stream.decode(raw, time_ns)
                except Exception:  # noqa: B902 - the caller counts it (samples None)
                    pass
            yield from [(b[0], b[1], b[2], r) for b, r in zip(batch, results)]

    @staticmethod
    def _iter(reader: Any, mine: dict[int, Stream], corrupt: list
              ) -> Iterator[tuple[Stream, int, bytes]]:
        conns = [s.conn for s in mine.values()]
        try:
            fast = mcap.messages(reader, conns, mine, corrupt)
            if fast is not None:
                yield from fast
                return
            for conn, time_ns, raw in reader.messages(connections=conns):
                yield mine[id(conn)], time_ns, raw
        except Exception as exc:  # noqa: B902 - any failure here is a broken file
            raise BagError(f'bag is truncated or corrupt: {_one_line(exc)}') from None


def list_topics(paths: Iterable[os.PathLike | str]) -> dict[str, tuple[str, int]]:
    """Return {topic: (ROS 2 message type, message count)} of the bags."""
    with BagSet(paths) as bags:
        return bags.topics()


def read_messages(paths: Iterable[os.PathLike | str],
                  topics: Optional[Iterable[str]] = None,
                  errors: Optional[dict[str, int]] = None) -> Iterator[BagMessage]:
    """
    Yield the supported messages of ``topics`` (all when None) in receive-time order.

    Messages that fail to deserialize, and those of mcap chunks skipped as corrupt,
    are counted in ``errors`` (by topic); messages of unsupported types are not read.
    """
    wanted = None if topics is None else {normalize_topic(t) for t in topics}
    with BagSet(paths) as bags:
        streams = [s for s in bags.streams if s.msgtype in convert.SUPPORTED_TYPES
                   and (wanted is None or s.topic in wanted)]
        if not streams:
            return
        for stream, time_ns, _, samples in bags.decoded(streams):
            if samples is None:  # a corrupt message must not end the run
                if errors is not None:
                    errors[stream.topic] = errors.get(stream.topic, 0) + 1
                continue
            yield BagMessage(stream.topic, stream.msgtype, time_ns, samples)
        if errors is not None:  # messages of corrupt chunks (skipped whole)
            for chunk in bags.corrupt_chunks:
                for topic, n in chunk['messages'].items():
                    errors[topic] = errors.get(topic, 0) + n


# ---------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------
class BagWriter:
    """
    Write core samples into a ROS 2 bag (mcap by default, or sqlite3), atomically.

    Use as a context manager; the bag appears at ``path`` only after a clean
    close. ``write(topic, sample, time_ns)`` takes a core sample, or a list of
    :class:`StaticTransform` for ``/tf_static``; ``latched`` topics are offered
    with transient-local durability. ``compress`` zstd-compresses mcap chunks
    (readable by rosbag2 and rosbags).
    """

    def __init__(self, path: os.PathLike | str, storage: str = 'mcap',
                 latched: Iterable[str] = ('/tf_static',), compress: bool = False,
                 custom: Optional[dict[str, str]] = None):
        """
        Prepare a writer; BagError when the target exists or its folder is not writable.

        ``custom`` is written into the bag's metadata (``custom_data``: string keys
        and values, as rosbag2 keeps them).
        """
        from rosbags.rosbag2 import StoragePlugin
        self.path = Path(path)
        if storage not in ('mcap', 'sqlite3'):
            raise BagError(f'unknown storage {storage!r}; expected mcap or sqlite3')
        if self.path.exists():
            raise BagError(f'output bag already exists: {self.path}')
        parent = self.path.parent if str(self.path.parent) else Path('.')
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            raise BagError(f'output folder is missing or not writable: {parent}')
        self._plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        self._custom = {str(k): str(v) for k, v in (custom or {}).items()}
        self._compress = bool(compress) and storage == 'mcap'
        self._tmpdir = parent / f'.{self.path.name}.partial'
        self._tmp = self._tmpdir / self.path.name
        self._latched = {normalize_topic(t) for t in latched}
        self._writer = None
        self._mcap = None
        self.fast_mcap = True  # write mcap records directly (same bytes as rosbags)
        self._conns: dict[str, Any] = {}
        self.count = 0
        self.counts: dict[str, int] = {}

    def __enter__(self) -> 'BagWriter':
        """Open the temporary bag."""
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, Writer
        if self._tmpdir.exists():
            shutil.rmtree(self._tmpdir)
        try:
            self._tmpdir.mkdir()
            self._writer = Writer(self._tmp, version=9, storage_plugin=self._plugin)
            if self._compress:
                self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            for key, value in self._custom.items():
                self._writer.set_custom_data(key, value)
            self._writer.open()
            mcap.write_chunk_crcs(self._writer)
            self._mcap = mcap.fast_storage(self._writer) if self.fast_mcap else None
        except OSError as exc:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            raise BagError(f'cannot write bag {self.path}: {_one_line(exc)}') from None
        return self

    def _connection(self, topic: str, msgtype: str) -> Any:
        conn = self._conns.get(topic)
        if conn is None:
            qos = ()
            if topic in self._latched:
                qos = (_latched_qos(),)
            conn = self._writer.add_connection(topic, msgtype, typestore=convert.typestore(),
                                               offered_qos_profiles=qos)
            self._conns[topic] = conn
        elif conn.msgtype != msgtype:
            raise BagError(f'topic {topic} written with two types: {conn.msgtype} and {msgtype}')
        return conn

    def write(self, topic: str, sample: Any, time_ns: Optional[int] = None) -> None:
        """Write one core sample on ``topic`` at receive time ``time_ns`` (default: its stamp)."""
        if isinstance(sample, list):
            msgtype, msg = convert.to_msg(sample)
            self.write_msg(topic, msgtype, msg, time_ns if time_ns is not None else (
                convert.sample_time_ns(sample[0]) if sample else 0))
            return
        msgtype, data = serialize(sample)
        self.write_raw(topic, msgtype, data, time_ns if time_ns is not None else
                       convert.sample_time_ns(sample))

    def write_msg(self, topic: str, msgtype: str, msg: Any, time_ns: int) -> None:
        """Write an already built rosbags message."""
        data = convert.typestore().serialize_cdr(msg, msgtype)
        self.write_raw(topic, msgtype, data, time_ns)

    def write_raw(self, topic: str, msgtype: str, data: bytes, time_ns: int) -> None:
        """Write CDR bytes of ``msgtype``."""
        topic = normalize_topic(topic)
        conn = self._connection(topic, msgtype)
        time_ns = int(time_ns)
        if self._mcap is not None:
            self._write_mcap(conn, time_ns, data)
        else:
            self._writer.write(conn, time_ns, data)
        self.count += 1
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def _write_mcap(self, conn: Any, ts: int, data: bytes) -> None:
        """
        Append one message record as rosbags' McapWriter.write does, byte for byte.

        rosbags builds each record field by field through a BytesIO and checks the
        connection by equality against all others; this packs the 31-byte record
        header at once (op 0x05, length, channel id, sequence 0, log and publish
        time) and keeps the same chunk index and statistics.
        """
        writer, st = self._writer, self._mcap
        cid = conn.id
        chunk = st.chunk
        if ts < st.message_start_time:
            st.message_start_time = ts
        if ts > st.message_end_time:
            st.message_end_time = ts
        st.channel_stats[cid] += 1
        if ts < chunk.message_start_time:
            chunk.message_start_time = ts
        if ts > chunk.message_end_time:
            chunk.message_end_time = ts
        bio = chunk.bio
        chunk.msgs[cid].append((ts, bio.tell()))
        bio.write(mcap.MESSAGE_HEADER.pack(0x05, 22 + len(data), cid, 0, ts, ts))
        bio.write(data)
        if bio.tell() > 2**20:
            st.close_chunk()
        writer.counts[cid] += 1
        if ts < writer.min_timestamp:
            writer.min_timestamp = ts
        if ts > writer.max_timestamp:
            writer.max_timestamp = ts

    def __exit__(self, exc_type, exc, tb) -> None:
        """Close; on success move the bag into place, on error remove the partial bag."""
        try:
            if self._writer is not None:
                self._writer.close()
        except BaseException:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            raise
        if exc_type is None:
            os.replace(self._tmp, self.path)
        shutil.rmtree(self._tmpdir, ignore_errors=True)


def _latched_qos() -> Any:
    """Return a rosbags Qos of reliable, transient-local, keep-last 1."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
    inf = QosTime(2147483647, 4294967295)
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
               inf, inf, QosLiveliness.AUTOMATIC, inf, False)
