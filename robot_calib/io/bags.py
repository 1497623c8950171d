# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Read ROS 1 and ROS 2 bags into core samples, and write ROS 2 bags (mcap or sqlite3).

Reading merges any number of bags in time order (bag receive time) and turns
every supported message into core samples with :mod:`robot_calib.io.convert`.
Writing goes to a temporary folder that is renamed into place only when the
bag is closed cleanly, so an interrupted run never leaves a bag that looks
complete.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import shutil
from typing import Any, Iterable, Iterator, Optional

from robot_calib.io import convert


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


def _reader_paths(paths: Iterable[os.PathLike | str]) -> list[Path]:
    out = []
    for p in paths:
        path = Path(p)
        if not path.exists():
            raise BagError(f'bag not found: {path}')
        if path.is_file() and path.suffix in ('.mcap', '.db3') and \
                not (path.parent / 'metadata.yaml').exists():
            raise BagError(f'{path}: a ROS 2 bag is a folder with metadata.yaml; '
                           'give the folder')
        if path.is_file() and path.suffix in ('.mcap', '.db3'):
            path = path.parent
        out.append(path)
    return out


def open_reader(paths: Iterable[os.PathLike | str]) -> Any:
    """Open bags with rosbags' AnyReader (caller closes); BagError when unreadable."""
    from rosbags.highlevel import AnyReader
    bag_paths = _reader_paths(paths)
    reader = AnyReader(bag_paths, default_typestore=convert.typestore())
    try:
        reader.open()
    except Exception as exc:  # rosbags raises several error types for broken bags
        raise BagError(f'cannot read {", ".join(map(str, bag_paths))}: {exc}') from None
    return reader


def list_topics(paths: Iterable[os.PathLike | str]) -> dict[str, tuple[str, int]]:
    """Return {topic: (ROS 2 message type, message count)} of the bags."""
    reader = open_reader(paths)
    try:
        out: dict[str, tuple[str, int]] = {}
        for c in reader.connections:
            topic = normalize_topic(c.topic)
            count = out.get(topic, ('', 0))[1] + (c.msgcount or 0)
            out[topic] = (convert.normalize_type(c.msgtype), count)
        return out
    finally:
        reader.close()


def read_messages(paths: Iterable[os.PathLike | str],
                  topics: Optional[Iterable[str]] = None,
                  errors: Optional[dict[str, int]] = None) -> Iterator[BagMessage]:
    """
    Yield the supported messages of ``topics`` (all when None) in receive-time order.

    Messages that fail to deserialize are counted in ``errors`` (by topic) and
    skipped; messages of unsupported types are not read.
    """
    wanted = None if topics is None else {normalize_topic(t) for t in topics}
    reader = open_reader(paths)
    try:
        conns = [c for c in reader.connections
                 if convert.normalize_type(c.msgtype) in convert.SUPPORTED_TYPES
                 and (wanted is None or normalize_topic(c.topic) in wanted)]
        if not conns:
            return
        try:
            for conn, time_ns, raw in reader.messages(connections=conns):
                topic = normalize_topic(conn.topic)
                msgtype = convert.normalize_type(conn.msgtype)
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                    samples = convert.from_msg(msgtype, msg, time_ns)
                except Exception:  # a corrupt message must not end the run
                    if errors is not None:
                        errors[topic] = errors.get(topic, 0) + 1
                    continue
                yield BagMessage(topic, msgtype, time_ns, samples)
        except Exception as exc:  # truncated file in the middle of the data
            if isinstance(exc, GeneratorExit):
                raise
            raise BagError(f'bag is truncated or corrupt: {exc}') from None
    finally:
        reader.close()


class BagWriter:
    """
    Write core samples into a ROS 2 bag (mcap by default, or sqlite3), atomically.

    Use as a context manager; the bag appears at ``path`` only after a clean
    close. ``write(topic, sample, time_ns)`` takes a core sample, or a list of
    :class:`StaticTransform` for ``/tf_static``; ``latched`` topics are offered
    with transient-local durability.
    """

    def __init__(self, path: os.PathLike | str, storage: str = 'mcap',
                 latched: Iterable[str] = ('/tf_static',)):
        """Prepare a writer; BagError when the target exists or its folder is not writable."""
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
        self._tmp = parent / f'.{self.path.name}.partial'
        self._latched = {normalize_topic(t) for t in latched}
        self._writer = None
        self._conns: dict[str, Any] = {}
        self.count = 0

    def __enter__(self) -> 'BagWriter':
        """Open the temporary bag."""
        from rosbags.rosbag2 import Writer
        if self._tmp.exists():
            shutil.rmtree(self._tmp)
        self._writer = Writer(self._tmp, version=9, storage_plugin=self._plugin)
        self._writer.open()
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
        msgtype, msg = convert.to_msg(sample)
        self.write_msg(topic, msgtype, msg, time_ns if time_ns is not None else (
            convert.sample_time_ns(sample) if not isinstance(sample, list) else
            (convert.sample_time_ns(sample[0]) if sample else 0)))

    def write_msg(self, topic: str, msgtype: str, msg: Any, time_ns: int) -> None:
        """Write an already built rosbags message."""
        data = convert.typestore().serialize_cdr(msg, msgtype)
        self.write_raw(topic, msgtype, data, time_ns)

    def write_raw(self, topic: str, msgtype: str, data: bytes, time_ns: int) -> None:
        """Write CDR bytes of ``msgtype``."""
        conn = self._connection(normalize_topic(topic), msgtype)
        self._writer.write(conn, int(time_ns), data)
        self.count += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        """Close; on success move the bag into place, on error remove the partial bag."""
        try:
            if self._writer is not None:
                self._writer.close()
        finally:
            if exc_type is None:
                os.replace(self._tmp, self.path)
            else:
                shutil.rmtree(self._tmp, ignore_errors=True)


def _latched_qos() -> Any:
    """Return a rosbags Qos of reliable, transient-local, keep-last 1."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
    inf = QosTime(2147483647, 4294967295)
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
               inf, inf, QosLiveliness.AUTOMATIC, inf, False)
