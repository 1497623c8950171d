# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Offline replay: run the nodes' pipelines over recorded bags as fast as possible, no rclpy.

Each selected pipeline gets the messages of its input topics (``'/' + topic``
after ``--remap``) in bag time order, through exactly the conversion code the
live node uses. Static transforms (``/tf_static``) are delivered to every
pipeline before any other message. The outputs land in ``DIR``:

- ``output.mcap`` and ``metadata.yaml``: ``DIR`` is a ROS 2 bag (``ros2 bag info DIR``,
  ``ros2 bag play DIR``, Foxglove, :func:`robot_calib.io.bags.read_messages`) of every published
  output topic, same names and types as live, each message stamped with the
  stamp of the input that produced it;
- ``summary.json``: per node its pipeline summary (parameters, inputs read /
  accepted / rejected per reason, outputs, method results) and timing; at the
  top level the bags, their duration, the topics read with counts, the
  undecodable messages per topic, the mcap chunks skipped as corrupt
  (``corrupt_chunks``: file, offset, time span, messages lost per topic,
  reason) and the nodes skipped (with the reason);
- ``report.md`` with PNG plots under ``plots/``, and each pipeline's
  artifacts (e.g. ``wheel_calibration.yaml``).
- ``stack/``: the results in the form the robot's own stack takes
  (ros2_control controller parameters, static transforms, URDF joints, a gyro
  bias; :mod:`~robot_calib.replay.stack_export`), listed in ``summary.json``
  under ``stack`` (with the files withheld and why).

Everything is written into a temporary folder next to ``DIR`` and moved into
place only when the run succeeded; bad input raises :class:`ReplayError`,
:class:`robot_calib.io.bags.BagError` or
:class:`robot_calib.core.params.ParamError`, each with a one-line message.

The work is split by job: :mod:`~robot_calib.replay.config` (what is asked:
nodes, remaps, parameters, output folder), :mod:`~robot_calib.replay.select`
(which nodes run on which topics), :mod:`~robot_calib.replay.run` (the message
loop) and :mod:`~robot_calib.replay.summary` (artifacts, summary, report).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
import shutil
import time
from typing import Any, Iterable, Mapping, Optional, Sequence, Union

from robot_calib.io.bags import BagSet
from robot_calib.replay.config import (check_out_dir, check_out_not_input, load_params_file,
                                       move_into_place,
                                       NodeSpec, OUTPUT_BAG, parse_overrides, parse_remaps,
                                       prepare_out_dir, ReplayError, REPORT, resolve_node,
                                       SUMMARY)
from robot_calib.replay.run import run
from robot_calib.replay.select import plan
from robot_calib.replay.stack_export import write_stack
from robot_calib.replay.summary import build_summary, write_artifacts, write_report

__all__ = ['OUTPUT_BAG', 'REPORT', 'ReplayError', 'SUMMARY', 'load_params_file',
           'parse_overrides', 'parse_remaps', 'replay', 'resolve_node']


def _check_window(start_offset: float, duration: Optional[float]) -> None:
    if not (math.isfinite(start_offset) and start_offset >= 0) or (
            duration is not None and not (math.isfinite(duration) and duration > 0)):
        raise ReplayError(f'bad time window: start offset {start_offset} s, duration '
                          f'{duration} s; expected a start >= 0 and a duration > 0')


def _node_list(nodes: Union[None, str, Sequence[NodeSpec]]) -> Optional[Sequence[NodeSpec]]:
    if isinstance(nodes, str):
        nodes = [n.strip() for n in nodes.split(',') if n.strip()]
        if not nodes:
            raise ReplayError('--nodes is empty; expected a comma-separated list of nodes')
    return nodes


def replay(bags: Union[str, os.PathLike, Sequence[Union[str, os.PathLike]]],
           out_dir: Union[str, os.PathLike],
           nodes: Union[None, str, Sequence[NodeSpec]] = None,
           remaps: Union[None, Mapping[str, str], Iterable[str]] = None,
           params_file: Union[None, str, os.PathLike] = None,
           overrides: Union[None, Mapping[str, Any], Iterable[str]] = None,
           progress: Optional[bool] = None,
           storage: str = 'mcap', start_offset: float = 0.0,
           duration: Optional[float] = None, compress: bool = True,
           plots: bool = True) -> dict:
    """
    Replay ``bags`` through pipelines and write ``out_dir``; return the summary dict.

    :param bags: one or more bags (ROS 2 folders, or ROS 1 ``.bag`` files).
    :param out_dir: output folder (created; replaced when it holds a previous replay).
    :param nodes: node names from the registry, ``package.module:Class`` strings or
        Pipeline classes (a comma-separated string works too); None runs every
        registered pipeline whose required inputs are in the bags.
    :param remaps: ``FROM:=TO`` rules: FROM is a node topic (then the node reads TO)
        or a bag topic (then it is seen as TO).
    :param params_file: a ROS 2 parameter YAML (``config/robot_calib.yaml`` format).
    :param overrides: ``NODE.PARAM=VALUE`` items, applied last.
    :param progress: show a progress bar on stderr (default: when stderr is a terminal).
    :param storage: storage of ``output.mcap``: 'mcap' (one file) or 'sqlite3' (a bag
        folder of that name, for tests).
    :param start_offset: skip the first ``start_offset`` seconds of the recording (s);
        static transforms are delivered all the same.
    :param duration: replay at most this many seconds after the start offset (s).
    :param compress: zstd-compress the chunks of ``output.mcap``, as rosbag2 does by default.
    :param plots: draw the report's plots (about 0.5 s a replay; a fleet skips them).
    :return: the summary written to ``summary.json``.
    """
    wall0 = time.perf_counter()
    bag_list = [bags] if isinstance(bags, (str, os.PathLike)) else list(bags)
    if not bag_list:
        raise ReplayError('no bag given; expected one or more bag paths')
    out_dir = Path(out_dir)
    _check_window(start_offset, duration)
    check_out_dir(out_dir)
    check_out_not_input(out_dir, bag_list)
    rules = parse_remaps(remaps)
    by_node = parse_overrides(overrides)
    file_params = load_params_file(params_file)
    nodes = _node_list(nodes)
    window = (start_offset, duration)
    with BagSet(bag_list) as bagset:
        chosen = plan(bagset, nodes, rules, file_params, by_node,
                      ', '.join(map(str, bag_list)))
        tmp = prepare_out_dir(out_dir)
        try:
            stats = run(bagset, chosen, tmp, progress, storage, window, compress, plots)
            wall_seconds = time.perf_counter() - wall0
            artifacts = write_artifacts(chosen, tmp)
            stack_files, stack = write_stack(chosen, tmp, bag_list)
            summary = build_summary(bag_list, bagset, chosen, stats,
                                    {**artifacts, **stack_files}, storage, wall_seconds, window)
            summary['stack'] = stack
            write_report(tmp, chosen, stats, summary, plots)
            move_into_place(tmp, out_dir)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return summary
