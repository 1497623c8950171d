# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The replay report: generic PNG plots and ``report.md`` built from ``summary.json``.

Generic plots: every nav_msgs/Odometry trajectory the nodes published, drawn
against the input odometry and ``/ground_truth/odom`` when the bag has it (x-y
in metres), and the heading of the same topics over time (degrees, seconds
from the bag start). Each pipeline adds its own plots through
``Pipeline.plot(out_dir)``.
"""

from __future__ import annotations

from pathlib import Path
import re
from typing import Any

import numpy as np
from robot_calib.core import figures

_MAX_POINTS = 20000
GROUND_TRUTH = '/ground_truth/odom'


def _thin(a: np.ndarray) -> np.ndarray:
    if len(a) <= _MAX_POINTS:
        return a
    return a[:: int(np.ceil(len(a) / _MAX_POINTS))]


def generic_plots(plot_dir: Path, inputs: dict[str, np.ndarray], outputs: dict[str, np.ndarray],
                  t0: float) -> list[str]:
    """
    Draw trajectory and heading plots; return their paths relative to the report.

    :param plot_dir: folder for the PNG files (created).
    :param inputs: input odometry by topic: arrays of rows (t s, x m, y m, yaw rad).
    :param outputs: output odometry by topic, same layout.
    :param t0: bag start time (s), subtracted on the time axis.
    :return: file names relative to the report folder (``plots/...``).
    """
    if not inputs and not outputs:
        return []
    plot_dir = Path(plot_dir)
    plot_dir.mkdir(parents=True, exist_ok=True)
    series = [(t, a, 'input') for t, a in sorted(inputs.items())] + \
        [(t, a, 'output') for t, a in sorted(outputs.items())]
    written = []

    fig, ax = figures.new_figure(7, 6)
    for topic, arr, kind in series:
        a = _thin(arr)
        ax.plot(a[:, 1], a[:, 2], **_style(topic, kind))
        ax.plot(a[:1, 1], a[:1, 2], 'k.', ms=4)
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_aspect('equal', adjustable='datalim')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title('Odometry trajectories (each in its own odom frame)')
    figures.save(fig, plot_dir / 'trajectories.png', dpi=100)
    written.append('plots/trajectories.png')

    fig, ax = figures.new_figure(9, 4)
    for topic, arr, kind in series:
        a = _thin(arr)
        ax.plot(a[:, 0] - t0, np.degrees(np.unwrap(a[:, 3])), **_style(topic, kind))
    ax.set_xlabel('time from bag start [s]')
    ax.set_ylabel('heading [deg]')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title('Heading over time (unwrapped)')
    figures.save(fig, plot_dir / 'heading.png', dpi=100)
    written.append('plots/heading.png')
    return written


def _style(topic: str, kind: str) -> dict:
    if topic == GROUND_TRUTH:
        return {'color': 'k', 'ls': ':', 'lw': 1.5, 'label': f'{topic} (reference)'}
    return {'ls': '-' if kind == 'output' else '--', 'lw': 1.2, 'label': f'{topic} ({kind})'}


_SCALAR = (str, int, float, bool, type(None))


def _brief(value: Any) -> str:
    """Return a one-cell rendering of a result: scalars, short lists/maps, else a count."""
    scalar = _SCALAR
    if isinstance(value, scalar):
        return _fmt(value).replace('|', '/')
    if isinstance(value, list):
        if len(value) <= 6 and all(isinstance(v, scalar) for v in value):
            return '[' + ', '.join(_fmt(v) for v in value) + ']'
        return f'{len(value)} items (see summary.json)'
    if isinstance(value, dict):
        if len(value) <= 8 and all(isinstance(v, scalar) for v in value.values()):
            return ', '.join(f'{k}: {_fmt(v)}' for k, v in value.items()).replace('|', '/')
        return f'{len(value)} entries (see summary.json)'
    return _fmt(value)


def _fmt(value: Any) -> str:
    if value is None:
        return 'n/a'
    if isinstance(value, float):
        return f'{value:.4g}'
    return str(value)


_STANDARD = {'params', 'inputs', 'outputs', 'timing', 'input_topics', 'output_topics', 'errors',
             'first_errors', 'notes', 'log'}


def render(summary: dict, generic: list[str], node_plots: dict[str, list[str]]) -> str:
    """Return the markdown report of a replay ``summary`` with its plot links."""
    lines = ['# robot_calib replay report', '']
    lines.append(f'Bags: {", ".join(f"`{b}`" for b in summary["bags"])}  ')
    lines.append(f'Duration: {summary["duration"]:.1f} s of recording, replayed in '
                 f'{_fmt(summary["timing"]["wall_seconds"])} s '
                 f'({_fmt(summary["timing"]["messages_per_second"])} messages/s).  ')
    if summary.get('remaps'):
        lines.append('Remaps: ' + ', '.join(f'`{a}:={b}`' for a, b in summary['remaps'].items())
                     + '  ')
    if summary.get('window'):
        start, length = summary['window']
        lines.append(f'Window: from {start:g} s' + (f' for {length:g} s' if length is not None
                                                    else ' to the end') + '  ')
    if summary.get('corrupt_chunks'):
        lines.append(f'**Corrupt:** {len(summary["corrupt_chunks"])} chunk(s) of the bag(s) '
                     'failed their check and were skipped whole (their messages are missing; '
                     'see `corrupt_chunks` in summary.json).  ')
    lines += ['', '## Topics', '', '| topic | type | in bag | read | undecodable |',
              '|---|---|---:|---:|---:|']
    for topic, info in summary['topics'].items():
        lines.append(f'| `{topic}` | {info["type"]} | {info["count"]} | {info["read"]} | '
                     f'{summary["undecodable"].get(topic, 0)} |')
    lines += ['', '## Nodes', '',
              '| node | input | read | accepted | rejected | outputs | msg/s | p50 ms | p99 ms |',
              '|---|---|---:|---:|---:|---|---:|---:|---:|']
    for name, node in summary['nodes'].items():
        timing = node.get('timing', {})
        outs = ', '.join(f'{k}: {v}' for k, v in node.get('outputs', {}).items()) or '-'
        for key, c in (node.get('inputs') or {'-': {}}).items():
            lines.append(
                f'| {name} | {key} | {c.get("read", 0)} | {c.get("accepted", 0)} | '
                f'{c.get("rejected", 0)} | {outs} | '
                f'{_fmt(timing.get("input_messages_per_second"))} | '
                f'{_fmt(timing.get("per_message_ms_p50"))} | '
                f'{_fmt(timing.get("per_message_ms_p99"))} |')
    for name, node in summary['nodes'].items():
        lines += ['', f'### {name}', '']
        for key, c in (node.get('inputs') or {}).items():
            reasons = {k[len('rejected_'):]: v for k, v in c.items()
                       if k.startswith('rejected_')}
            if reasons or c.get('gaps'):
                text = ', '.join(f'{k} {v}' for k, v in reasons.items())
                lines.append(f'- input `{key}`: rejected {text or "none"}; gaps '
                             f'{c.get("gaps", 0)}')
        if node.get('errors'):
            lines.append(f'- errors: {node["errors"]}')
        for note in node.get('notes', []):
            lines.append(f'- note: {note}')
        results = {k: v for k, v in node.items() if k not in _STANDARD}
        if results:
            lines += ['', '| result | value |', '|---|---|']
            for k, v in results.items():
                # a result of a few dozen plain values (a calibration) is shown, not counted
                if isinstance(v, dict) and 8 < len(v) <= 32 and all(
                        isinstance(x, _SCALAR) for x in v.values()):
                    lines += [f'| {k}.{s} | {_brief(x)} |' for s, x in v.items()]
                else:
                    lines.append(f'| {k} | {_brief(v)} |')
        for plot in node_plots.get(name, []):
            lines += ['', f'![{name}]({plot})']
    if summary.get('skipped'):
        lines += ['', '## Skipped nodes', '']
        lines += [f'- {name}: {why}' for name, why in summary['skipped'].items()]
    if summary.get('artifacts'):
        lines += ['', '## Files', '']
        lines += [f'- [{f}]({f})' for f in summary['artifacts']]
    stack = summary.get('stack') or {}
    if stack.get('files') or stack.get('withheld'):
        lines += ['', "## For the robot's stack", '',
                  f'In `{stack.get("folder", "stack")}/`: ros2_control parameters, static '
                  'transforms and URDF joints of what the nodes found (each file says which '
                  'node and which recording it came from).', '']
        lines += [f'- [{f}]({f}) ({node})' for f, node in stack.get('files', {}).items()]
        lines += [f'- not written: {why}' for why in stack.get('withheld', [])]
    if generic:
        lines += ['', '## Plots', '']
        lines += [f'![{Path(p).stem}]({p})' for p in generic]
    lines += ['', f'Output bag: `{summary["output"]["bag"]}` (ROS 2, '
              f'{summary["output"]["storage"]}): ' + (', '.join(
                  f'`{t}` {n}' for t, n in summary['output']['topics'].items()) or 'no messages')
              + '.', '']
    return re.sub(r'\n{3,}', '\n\n', '\n'.join(lines))
