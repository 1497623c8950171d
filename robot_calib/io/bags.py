# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Read ROS 1 and ROS 2 bags into core samples, and write ROS 2 bags (mcap or sqlite3).

Reading merges any number of bags in time order (bag receive time) and turns
every supported message into core samples with :mod:`robot_calib.codec`
(fast paths over the bytes where it has them, which is what lets replay read
well above 50k messages/s; rosbags' deserializer otherwise). mcap chunks
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
from operator import itemgetter
import os
from pathlib import Path
import shutil
from typing import AbstractSet, Any, Callable, Iterable, Iterator, Optional

from robot_calib import codec
from robot_calib.io import mcap, safe_yaml


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


def _check_metadata(meta: Path) -> None:
    """Raise BagError when a bag's metadata.yaml is hostile (an alias bomb, absurdly deep)."""
    import yaml
    try:
        safe_yaml.check_yaml_file(meta)
    except safe_yaml.YamlLimitError as exc:
        raise BagError(f'cannot read bag {meta.parent}: metadata.yaml {_one_line(exc)}') \
            from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        pass  # rosbags says what is wrong with it, as before


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
        if path.is_dir():
            _check_metadata(path / 'metadata.yaml')
        out.append(path)
    if not out:
        raise BagError('no bag given')
    return out


def open_reader(paths: Iterable[os.PathLike | str]) -> Any:
    """Open bags with rosbags' AnyReader (caller closes); BagError when unreadable."""
    from rosbags.highlevel import AnyReader
    bag_paths = _reader_paths(paths)
    reader = AnyReader(bag_paths, default_typestore=codec.typestore())
    try:
        reader.open()
    except Exception as exc:  # noqa: B902 - rosbags raises several error types
        raise BagError(f'cannot read {", ".join(map(str, bag_paths))}: '
                       f'{_one_line(exc)}') from None
    return reader


# ---------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------
UNDECODED = ('undecoded',)
"""The samples :meth:`BagSet.decoded` yields for a message of a lazy stream (not decoded)."""


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
                 'to_cdr', 'latched', 'conn', 'decode_batch', 'decode_pose')

    def __init__(self, topic: str, msgtype: str, count: int, bag: Path, conn: Any,
                 to_msg: Callable[[bytes], Any], to_cdr: Callable[[bytes], bytes],
                 ros1: bool, latched: bool):
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
            return codec.from_msg(msgtype, to_msg(raw), time_ns)

        self.decode_generic = generic
        supported = codec.supported(msgtype)
        self.decode_batch = codec.batch_decoder(msgtype, ros1) if supported else None
        self.decode = codec.decoder(msgtype, generic, ros1) if supported else generic
        self.decode_pose = codec.pose_decoder(msgtype, ros1)
        """(t, x, y, yaw) of a little-endian CDR message (odometry), None when there is none."""


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
                reader = AnyReader([path], default_typestore=codec.typestore())
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
        # the type store is imported on first use: the fast paths read ROS 2 bags without it
        for conn in reader.connections:
            msgtype = codec.normalize_type(conn.msgtype)
            if ros1:
                def to_msg(raw: bytes, _r=reader, _t=conn.msgtype) -> Any:
                    return _r.typestore.deserialize_ros1(raw, _t)

                def to_cdr(raw: bytes, _m=to_msg, _t=msgtype) -> bytes:
                    return bytes(codec.typestore().serialize_cdr(_m(raw), _t))
            else:
                def to_msg(raw: bytes, _t=msgtype) -> Any:
                    store = codec.typestore()
                    if _t not in store.fielddefs:
                        raise KeyError(f'type {_t} is not in the ROS 2 Jazzy typestore')
                    return store.deserialize_cdr(raw, _t)

                def to_cdr(raw: bytes) -> bytes:
                    return bytes(raw)
            self.streams.append(Stream(normalize_topic(conn.topic), msgtype, conn.msgcount or 0,
                                       path, conn, to_msg, to_cdr, ros1,
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

    def decoded(self, streams: Optional[Iterable[Stream]] = None, block: int = 512,
                lazy: AbstractSet[int] = frozenset()
                ) -> Iterator[tuple[Stream, int, bytes, Any]]:
        """
        Yield ``(stream, time_ns, raw, samples)`` like :meth:`messages`, decoded.

        ``samples`` is the list :meth:`Stream.decode` returns, or None when the
        message cannot be decoded, or :data:`UNDECODED` for the streams whose
        ``id`` is in ``lazy`` (the caller decodes what it needs; the set is read
        for each block, so the caller may change it). Messages are read
        ``block`` at a time so that streams with a batch decoder decode them
        together (same samples, faster; the samples of one batch share one array,
        so keeping one sample keeps at most ``block`` x 296 bytes alive).
        """
        it = self.messages(streams)
        while True:
            batch = list(islice(it, block))
            if not batch:
                return
            first = batch[0][0]
            if all(b[0] is first for b in batch):  # one topic only: the common case
                groups = ([list(range(len(batch)))]
                          if first.decode_batch is not None and id(first) not in lazy else [])
            else:
                by_stream: dict[int, list[int]] = {}
                for i, b in enumerate(batch):
                    if b[0].decode_batch is not None and id(b[0]) not in lazy:
                        by_stream.setdefault(id(b[0]), []).append(i)
                groups = list(by_stream.values())
            results: list = [UNDECODED if id(b[0]) in lazy else None for b in batch]
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
        streams = [s for s in bags.streams if s.msgtype in codec.TYPES
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
            raise BagError(f'cannot write bag {self.path}: {_one_line(exc)}') from None
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
