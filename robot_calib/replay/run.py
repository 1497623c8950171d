# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The replay loop: static transforms first, then every message in bag time order, then finish.

Each sample goes to the pipelines that read its topic (through exactly the
code the live node runs), their outputs are serialized with the codec and
written to the output bag stamped with the input that produced them. Errors
are counted per node and stage, never fatal.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from functools import cache, partial
import gc
import os
from pathlib import Path
import shutil
import sys
import time
from typing import Any, Optional

from robot_calib import codec
from robot_calib.core import types as T
from robot_calib.core.series import Thinned
from robot_calib.io.bags import BagSet, BagWriter, UNDECODED
from robot_calib.pipelines.validation import restamp_unset, sample_problem, UNCHECKED
from robot_calib.replay.config import OUTPUT_BAG
from robot_calib.replay.select import NodeRun, Plan

GROUND_TRUTH = '/ground_truth/odom'
_ODOM_TYPE = codec.KINDS['odom'].msgtype


@dataclass
class RunStats:
    """What the loop saw: messages read, undecodable, trajectories drawn, outputs written."""

    read: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    undecodable: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    restamped: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    """Messages whose header stamp was unset (0): their receive time stood in."""
    trajectories: dict[str, Thinned] = field(default_factory=lambda: defaultdict(Thinned))
    """Input odometry topics (and the ground truth): (t, x, y, yaw) for the plots."""
    out_traj: dict[str, Thinned] = field(default_factory=lambda: defaultdict(Thinned))
    out_counts: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    n_msgs: int = 0
    n_static: int = 0
    finish_times: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0


def _routes(plan: Plan, times: list) -> dict[str, list]:
    """
    Return topic -> [(process_checked, input key, run, add_time)] of the nodes reading it.

    ``add_time`` collects a node's seconds per input into a list appended to
    ``times`` as (run, list): :func:`_flush_times` moves them into ``run.times``.
    """
    routes: dict[str, list] = defaultdict(list)
    for run in plan.runs:
        pending: list[float] = []
        times.append((run, pending))
        for key, topic in run.inputs.items():
            routes[topic].append((run.pipeline.process_checked, key, run, pending.append))
    return routes


def _flush_times(times: list) -> None:
    """Move the seconds per input collected by the loop into each run's reservoir."""
    for run, pending in times:
        run.times.extend(pending)
        pending.clear()


def _deliver_static(bagset: BagSet, plan: Plan, stats: RunStats) -> None:
    """Hand every static transform to every node before anything else (its own topic)."""
    wanted = {run.tf_topic for run in plan.runs}   # /tf_static unless a node's is remapped
    static = [s for s in bagset.streams if plan.topic_of_stream[id(s)] in wanted
              and s.msgtype == codec.KINDS['tf_static'].msgtype]
    for stream, time_ns, raw in bagset.messages(static) if static else ():
        topic = plan.topic_of_stream[id(stream)]
        try:
            samples = stream.decode(raw, time_ns)
        except Exception:  # noqa: B902 - counted, never fatal
            stats.undecodable[topic] += 1
            continue
        stats.read[topic] += 1
        for tf in samples:
            stats.n_static += 1
            for run in plan.runs:
                if run.tf_topic != topic:
                    continue
                try:
                    run.pipeline.process(run.tf_key, tf)
                except Exception as exc:  # noqa: B902 - counted, never fatal
                    run.error('tf_static', exc)


