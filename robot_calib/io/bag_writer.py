# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Write core samples into a ROS 2 bag (mcap or sqlite3), atomically.

Writing goes to a temporary folder that is renamed into place only when the
bag is closed cleanly, so an interrupted run never leaves a bag that looks
complete; every mcap chunk written carries its CRC-32 (:mod:`robot_calib.io.mcap`).
:mod:`robot_calib.io.bags` re-exports :class:`BagWriter` and :func:`receive_time`.
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil
from typing import Any, Callable, Iterable, Optional

from robot_calib import codec
from robot_calib.io import mcap
from robot_calib.io.bag_common import BagError, normalize_topic, one_line


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
        self._pending: dict[int, list] = {}
        """Channel id -> [messages, first, last time (ns)] not yet in rosbags' counts."""
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
            if self._mcap is not None:
                mcap.fast_close_chunk(self._mcap)
        except OSError as exc:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            raise BagError(f'cannot write bag {self.path}: {one_line(exc)}') from None
        return self

    def _connection(self, topic: str, msgtype: str) -> Any:
        conn = self._conns.get(topic)
        if conn is None:
            qos = ()
            if topic in self._latched:
                qos = (_latched_qos(),)
            msgdef, rihs01 = codec.definition(msgtype)
            conn = self._writer.add_connection(topic, msgtype, msgdef=msgdef, rihs01=rihs01,
                                               offered_qos_profiles=qos)
            self._conns[topic] = conn
        elif conn.msgtype != msgtype:
            raise BagError(f'topic {topic} written with two types: {conn.msgtype} and {msgtype}')
        return conn

    def write(self, topic: str, sample: Any, time_ns: Optional[int] = None) -> None:
        """Write one core sample on ``topic`` at receive time ``time_ns`` (default: its stamp)."""
        msgtype, data = codec.serialize(sample)
        if time_ns is None:  # a list of transforms: the first one's stamp
            first = (sample[0] if sample else None) if isinstance(sample, list) else sample
            time_ns = codec.sample_time_ns(first) if first is not None else 0
        self.write_raw(topic, msgtype, data, time_ns)

    def write_raw(self, topic: str, msgtype: str, data: bytes, time_ns: int) -> None:
        """Write CDR bytes of ``msgtype``."""
        topic = normalize_topic(topic)
        self._put(self._connection(topic, msgtype), topic, int(time_ns), data)

    def raw_writer(self, topic: str, msgtype: str) -> Callable[[bytes, int], None]:
        """
        Return ``write(data, time_ns)``: :meth:`write_raw` on ``topic`` with ``msgtype``.

        The same records, with less work per message; the connection is added by
        the first message, as :meth:`write_raw` adds it.
        """
        topic = normalize_topic(topic)
        if self._mcap is not None:
            return self._direct_writer(topic, msgtype)
        conn = None

        def write(data: bytes, time_ns: int) -> None:
            nonlocal conn
            if conn is None:
                conn = self._connection(topic, msgtype)
            self._put(conn, topic, int(time_ns), data)
        return write

    def _direct_writer(self, topic: str, msgtype: str) -> Callable[[bytes, int], None]:
        """
        Return ``write(data, time_ns)`` appending mcap records as :meth:`_write_mcap` does.

        One call a message: the chunk's index and time span are kept as each record
        is appended; the counts and time span of the whole file (rosbags'
        ``channel_stats``, ``counts``, start and end times) are summed per channel
        in :attr:`_pending` and added before the file is closed (:meth:`_settle`).
        """
        st, counts, append = self._mcap, self.counts, mcap.append_message
        cid = -1
        pending: list = []

        def write(data: bytes, time_ns: int) -> None:
            nonlocal cid, pending
            if cid < 0:
                cid = self._connection(topic, msgtype).id
                pending = self._pending.setdefault(cid, [0, 2**63 - 1, 0])
                counts.setdefault(topic, 0)
            ts = receive_time(time_ns)
            append(st, cid, ts, data)
            pending[0] += 1
            if ts < pending[1]:
                pending[1] = ts
            if ts > pending[2]:
                pending[2] = ts
            self.count += 1
            counts[topic] += 1
        return write

    def _settle(self) -> None:
        """Add the counts and time spans :meth:`_direct_writer` kept aside to rosbags' own."""
        writer, st = self._writer, self._mcap
        for cid, (n, lo, hi) in self._pending.items():
            if not n:
                continue
            st.channel_stats[cid] += n
            writer.counts[cid] += n
            st.message_start_time = min(st.message_start_time, lo)
            st.message_end_time = max(st.message_end_time, hi)
            writer.min_timestamp = min(writer.min_timestamp, lo)
            writer.max_timestamp = max(writer.max_timestamp, hi)
        self._pending.clear()

    def _put(self, conn: Any, topic: str, time_ns: int, data: bytes) -> None:
        """Append one message record on ``conn`` (``topic``) and count it."""
        time_ns = receive_time(time_ns)
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
        if ts < st.message_start_time:
            st.message_start_time = ts
        if ts > st.message_end_time:
            st.message_end_time = ts
        st.channel_stats[cid] += 1
        mcap.append_message(st, cid, ts, data)
        writer.counts[cid] += 1
        if ts < writer.min_timestamp:
            writer.min_timestamp = ts
        if ts > writer.max_timestamp:
            writer.max_timestamp = ts

    def __exit__(self, exc_type, exc, tb) -> None:
        """Close; on success move the bag into place, on error remove the partial bag."""
        try:
            if self._writer is not None:
                if self._mcap is not None:
                    self._settle()
                self._writer.close()
        except BaseException:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            raise
        if exc_type is None:
            os.replace(self._tmp, self.path)
        shutil.rmtree(self._tmpdir, ignore_errors=True)


def receive_time(time_ns: int) -> int:
    """
    Return ``time_ns`` as a bag receive time (ns), or raise BagError when no bag can hold it.

    rosbag2 stores receive times as non-negative integers (mcap: uint64; both
    storages: below 2^63); one outside would fail the whole file when it is
    closed, so it is refused before anything of the message is written.
    """
    ts = int(time_ns)
    if not 0 <= ts < 2**63:
        raise BagError(f'receive time {ts} ns is outside 0 .. 2^63 - 1 ns')
    return ts


def _latched_qos() -> Any:
    """Return a rosbags Qos of reliable, transient-local, keep-last 1."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
    inf = QosTime(2147483647, 4294967295)
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
               inf, inf, QosLiveliness.AUTOMATIC, inf, False)
