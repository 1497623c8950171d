# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Convert a ROS 1 (or ROS 2) bag into a ROS 2 bag, renaming topics and adding /tf_static.

Messages are copied field for field into the ROS 2 Jazzy types (ROS 1 headers
lose their ``seq``; nothing else changes), so covariances and frames stay
exactly as recorded. Used to build the sample bags under ``bags/``; run
``python -m robot_calib.io.convert_bag --help`` for the command line.

Static transforms follow ``static_transform_publisher``'s argument order:
``x y z yaw pitch roll parent child`` (m, rad).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Iterable, Mapping, Optional, Sequence, Union

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy
from robot_calib.io.bag_writer import BagWriter
from robot_calib.io.bags import BagError, BagSet, normalize_topic

_NS = 1_000_000_000


def static_transform(x: float, y: float, z: float, yaw: float, pitch: float, roll: float,
                     parent: str, child: str, stamp_ns: int = 0) -> T.StaticTransform:
    """
    Return the transform ``static_transform_publisher x y z yaw pitch roll parent child`` gives.

    :param x: translation x (m); likewise ``y``, ``z``.
    :param yaw: rotation about z (rad), applied first of the intrinsic z-y'-x'' sequence;
        likewise ``pitch`` about y and ``roll`` about x (rad).
    """
    q = quat_from_rpy(roll, pitch, yaw)
    return T.StaticTransform(parent.lstrip('/'), child.lstrip('/'),
                             np.array((x, y, z), dtype=float), np.asarray(q, dtype=float),
                             stamp_ns * 1e-9, stamp_ns)


def convert_bag(src: Union[str, os.PathLike], dst: Union[str, os.PathLike],
                renames: Optional[Mapping[str, str]] = None,
                topics: Optional[Iterable[str]] = None,
                static: Sequence[T.StaticTransform] = (), storage: str = 'mcap',
                compress: bool = True, start: float = 0.0,
                duration: Optional[float] = None) -> dict[str, int]:
    """
    Copy ``src`` into a new ROS 2 bag ``dst``; return the message count per topic.

    :param src: input bag (ROS 1 ``.bag`` file or ROS 2 folder).
    :param dst: output ROS 2 bag folder (must not exist).
    :param renames: ``{bag topic: new name}``.
    :param topics: keep only these topics (names after renaming); None keeps every topic
        whose type exists in ROS 2 Jazzy.
    :param static: transforms to publish on ``/tf_static`` at the first kept message time.
    :param storage: 'mcap' (default) or 'sqlite3'.
    :param compress: zstd-compress mcap chunks.
    :param start: skip the first ``start`` seconds of the recording (s).
    :param duration: keep at most this many seconds after ``start`` (s); None: all.
    """
    rename = {normalize_topic(k): normalize_topic(v) for k, v in (renames or {}).items()}
    keep = None if topics is None else {normalize_topic(t) for t in topics}
    from robot_calib import codec
    store = codec.typestore()
    counts: dict[str, int] = {}
    with BagSet([src]) as bags:
        missing = set(rename) - set(bags.topics())
        if missing:
            raise BagError(f'cannot rename {sorted(missing)}: not in {src}')
        chosen = []
        for s in bags.streams:
            name = rename.get(s.topic, s.topic)
            if keep is not None and name not in keep:
                continue
            if s.msgtype not in store.fielddefs:
                if keep is not None:
                    raise BagError(f'{s.topic}: type {s.msgtype} does not exist in ROS 2')
                continue
            chosen.append((s, name))
        names = {id(s): name for s, name in chosen}
        t_first = bags.start_ns + int(round(start * _NS))
        t_stop = None if duration is None else t_first + int(round(duration * _NS))
        with BagWriter(dst, storage=storage, compress=compress) as writer:
            wrote_static = not static
            for stream, time_ns, raw in bags.messages([s for s, _ in chosen]):
                if time_ns < t_first:
                    continue
                if t_stop is not None and time_ns > t_stop:
                    break
                if not wrote_static:
                    tfs = [T.StaticTransform(tf.parent, tf.child, tf.translation, tf.rotation,
                                             time_ns * 1e-9, time_ns) for tf in static]
                    writer.write('/tf_static', tfs, time_ns)
                    counts['/tf_static'] = 1
                    wrote_static = True
                writer.write_raw(names[id(stream)], stream.msgtype, stream.to_cdr(raw), time_ns)
                counts[names[id(stream)]] = counts.get(names[id(stream)], 0) + 1
    return counts


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Command line: ``python -m robot_calib.io.convert_bag SRC DST [options]``."""
    parser = argparse.ArgumentParser(
        prog='python -m robot_calib.io.convert_bag',
        description='Convert a ROS 1/ROS 2 bag into a ROS 2 bag (mcap by default).')
    parser.add_argument('src', help='input bag (.bag file or ROS 2 folder)')
    parser.add_argument('dst', help='output ROS 2 bag folder (must not exist)')
    parser.add_argument('--rename', action='append', default=[], metavar='FROM:=TO',
                        help='rename a topic (repeatable)')
    parser.add_argument('--topics', default=None,
                        help='comma-separated topics to keep (names after renaming)')
    parser.add_argument('--static', action='append', default=[],
                        metavar='"X Y Z YAW PITCH ROLL PARENT CHILD"',
                        help='add a static transform (static_transform_publisher order)')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    parser.add_argument('--no-compress', action='store_true', help='do not compress mcap')
    parser.add_argument('--start', type=float, default=0.0, help='skip the first S seconds')
    parser.add_argument('--duration', type=float, default=None, help='keep S seconds')
    args = parser.parse_args(argv)
    try:
        renames = {}
        for rule in args.rename:
            src, sep, dst = rule.partition(':=')
            if not sep:
                raise ValueError(f'bad --rename {rule!r}: expected FROM:=TO')
            renames[src] = dst
        statics = []
        for text in args.static:
            parts = text.split()
            if len(parts) != 8:
                raise ValueError(f'bad --static {text!r}: expected "X Y Z YAW PITCH ROLL '
                                 'PARENT CHILD"')
            statics.append(static_transform(*map(float, parts[:6]), parts[6], parts[7]))
        topics = None if args.topics is None else [t for t in args.topics.split(',') if t]
        counts = convert_bag(args.src, args.dst, renames, topics, statics, args.storage,
                             not args.no_compress, args.start, args.duration)
    except (BagError, ValueError, OSError) as exc:
        print(f'convert_bag: error: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    for topic, n in sorted(counts.items()):
        print(f'{topic}: {n}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