class _Emitter:
    """Serialize a node's outputs into the output bag; count them, keep odometry tracks."""

    def __init__(self, writer: BagWriter, stats: RunStats):
        self.writer = writer
        self.stats = stats
        self._routes: dict[int, dict[str, Optional[tuple]]] = {}
        """id(run) -> output key -> (topic, declared type, write, encoders), None: undeclared."""

    def _route(self, run: NodeRun, out_key: str) -> Optional[tuple]:
        spec = run.outputs.get(out_key)
        route = None if spec is None else (spec[0], spec[1],
                                           self.writer.raw_writer(spec[0], spec[1]), {})
        self._routes[id(run)][out_key] = route
        return route

    @staticmethod
    def _encoder(encoders: dict, sample_type: type, declared: str) -> Any:
        """
        Return (and keep) the fast encoder :func:`codec.serialize` takes for ``sample_type``.

        None when it takes none or writes another type than ``declared`` (the
        sample then goes through :func:`codec.serialize`, which says why).
        """
        row = codec.BY_SAMPLE.get(sample_type)
        encode = (row.fast.encode_cdr if row is not None and row.msgtype == declared
                  else None)
        encoders[sample_type] = encode
        return encode

    def __call__(self, run: NodeRun, outs: list) -> None:
        """Write outputs ``(key, sample)`` of ``run``; a bad one is counted, never fatal."""
        routes = self._routes.get(id(run))
        if routes is None:
            routes = self._routes[id(run)] = {}
        out_counts = self.stats.out_counts
        for out_key, sample in outs:
            route = routes.get(out_key, False)
            if route is False:
                route = self._route(run, out_key)
            try:
                if route is None:
                    raise KeyError(f'output {out_key!r} is not declared in outputs')
                topic, declared, write, encoders = route
                encode = encoders.get(type(sample), False)
                if encode is False:
                    encode = self._encoder(encoders, type(sample), declared)
                # codec.serialize and codec.sample_time_ns for a stamp that fits a ROS time
                ns = sample.stamp_ns if encode is not None else None
                if type(ns) is int and ns < 2**62 and (ns >= 0 or 0 <= sample.t < 2**31):
                    write(encode(sample), ns if ns >= 0 else int(round(sample.t * 1e9)))
                else:
                    msgtype, data = codec.serialize(sample)
                    if msgtype != declared:
                        raise TypeError(f'output {out_key!r} is {msgtype}, declared {declared}')
                    write(data, codec.sample_time_ns(
                        sample if not isinstance(sample, list) else sample[0]))
            except Exception as exc:  # noqa: B902 - counted, never fatal
                run.error('output', exc)
                continue
            out_counts[topic] += 1
            if isinstance(sample, T.OdomSample):
                self.stats.out_traj[topic].append((sample.t, sample.x, sample.y, sample.yaw))


def _progress_bar(total: int, progress: Optional[bool]) -> Any:
    show = sys.stderr.isatty() if progress is None else bool(progress)
    if not (show and total):
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit='msg', unit_scale=True, file=sys.stderr, desc='replay',
                dynamic_ncols=True)


def _window_ns(bagset: BagSet, window: tuple[float, Optional[float]]
               ) -> tuple[int, Optional[int]]:
    """Return the first and last receive time (ns; None: no end) of ``window``."""
    t_lo = bagset.start_ns + int(round(window[0] * 1e9))
    return t_lo, None if window[1] is None else t_lo + int(round(window[1] * 1e9))


def _expected_messages(bagset: BagSet, streams: list,
                       window: tuple[float, Optional[float]]) -> int:
    """
    Return how many messages of ``streams`` lie inside ``window``: the progress bar's total.

    The bags count messages per topic only: for a window narrower than the
    recording this is their share of its time span, an estimate.
    """
    total = sum(s.count for s in streams)
    t_lo, t_hi = _window_ns(bagset, window)
    start, end = bagset.start_ns, bagset.end_ns
    if t_lo <= start and (t_hi is None or t_hi >= end):
        return total
    inside = (end if t_hi is None else min(t_hi, end)) - t_lo
    return round(total * inside / (end - start)) if inside > 0 else 0


