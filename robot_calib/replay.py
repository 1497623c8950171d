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

Everything is written into a temporary folder next to ``DIR`` and moved into
place only when the run succeeded; bad input raises :class:`ReplayError`,
:class:`robot_calib.io.bags.BagError` or
:class:`robot_calib.core.params.ParamError`, each with a one-line message.
"""

from __future__ import annotations

from collections import defaultdict
import dataclasses
import gc
import importlib
import json
import math
import os
from pathlib import Path
import shutil
import sys
import tempfile
import time
from typing import Any, Iterable, Mapping, Optional, Sequence, Union

import numpy as np

from robot_calib import codec, pipelines
from robot_calib.core import types as T
from robot_calib.core.jsonable import jsonable
from robot_calib.core.params import describe, flatten_nested, from_flat, ParamError
from robot_calib.core.series import Reservoir, Thinned
from robot_calib.io.bags import BagError, BagSet, BagWriter, normalize_topic
from robot_calib.pipelines.base import Pipeline

OUTPUT_BAG = 'output.mcap'
SUMMARY = 'summary.json'
REPORT = 'report.md'
GROUND_TRUTH = '/ground_truth/odom'
TF_STATIC = '/tf_static'
_ODOM_TYPE = codec.KINDS['odom'].msgtype


class ReplayError(ValueError):
    """Bad replay input (nodes, topics, remaps, parameters, output folder): one-line message."""


NodeSpec = Union[str, type]


# ---------------------------------------------------------------------------------------
# argument parsing helpers (shared with the CLI)
# ---------------------------------------------------------------------------------------
def parse_remaps(remaps: Union[None, Mapping[str, str], Iterable[str]]) -> list[tuple[str, str]]:
    """Parse ``FROM:=TO`` rules (or a mapping) into normalized ``(from, to)`` topic pairs."""
    if not remaps:
        return []
    items = remaps.items() if isinstance(remaps, Mapping) else None
    out = []
    if items is None:
        pairs = []
        for rule in remaps:
            if not isinstance(rule, str) or ':=' not in rule:
                raise ReplayError(f'bad --remap {rule!r}: expected FROM:=TO, e.g. imu:=/imu/data')
            pairs.append(tuple(rule.split(':=', 1)))
        items = pairs
    for src, dst in items:
        src, dst = str(src).strip(), str(dst).strip()
        if not src.strip('/') or not dst.strip('/') or ' ' in src or ' ' in dst \
                or ':=' in dst:
            raise ReplayError(f'bad --remap {src}:={dst}: expected FROM:=TO with two topic '
                              'names, e.g. imu:=/imu/data')
        out.append((normalize_topic(src), normalize_topic(dst)))
    return out


def parse_overrides(overrides: Union[None, Mapping[str, Any], Iterable[str]]
                    ) -> dict[str, dict[str, Any]]:
    """Parse ``NODE.PARAM=VALUE`` items (or a ``{'NODE.PARAM': value}`` mapping) by node."""
    out: dict[str, dict[str, Any]] = defaultdict(dict)
    if not overrides:
        return {}
    if isinstance(overrides, Mapping):
        items = list(overrides.items())
    else:
        items = []
        for item in overrides:
            if not isinstance(item, str) or '=' not in item:
                raise ReplayError(f'bad --set {item!r}: expected NODE.PARAM=VALUE, '
                                  'e.g. tilt_detection.fall_angle=0.6')
            key, value = item.split('=', 1)
            items.append((key, value))
    for key, value in items:
        key = str(key).strip()
        node, _, name = key.partition('.')
        if not node or not name or any(not part for part in name.split('.')):
            raise ReplayError(f'bad --set {key}={value}: expected NODE.PARAM=VALUE, '
                              'e.g. tilt_detection.fall_angle=0.6')
        out[node][name] = value.strip() if isinstance(value, str) else value
    return dict(out)


def load_params_file(path: Union[str, os.PathLike, None]) -> dict[str, dict[str, Any]]:
    """
    Read a ROS 2 parameter YAML (node -> ros__parameters -> nested or dotted keys).

    Returns ``{node name: {dotted name: value}}``; ``/**`` (all nodes) is kept as
    the key ``'/**'``. Raises ReplayError when the file is missing or malformed.
    """
    if path is None:
        return {}
    import yaml
    p = Path(path)
    if not p.is_file():
        raise ReplayError(f'parameter file not found: {p} (expected a YAML file like '
                          'config/robot_calib.yaml)')
    try:
        data = yaml.safe_load(p.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        first = ' '.join(str(exc).split())
        raise ReplayError(f'cannot read parameter file {p}: {first}') from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ReplayError(f'parameter file {p}: expected a mapping of node names to '
                          '{ros__parameters: {...}}')
    out = {}
    for node, section in data.items():
        name = str(node)
        if name != '/**':
            name = name.lstrip('/')
        if not isinstance(section, dict) or not isinstance(
                section.get('ros__parameters', {}), dict):
            raise ReplayError(f'parameter file {p}: node {node!r} must map to '
                              '{ros__parameters: {...}}')
        out[name] = flatten_nested(section.get('ros__parameters') or {})
    return out


def _node_name(cls: type) -> str:
    return getattr(cls, 'name', '') or cls.__name__


def resolve_node(spec: NodeSpec) -> tuple[str, type]:
    """Return ``(name, pipeline class)`` of a registry name, ``module:Class`` or a class."""
    if isinstance(spec, type):
        cls = spec
    elif ':' in spec:
        module, _, attr = spec.partition(':')
        try:
            mod = importlib.import_module(module)
        except ImportError as exc:
            raise ReplayError(f'--nodes {spec}: cannot import module {module!r} ({exc})') \
                from None
        cls = getattr(mod, attr, None)
        if cls is None:
            raise ReplayError(f'--nodes {spec}: module {module!r} has no class {attr!r}')
    else:
        if spec not in pipelines.REGISTRY:
            raise ReplayError(f'unknown node {spec!r}; expected one of '
                              f'{", ".join(pipelines.REGISTRY)} or package.module:Class')
        if spec not in pipelines.available():
            raise ReplayError(f'node {spec!r} is not available in this installation '
                              f'(available: {", ".join(pipelines.available()) or "none"})')
        try:
            cls = pipelines.load(spec)
        except Exception as exc:  # noqa: B902 - a broken module is reported, not raised
            raise ReplayError(f'node {spec!r} cannot be loaded: {type(exc).__name__}: '
                              f'{" ".join(str(exc).split())}') from None
    if not (isinstance(cls, type) and issubclass(cls, Pipeline)):
        raise ReplayError(f'--nodes {spec}: {cls!r} is not a robot_calib Pipeline class')
    return _node_name(cls), cls


# ---------------------------------------------------------------------------------------
# run state
# ---------------------------------------------------------------------------------------
class _Node:
    """A pipeline being replayed: its routes, outputs, timing and errors."""

    def __init__(self, name: str, cls: type, params: Any):
        self.name = name
        self.cls = cls
        self.logs: list[str] = []
        self.log_counts: dict[str, int] = defaultdict(int)
        self.pipeline: Pipeline = cls(params, log=self._log)
        self.inputs: dict[str, str] = {}  # key -> topic
        self.outputs: dict[str, tuple[str, str, bool]] = {}  # key -> (topic, msgtype, latched)
        self.notes: list[str] = []
        self.times = Reservoir()
        """Seconds per input message: count, sum and a sample for percentiles."""
        self.errors: dict[str, int] = defaultdict(int)
        self.first_errors: list[str] = []
        self.tf_key = 'tf_static'
        self.errors_key = 'errors'

    def _log(self, level: str, message: str) -> None:
        self.log_counts[level] += 1
        if len(self.logs) < 50:
            self.logs.append(f'[{level}] {message}')

    def error(self, where: str, exc: BaseException) -> None:
        self.errors[where] += 1
        if len(self.first_errors) < 5:
            self.first_errors.append(f'{where}: {type(exc).__name__}: '
                                     f'{" ".join(str(exc).split())}')


def _check_inputs(cls: type, topic_of: Any, bag_topics: dict[str, tuple[str, int]]
                  ) -> tuple[Optional[str], dict[str, str], list[str]]:
    """Return (reason it cannot run or None, {key: topic} of inputs present, notes)."""
    present: dict[str, str] = {}
    notes = []
    for spec in cls.inputs:
        if spec.kind == 'tf_static':
            continue
        topic = topic_of(spec.topic)
        expected = codec.KINDS[spec.kind].msgtype
        have = bag_topics.get(topic)
        if have is None:
            if not spec.optional:
                return (f'needs {topic} ({expected}), not in the bag(s)', present, notes)
            notes.append(f'optional input {topic} ({expected}) not in the bag(s)')
            continue
        if not codec.accepts(spec.kind, have[0]):
            msg = f'{topic} is {have[0]} in the bag(s), expected {expected}'
            if not spec.optional:
                return (msg, present, notes)
            notes.append('optional input ignored: ' + msg)
            continue
        present[spec.key] = topic
    return None, present, notes


def _params_for(name: str, cls: type, file_params: dict[str, dict[str, Any]],
                overrides: dict[str, Any]) -> Any:
    params_type = cls.params_type
    if not dataclasses.is_dataclass(params_type):
        if file_params.get(name) or overrides:
            raise ReplayError(f'node {name} has no parameters to set')
        return None
    known = {i.name for i in describe(params_type)}
    flat = {k: v for k, v in file_params.get('/**', {}).items() if k in known}
    flat.update(file_params.get(name, {}))
    flat.update(overrides)
    try:
        return from_flat(params_type, flat)
    except ParamError as exc:
        raise ParamError(f'node {name}: {exc}') from None


def _check_out_dir(out_dir: Path) -> None:
    """Raise ReplayError when ``out_dir`` cannot be (re)placed by a replay output."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ReplayError(f'output {out_dir} exists and is not a folder; expected a folder path')
    if out_dir.is_dir() and any(out_dir.iterdir()) and not (out_dir / SUMMARY).is_file():
        raise ReplayError(f'output folder {out_dir} exists, is not empty and is not a '
                          'previous replay output; give a new or empty folder')
    ancestor = out_dir.absolute().parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir() or not os.access(ancestor, os.W_OK | os.X_OK):
        raise ReplayError(f'output folder {out_dir.parent} is not writable ({ancestor} is not '
                          'a writable folder); expected a writable folder')


def _prepare_out_dir(out_dir: Path) -> Path:
    """Check the output folder and return a fresh temporary folder next to it."""
    _check_out_dir(out_dir)
    parent = out_dir.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f'.{out_dir.name}.partial-', dir=parent))
        umask = os.umask(0o022)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # a normal folder once in place (mkdtemp makes 0700)
        return tmp
    except OSError as exc:
        raise ReplayError(f'output folder {parent} is not writable '
                          f'({exc.strerror or exc}); expected a writable folder') from None


def _move_into_place(tmp: Path, out_dir: Path) -> None:
    old = None
    if out_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=f'.{out_dir.name}.old-', dir=out_dir.parent))
        os.replace(out_dir, old / 'previous')
    os.replace(tmp, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


# ---------------------------------------------------------------------------------------
# replay
# ---------------------------------------------------------------------------------------
def replay(bags: Union[str, os.PathLike, Sequence[Union[str, os.PathLike]]],
           out_dir: Union[str, os.PathLike],
           nodes: Union[None, str, Sequence[NodeSpec]] = None,
           remaps: Union[None, Mapping[str, str], Iterable[str]] = None,
           params_file: Union[None, str, os.PathLike] = None,
           overrides: Union[None, Mapping[str, Any], Iterable[str]] = None,
           progress: Optional[bool] = None,
           storage: str = 'mcap', start_offset: float = 0.0,
           duration: Optional[float] = None) -> dict:
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
    :return: the summary written to ``summary.json``.
    """
    wall0 = time.perf_counter()
    bag_list = [bags] if isinstance(bags, (str, os.PathLike)) else list(bags)
    if not bag_list:
        raise ReplayError('no bag given; expected one or more bag paths')
    out_dir = Path(out_dir)
    if not (math.isfinite(start_offset) and start_offset >= 0) or (
            duration is not None and not (math.isfinite(duration) and duration > 0)):
        raise ReplayError(f'bad time window: start offset {start_offset} s, duration '
                          f'{duration} s; expected a start >= 0 and a duration > 0')
    _check_out_dir(out_dir)
    rules = parse_remaps(remaps)
    by_node = parse_overrides(overrides)
    file_params = load_params_file(params_file)
    if isinstance(nodes, str):
        nodes = [n.strip() for n in nodes.split(',') if n.strip()]
        if not nodes:
            raise ReplayError('--nodes is empty; expected a comma-separated list of nodes')

    with BagSet(bag_list) as bagset:
        # -- bag topics, with bag-side remaps -------------------------------------------
        if nodes is None:
            candidates = []
            skipped: dict[str, str] = {}
            for name in pipelines.REGISTRY:
                if name not in pipelines.available():
                    skipped[name] = 'not installed (module missing)'
                    continue
                try:
                    candidates.append(resolve_node(name))
                except ReplayError as exc:
                    skipped[name] = str(exc)
        else:
            candidates = [resolve_node(n) for n in nodes]
            skipped = {}
            names = [n for n, _ in candidates]
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise ReplayError(f'node(s) {dup} given twice in --nodes')
        node_topics = set()
        for _, cls in candidates:
            node_topics.update(normalize_topic(s.topic) for s in cls.inputs)
            node_topics.update(normalize_topic(s.topic) for s in cls.outputs)
        raw_topics = bagset.topics()
        node_map: dict[str, str] = {}
        bag_map: dict[str, str] = {}
        for src, dst in rules:
            if src in node_topics:
                node_map[src] = dst
            elif src in raw_topics:
                bag_map[src] = dst
            else:
                raise ReplayError(
                    f'--remap {src}:={dst}: {src} is neither a topic of the nodes '
                    f'({", ".join(sorted(node_topics)) or "none"}) nor a topic in the bag(s) '
                    f'({", ".join(sorted(raw_topics)) or "none"})')
        topic_of_stream = {id(s): bag_map.get(s.topic, s.topic) for s in bagset.streams}
        bag_topics: dict[str, tuple[str, int]] = {}
        for s in bagset.streams:
            t = topic_of_stream[id(s)]
            prev = bag_topics.get(t)
            if prev is not None and prev[0] != s.msgtype:
                raise BagError(f'topic {t} has two types in the bag(s): {prev[0]} and '
                               f'{s.msgtype}; expected one type per topic')
            bag_topics[t] = (s.msgtype, (prev[1] if prev else 0) + s.count)

        def topic_of(topic: str) -> str:
            t = normalize_topic(topic)
            return node_map.get(t, t)

        # -- node selection ---------------------------------------------------------------
        selected = []
        for name, cls in candidates:
            reason, present, notes = _check_inputs(cls, topic_of, bag_topics)
            if reason is not None:
                if nodes is not None:
                    raise ReplayError(f'node {name} {reason}; bag topics: '
                                      f'{", ".join(sorted(bag_topics)) or "none"} '
                                      '(use --remap NODE_TOPIC:=BAG_TOPIC)')
                skipped[name] = reason
                continue
            selected.append((name, cls, present, notes))
        if not selected:
            why = '; '.join(f'{n}: {r}' for n, r in skipped.items()) or 'no node is installed'
            raise ReplayError(f'no node can run on {", ".join(map(str, bag_list))} ({why})')
        names = {n for n, *_ in selected}
        for node in by_node:
            if node not in names:
                raise ReplayError(f'--set {node}.*: {node} is not among the replayed nodes '
                                  f'({", ".join(sorted(names))})')

        runs: list[_Node] = []
        for name, cls, present, notes in selected:
            params = _params_for(name, cls, file_params, by_node.get(name, {}))
            run = _Node(name, cls, params)
            run.inputs = present
            run.notes = notes
            for spec in cls.inputs:
                if spec.kind == 'tf_static':
                    run.tf_key = spec.key
            for spec in cls.outputs:
                run.outputs[spec.key] = (topic_of(spec.topic), codec.KINDS[spec.kind].msgtype,
                                         spec.qos == 'latched')
            runs.append(run)

        tmp = _prepare_out_dir(out_dir)
        try:
            summary = _run(bagset, bag_list, runs, skipped, topic_of_stream, bag_topics,
                           tmp, progress, storage, wall0, {**node_map, **bag_map},
                           (start_offset, duration))
            _move_into_place(tmp, out_dir)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return summary


def _run(bagset: BagSet, bag_list: list, runs: list[_Node], skipped: dict[str, str],
         topic_of_stream: dict[int, str], bag_topics: dict[str, tuple[str, int]], tmp: Path,
         progress: Optional[bool], storage: str, wall0: float, remaps: dict[str, str],
         window: tuple[float, Optional[float]] = (0.0, None)) -> dict:
    """Run the selected nodes over the bags into ``tmp``; return the summary."""
    # topic -> [(process, key, run)]
    routes: dict[str, list] = defaultdict(list)
    for run in runs:
        for key, topic in run.inputs.items():
            routes[topic].append((run.pipeline.process, key, run, run.times.append))
    traj_topics = {t for t in routes if bag_topics[t][0] == _ODOM_TYPE}
    if GROUND_TRUTH in bag_topics and bag_topics[GROUND_TRUTH][0] == _ODOM_TYPE:
        traj_topics.add(GROUND_TRUTH)
    streams = [s for s in bagset.streams
               if topic_of_stream[id(s)] in routes or topic_of_stream[id(s)] in traj_topics]
    static = [s for s in bagset.streams if topic_of_stream[id(s)] == TF_STATIC
              and s.msgtype == 'tf2_msgs/msg/TFMessage']
    read: dict[str, int] = defaultdict(int)
    undecodable: dict[str, int] = defaultdict(int)
    trajectories: dict[str, Thinned] = defaultdict(Thinned)
    n_static = 0

    # -- static transforms first -------------------------------------------------------------
    for stream, time_ns, raw in bagset.messages(static) if static else ():
        try:
            samples = stream.decode(raw, time_ns)
        except Exception:  # noqa: B902 - counted, never fatal
            undecodable[TF_STATIC] += 1
            continue
        read[TF_STATIC] += 1
        for tf in samples:
            n_static += 1
            for run in runs:
                try:
                    run.pipeline.process(run.tf_key, tf)
                except Exception as exc:  # noqa: B902 - counted, never fatal
                    run.error('tf_static', exc)

    total = sum(s.count for s in streams)
    show = sys.stderr.isatty() if progress is None else bool(progress)
    bar = None
    if show and total:
        from tqdm import tqdm
        bar = tqdm(total=total, unit='msg', unit_scale=True, file=sys.stderr,
                   desc='replay', dynamic_ncols=True)
    perf = time.perf_counter
    # id(stream) -> (topic, routes, trajectory topic or None)
    stream_info = {id(s): (topic_of_stream[id(s)], routes.get(topic_of_stream[id(s)], ()),
                           topic_of_stream[id(s)] if topic_of_stream[id(s)] in traj_topics
                           else None) for s in streams}
    out_traj: dict[str, Thinned] = defaultdict(Thinned)
    out_counts: dict[str, int] = defaultdict(int)
    n_msgs = 0
    bag_dir = tmp / Path(OUTPUT_BAG).stem  # a ROS 2 bag folder, flattened below
    with BagWriter(bag_dir, storage=storage,
                   latched=[t for r in runs for (t, _, latched) in r.outputs.values()
                            if latched]) as writer:

        def emit(run: _Node, outs: list) -> None:
            for out_key, sample in outs:
                spec = run.outputs.get(out_key)
                try:
                    if spec is None:
                        raise KeyError(f'output {out_key!r} is not declared in outputs')
                    msgtype, data = codec.serialize(sample)
                    if msgtype != spec[1]:
                        raise TypeError(f'output {out_key!r} is {msgtype}, declared {spec[1]}')
                    writer.write_raw(spec[0], msgtype, data, codec.sample_time_ns(
                        sample if not isinstance(sample, list) else sample[0]))
                except Exception as exc:  # noqa: B902 - counted, never fatal
                    run.error('output', exc)
                    continue
                out_counts[spec[0]] += 1
                if isinstance(sample, T.OdomSample):
                    out_traj[spec[0]].append((sample.t, sample.x, sample.y, sample.yaw))

        # Fewer, cheaper garbage collections while samples are created at a high rate
        # (restored below): existing objects are frozen out of the collector's scans.
        gc_threshold = gc.get_threshold()
        gc.freeze()
        gc.set_threshold(max(gc_threshold[0], 20000), *gc_threshold[1:])
        try:
            it = bagset.decoded(streams) if streams else ()
            t_lo = bagset.start_ns + int(round(window[0] * 1e9))
            t_hi = None if window[1] is None else t_lo + int(round(window[1] * 1e9))
            clip = window[0] > 0 or t_hi is not None
            for stream, time_ns, _, samples in it:
                if clip:
                    if time_ns < t_lo:
                        continue
                    if t_hi is not None and time_ns > t_hi:
                        break
                topic, targets, traj = stream_info[id(stream)]
                if samples is None:  # undecodable: counted, never fatal
                    undecodable[topic] += 1
                    continue
                n_msgs += 1
                read[topic] += 1
                for sample in samples:
                    for process, key, run, add_time in targets:
                        t0 = perf()
                        try:
                            outs = process(key, sample)
                        except Exception as exc:  # noqa: B902 - counted, never fatal
                            run.error('process', exc)
                            run.pipeline.reject(key, 'processing_error')
                            outs = None
                        add_time(perf() - t0)
                        if outs:
                            emit(run, outs)
                    if traj is not None:
                        trajectories[traj].append((sample.t, sample.x, sample.y, sample.yaw))
                if bar is not None and not n_msgs % 2000:
                    bar.update(2000)
            if bar is not None:
                bar.update(n_msgs % 2000)
                bar.close()
        finally:
            gc.set_threshold(*gc_threshold)
            gc.unfreeze()
        finish_times = {}
        for run in runs:
            t0 = perf()
            try:
                emit(run, run.pipeline.finish())
            except Exception as exc:  # noqa: B902 - counted, never fatal
                run.error('finish', exc)
            finish_times[run.name] = perf() - t0
    if storage == 'mcap':  # the output folder is itself a ROS 2 bag: metadata.yaml + the mcap
        os.replace(bag_dir / f'{bag_dir.name}.mcap', tmp / OUTPUT_BAG)
        meta = (bag_dir / 'metadata.yaml').read_text()
        (tmp / 'metadata.yaml').write_text(meta.replace(f'{bag_dir.name}.mcap', OUTPUT_BAG))
        shutil.rmtree(bag_dir)
    else:
        os.replace(bag_dir, tmp / OUTPUT_BAG)
    replay_seconds = perf() - wall0

    # -- artifacts ---------------------------------------------------------------------------
    artifacts = {}
    for run in runs:
        try:
            files = run.pipeline.artifacts() or {}
        except Exception as exc:  # noqa: B902 - counted, never fatal
            run.error('artifacts', exc)
            continue
        for fname, text in files.items():
            if Path(fname).name != fname or fname in (SUMMARY, REPORT, OUTPUT_BAG, 'plots'):
                run.error('artifacts', ValueError(f'bad artifact name {fname!r}'))
                continue
            if fname in artifacts:
                fname = f'{run.name}_{fname}'
            (tmp / fname).write_text(text)
            artifacts[fname] = run.name

    # -- summary -----------------------------------------------------------------------------
    start, end = bagset.start_ns, bagset.end_ns
    nodes_summary = {}
    for run in runs:
        try:
            base = run.pipeline.summary()
        except Exception as exc:  # noqa: B902 - counted, never fatal
            run.error('summary', exc)
            base = {'inputs': {k: dict(v) for k, v in run.pipeline.counts.items()},
                    'outputs': dict(run.pipeline.n_outputs)}
        proc = run.times.total
        n_in = run.times.count
        if 'timing' in base:  # the method's own timing figures, kept under another key
            base['method_timing'] = base.pop('timing')
        extras = {
            'timing': {
                'wall_seconds': proc + finish_times.get(run.name, 0.0),
                'process_seconds': proc,
                'finish_seconds': finish_times.get(run.name, 0.0),
                'input_messages': n_in,
                'input_messages_per_second': n_in / proc if proc > 0 else None,
                'per_message_ms_p50': None if not n_in else run.times.percentile(50) * 1e3,
                'per_message_ms_p99': None if not n_in else run.times.percentile(99) * 1e3,
            },
            'input_topics': dict(run.inputs),
            'output_topics': {k: v[0] for k, v in run.outputs.items()},
            'errors': dict(run.errors),
        }
        if run.first_errors:
            extras['first_errors'] = run.first_errors
        if run.notes:
            extras['notes'] = run.notes
        if run.logs:
            extras['log'] = run.logs
        for key, value in extras.items():  # never hide a key the method reports
            base[key if key not in base or key == 'timing' else f'replay_{key}'] = value
        run.errors_key = 'errors' if base.get('errors') is extras['errors'] else 'replay_errors'
        nodes_summary[run.name] = base
    summary = {
        'bags': [str(b) for b in bag_list],
        'start_time': start * 1e-9,
        'end_time': end * 1e-9,
        'duration': max(end - start, 0) * 1e-9,
        'window': [window[0], window[1]],
        'topics': {t: {'type': ty, 'count': n, 'read': read.get(t, 0)}
                   for t, (ty, n) in sorted(bag_topics.items())},
        'topics_read': dict(sorted(read.items())),
        'undecodable': dict(sorted(undecodable.items())),
        'corrupt_chunks': bagset.corrupt_chunks,
        'static_transforms': n_static,
        'remaps': remaps,
        'nodes': nodes_summary,
        'skipped': skipped,
        'output': {'bag': OUTPUT_BAG, 'storage': storage, 'topics': dict(sorted(
            out_counts.items()))},
        'artifacts': sorted(artifacts),
        'timing': {'wall_seconds': replay_seconds, 'messages': n_msgs,
                   'messages_per_second': n_msgs / replay_seconds if replay_seconds else None},
    }
    summary = jsonable(summary)

    # -- plots and report --------------------------------------------------------------------
    from robot_calib import report
    node_plots = {}
    for run in runs:
        pdir = tmp / 'plots' / run.name
        pdir.mkdir(parents=True, exist_ok=True)
        try:
            files = run.pipeline.plot(str(pdir)) or []
            node_plots[run.name] = [f'plots/{run.name}/{Path(f).name}' for f in files]
        except Exception as exc:  # noqa: B902 - a plot must not fail the run
            summary['nodes'][run.name][run.errors_key]['plot'] = \
                f'{type(exc).__name__}: {" ".join(str(exc).split())}'
        if not any(pdir.iterdir()):
            pdir.rmdir()
    inputs = {t: np.asarray(list(v), dtype=float) for t, v in trajectories.items() if v}
    outputs = {t: np.asarray(list(v), dtype=float) for t, v in out_traj.items() if v}
    try:
        generic = report.generic_plots(tmp / 'plots', inputs, outputs, start * 1e-9)
    except Exception as exc:  # noqa: B902 - a plot must not fail the run
        summary['plot_error'] = f'{type(exc).__name__}: {" ".join(str(exc).split())}'
        generic = []
    summary['plots'] = generic + [f for v in node_plots.values() for f in v]
    (tmp / REPORT).write_text(report.render(summary, generic, node_plots))
    (tmp / SUMMARY).write_text(json.dumps(summary, indent=2, allow_nan=False) + '\n')
    return summary
