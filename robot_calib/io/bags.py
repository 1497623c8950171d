# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Read ROS 1 and ROS 2 bags into core samples.

Reading merges any number of bags in time order (bag receive time) and turns
every supported message into core samples with :mod:`robot_calib.codec`
(fast paths over the bytes where it has them, which is what lets replay read
well above 50k messages/s; rosbags' deserializer otherwise). mcap chunks
are read by :mod:`robot_calib.io.mcap`: a chunk that fails its CRC is skipped
whole and listed in :attr:`BagSet.corrupt_chunks`.

Writing (ROS 2 bags, mcap or sqlite3) is in :mod:`robot_calib.io.bag_writer`;
its :class:`BagWriter` and :func:`receive_time` are importable from here too,
as are :class:`BagError` and :func:`normalize_topic` (:mod:`robot_calib.io.bag_common`).
"""

from __future__ import annotations

from dataclasses import dataclass
import heapq
from itertools import islice
from operator import itemgetter
import os
from pathlib import Path
from typing import AbstractSet, Any, Callable, Iterable, Iterator, Optional

from robot_calib import codec
from robot_calib.io import mcap, safe_yaml
from robot_calib.io.bag_common import BagError, normalize_topic, one_line
from robot_calib.io.bag_writer import BagWriter, receive_time  # noqa: F401 - re-exported


@dataclass(frozen=True)
class BagMessage:
    """One message read from a bag: topic, ROS 2 type, receive time (ns) and core samples."""

    topic: str
    msgtype: str
    time_ns: int
    samples: list


def _check_metadata(meta: Path) -> None:
    """Raise BagError when a bag's metadata.yaml is hostile (an alias bomb, absurdly deep)."""
    import yaml
    try:
        safe_yaml.check_yaml_file(meta)
    except safe_yaml.YamlLimitError as exc:
        raise BagError(f'cannot read bag {meta.parent}: metadata.yaml {one_line(exc)}') \
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
                       f'{one_line(exc)}') from None
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
            raise BagError(f'cannot read bag {path}: {one_line(exc)} (expected a ROS 2 '
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
            raise BagError(f'bag is truncated or corrupt: {one_line(exc)}') from None


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