def _loop(bagset: BagSet, streams: list, stream_info: dict, emit: _Emitter, stats: RunStats,
          window: tuple[float, Optional[float]], bar: Any, times: list) -> None:
    """Feed every message of ``streams`` inside ``window`` (s from the start, length)."""
    perf = time.perf_counter
    t_lo, t_hi = _window_ns(bagset, window)
    clip = window[0] > 0 or t_hi is not None
    # not decoded: a topic read for its trajectory alone (decoded where the plot keeps a
    # point), and a topic every node reading it turns away unread (Pipeline.refusal)
    lazy = {id(s) for s in streams if not stream_info[id(s)][1]}
    for stream, time_ns, raw, samples in (bagset.decoded(streams, lazy=lazy) if streams
                                          else ()):
        if clip:
            if time_ns < t_lo:
                continue
            if t_hi is not None and time_ns > t_hi:
                break
        topic, targets, traj, refusable = stream_info[id(stream)]
        if samples is None:  # undecodable: counted, never fatal
            stats.undecodable[topic] += 1
            continue
        if refusable:
            if _refused(targets):
                lazy.add(id(stream))
                targets = ()
            else:
                lazy.discard(id(stream))
        if samples is UNDECODED:
            if targets:
                samples = _decode(stream, raw, time_ns, stats.undecodable, topic)
                if samples is None:
                    continue
            else:
                samples = ()
                if traj is not None:
                    stats.trajectories[traj].append_lazy(
                        partial(_pose, stream, raw, time_ns, stats.undecodable, topic))
        if samples and getattr(samples[0], 'stamp_ns', -1) == 0:
            restamped = restamp_unset(samples, time_ns)
            if restamped is not None:  # a driver that leaves header.stamp unset
                samples = restamped
                stats.restamped[topic] += 1
        stats.n_msgs += 1
        stats.read[topic] += 1
        for sample in samples:
            if targets:
                try:  # once for every node reading the sample (each counts its own rejections)
                    problem = (None if isinstance(sample, T.StaticTransform)
                               else sample_problem(sample))
                except Exception:  # noqa: B902 - each node fails on it below, as alone
                    problem = UNCHECKED
            t0 = perf()
            for process, key, run, add_time in targets:
                try:
                    outs = process(key, sample, problem)
                except Exception as exc:  # noqa: B902 - counted, never fatal
                    run.error('process', exc)
                    run.pipeline.reject(key, 'processing_error')
                    outs = None
                t1 = perf()
                add_time(t1 - t0)
                if outs:
                    emit(run, outs)
                    t1 = perf()  # a node's time leaves out writing its outputs
                t0 = t1
            if traj is not None:
                stats.trajectories[traj].append((sample.t, sample.x, sample.y, sample.yaw))
        if not stats.n_msgs % 2048:
            _flush_times(times)
            if bar is not None:
                bar.update(2048)
    if bar is not None:
        bar.total = stats.n_msgs  # what was replayed (a window's total is an estimate)
        bar.update(stats.n_msgs % 2048)
        bar.close()


def _refusable(stream: Any, targets: list) -> bool:
    """Return whether every node reading ``stream`` may refuse it (one sample a message)."""
    return (bool(targets) and stream.msgtype != codec.KINDS['tf_static'].msgtype
            and all(key in run.pipeline.refusable for _, key, run, _ in targets))


def _refused(targets: tuple) -> bool:
    """Count a message refused by every node reading it (:meth:`Pipeline.refuse`); say if so."""
    reasons = [run.pipeline.refusal(key) for _, key, run, _ in targets]
    if not all(reasons):
        return False
    for (_, key, run, add_time), reason in zip(targets, reasons):
        t0 = time.perf_counter()
        run.pipeline.refuse(key, reason)
        add_time(time.perf_counter() - t0)
    return True


def _decode(stream: Any, raw: bytes, time_ns: int, undecodable: dict[str, int],
            topic: str) -> Optional[list]:
    """Return the samples of a message; None (counted) when it cannot be decoded."""
    try:
        return stream.decode(raw, time_ns)
    except Exception:  # noqa: B902 - counted, never fatal
        undecodable[topic] += 1
        return None


def _pose(stream: Any, raw: bytes, time_ns: int, undecodable: dict[str, int],
          topic: str) -> Optional[tuple[float, float, float, float]]:
    """Return (t, x, y, yaw) of an odometry message; None (counted) when undecodable."""
    if stream.decode_pose is not None and raw[1] == 1:  # little-endian CDR
        try:
            return stream.decode_pose(raw)
        except Exception:  # noqa: B902 - the full decoder says whether it is undecodable
            pass
    samples = _decode(stream, raw, time_ns, undecodable, topic)
    if samples is None:
        return None
    return samples[0].t, samples[0].x, samples[0].y, samples[0].yaw


def _finish(plan: Plan, emit: _Emitter, stats: RunStats) -> None:
    for run in plan.runs:
        t0 = time.perf_counter()
        try:
            emit(run, run.pipeline.close())
        except Exception as exc:  # noqa: B902 - counted, never fatal
            run.error('finish', exc)
        stats.finish_times[run.name] = time.perf_counter() - t0


