# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What a replay leaves beside its output bag: artifacts, ``summary.json``, plots and ``report.md``.

The summary holds per node its pipeline summary (parameters, inputs read /
accepted / rejected per reason, outputs, method results) and timing; at the top
level the bags, their duration, the topics read with counts, the undecodable
messages per topic, the mcap chunks skipped as corrupt and the nodes skipped.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional

import numpy as np

from robot_calib.core.jsonable import jsonable
from robot_calib.io.bags import BagSet
from robot_calib.replay.config import OUTPUT_BAG, REPORT, SUMMARY
from robot_calib.replay.run import RunStats
from robot_calib.replay.select import NodeRun, Plan


def write_artifacts(plan: Plan, tmp: Path) -> dict[str, str]:
    """Write each node's artifact files into ``tmp``; return {file name: node}."""
    artifacts: dict[str, str] = {}
    for run in plan.runs:
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
    return artifacts


def _timing(run: NodeRun, finish_seconds: float) -> dict[str, Any]:
    proc = run.times.total
    n_in = run.times.count
    return {
        'wall_seconds': proc + finish_seconds,
        'process_seconds': proc,
        'finish_seconds': finish_seconds,
        'input_messages': n_in,
        'input_messages_per_second': n_in / proc if proc > 0 else None,
        'per_message_ms_p50': None if not n_in else run.times.percentile(50) * 1e3,
        'per_message_ms_p99': None if not n_in else run.times.percentile(99) * 1e3,
    }


def node_summary(run: NodeRun, finish_seconds: float) -> dict[str, Any]:
    """Return a node's summary: its pipeline's, plus timing, topics, errors and its log."""
    try:
        base = run.pipeline.summary()
    except Exception as exc:  # noqa: B902 - counted, never fatal
        run.error('summary', exc)
        base = {'inputs': {k: dict(v) for k, v in run.pipeline.counts.items()},
                'outputs': dict(run.pipeline.n_outputs)}
    if 'timing' in base:  # the method's own timing figures, kept under another key
        base['method_timing'] = base.pop('timing')
    extras = {
        'timing': _timing(run, finish_seconds),
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
    return base


def build_summary(bag_list: list, bagset: BagSet, plan: Plan, stats: RunStats,
                  artifacts: dict[str, str], storage: str, wall_seconds: float,
                  window: tuple[float, Optional[float]]) -> dict[str, Any]:
    """Return the JSON-ready summary of a replay."""
    start, end = bagset.start_ns, bagset.end_ns
    nodes = {run.name: node_summary(run, stats.finish_times.get(run.name, 0.0))
             for run in plan.runs}
    return jsonable({
        'bags': [str(b) for b in bag_list],
        'start_time': start * 1e-9,
        'end_time': end * 1e-9,
        'duration': max(end - start, 0) * 1e-9,
        'window': [window[0], window[1]],
        'topics': {t: {'type': ty, 'count': n, 'read': stats.read.get(t, 0)}
                   for t, (ty, n) in sorted(plan.bag_topics.items())},
        'topics_read': dict(sorted(stats.read.items())),
        'undecodable': dict(sorted(stats.undecodable.items())),
        'restamped': dict(sorted(stats.restamped.items())),
        'corrupt_chunks': bagset.corrupt_chunks,
        'static_transforms': stats.n_static,
        'remaps': plan.remaps,
        'nodes': nodes,
        'skipped': plan.skipped,
        'output': {'bag': OUTPUT_BAG, 'storage': storage,
                   'topics': dict(sorted(stats.out_counts.items()))},
        'artifacts': sorted(artifacts),
        'timing': {'wall_seconds': wall_seconds, 'messages': stats.n_msgs,
                   'messages_per_second': stats.n_msgs / wall_seconds if wall_seconds else None},
    })


def _one_line(exc: BaseException) -> str:
    return f'{type(exc).__name__}: {" ".join(str(exc).split())}'


def _generic_plots(tmp: Path, stats: RunStats, summary: dict[str, Any]) -> list[str]:
    from robot_calib import report
    inputs = {t: np.asarray(list(v), dtype=float) for t, v in stats.trajectories.items() if v}
    outputs = {t: np.asarray(list(v), dtype=float) for t, v in stats.out_traj.items() if v}
    try:
        return report.generic_plots(tmp / 'plots', inputs, outputs, summary['start_time'])
    except Exception as exc:  # noqa: B902 - a plot must not fail the run
        summary['plot_error'] = _one_line(exc)
        return []


def _node_plots(plan: Plan, tmp: Path, summary: dict[str, Any]) -> dict[str, list[str]]:
    node_plots = {}
    for run in plan.runs:
        pdir = tmp / 'plots' / run.name
        pdir.mkdir(parents=True, exist_ok=True)
        try:
            files = run.pipeline.plot(str(pdir)) or []
            node_plots[run.name] = [f'plots/{run.name}/{Path(f).name}' for f in files]
        except Exception as exc:  # noqa: B902 - a plot must not fail the run
            summary['nodes'][run.name][run.errors_key]['plot'] = _one_line(exc)
        if not any(pdir.iterdir()):
            pdir.rmdir()
    return node_plots


def write_report(tmp: Path, plan: Plan, stats: RunStats, summary: dict[str, Any],
                 plots: bool = True) -> None:
    """Draw the plots (unless ``plots`` is false), then write report.md and summary.json."""
    from robot_calib import report
    node_plots: dict[str, list[str]] = {}
    generic: list[str] = []
    if plots:
        node_plots = _node_plots(plan, tmp, summary)
        generic = _generic_plots(tmp, stats, summary)
    summary['plots'] = generic + [f for v in node_plots.values() for f in v]
    (tmp / REPORT).write_text(report.render(summary, generic, node_plots))
    (tmp / SUMMARY).write_text(json.dumps(summary, indent=2, allow_nan=False) + '\n')