def _place_output_bag(bag_dir: Path, tmp: Path, storage: str) -> None:
    """Make ``tmp`` itself a ROS 2 bag: its metadata.yaml beside ``output.mcap``."""
    if storage == 'mcap':
        os.replace(bag_dir / f'{bag_dir.name}.mcap', tmp / OUTPUT_BAG)
        meta = (bag_dir / 'metadata.yaml').read_text()
        (tmp / 'metadata.yaml').write_text(meta.replace(f'{bag_dir.name}.mcap', OUTPUT_BAG))
        shutil.rmtree(bag_dir)
    else:
        os.replace(bag_dir, tmp / OUTPUT_BAG)


_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
"""glibc's ``mallopt`` parameters (malloc.h)."""


@cache
def keep_freed_heap() -> bool:
    """
    Let glibc keep freed memory for reuse (once a process); return whether it was set.

    By default glibc serves an array over 128 KiB (raised as larger ones are freed)
    with its own ``mmap`` and returns it on free, and hands the top of the heap back
    beyond twice that: the many large, short-lived numpy arrays of a replay then
    meet fresh pages, each a page fault (a 1 h wheel calibration replay: 550k
    faults, 1.5 s of kernel time). Arrays up to 32 MiB now come from the heap,
    which keeps up to 64 MiB free (measured: 54k faults, 0.4 s). Other C
    libraries are left alone.
    """
    try:
        if not os.confstr('CS_GNU_LIBC_VERSION').startswith('glibc'):
            return False
        import ctypes
        mallopt = ctypes.CDLL(None).mallopt
    except (AttributeError, OSError, ValueError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, 32 << 20) and mallopt(_M_TRIM_THRESHOLD, 64 << 20))


def run(bagset: BagSet, plan: Plan, tmp: Path, progress: Optional[bool], storage: str,
        window: tuple[float, Optional[float]] = (0.0, None), compress: bool = True,
        plots: bool = True) -> RunStats:
    """
    Run the planned nodes over the bags; write the output bag (zstd chunks) into ``tmp``.

    With ``plots`` the input odometry and the ground truth are kept for the report's
    trajectory plots (the ground truth is read for them alone).
    """
    wall0 = time.perf_counter()
    keep_freed_heap()
    stats = RunStats()
    times: list = []
    routes = _routes(plan, times)
    traj_topics = {t for t in routes if plots and plan.bag_topics[t][0] == _ODOM_TYPE}
    if plots and plan.bag_topics.get(GROUND_TRUTH, ('',))[0] == _ODOM_TYPE:
        traj_topics.add(GROUND_TRUTH)
    topic_of = plan.topic_of_stream
    streams = [s for s in bagset.streams
               if topic_of[id(s)] in routes or topic_of[id(s)] in traj_topics]
    _deliver_static(bagset, plan, stats)
    # id(stream) -> (topic, routes, trajectory topic or None, whether every node may refuse it)
    stream_info = {id(s): (topic_of[id(s)], routes.get(topic_of[id(s)], ()),
                           topic_of[id(s)] if topic_of[id(s)] in traj_topics else None,
                           _refusable(s, routes.get(topic_of[id(s)], ())))
                   for s in streams}
    bar = _progress_bar(_expected_messages(bagset, streams, window), progress)
    bag_dir = tmp / Path(OUTPUT_BAG).stem  # a ROS 2 bag folder, flattened below
    latched = [t for r in plan.runs for (t, _, is_latched) in r.outputs.values() if is_latched]
    with BagWriter(bag_dir, storage=storage, latched=latched, compress=compress) as writer:
        emit = _Emitter(writer, stats)
        # Fewer, cheaper garbage collections while samples are created at a high rate
        # (restored below): existing objects are frozen out of the collector's scans.
        gc_threshold = gc.get_threshold()
        gc.freeze()
        gc.set_threshold(max(gc_threshold[0], 20000), *gc_threshold[1:])
        try:
            _loop(bagset, streams, stream_info, emit, stats, window, bar, times)
        finally:
            _flush_times(times)
            gc.set_threshold(*gc_threshold)
            gc.unfreeze()
        _finish(plan, emit, stats)
    _place_output_bag(bag_dir, tmp, storage)
    stats.seconds = time.perf_counter() - wall0
    return stats
