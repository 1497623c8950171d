# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The fleet's ``report.md``: the flags with their evidence, then the figures to judge them by.

Robots with flags come first, each with its trends; then the fleet: the spread
of every robot's latest values and each estimate across robots; then links to
every robot's trends, the slowest bags and the workers' peak memory. Figures
go to ``DIR/plots/`` (``robots/<robot>.png``, ``fleet_histograms.png``,
``estimates/<node>.<estimate>.png``); without matplotlib the report has text only.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterable

from robot_calib.core import figures
from robot_calib.fleet import plots
from robot_calib.fleet.results import atomic_write, days_of


def _flag_table(found: list[dict[str, Any]]) -> list[str]:
    lines = ['## Flags', '', '| robot | date | node | parameter | reason |',
             '|---|---|---|---|---|']
    return lines + ([f'| {f["robot"]} | {f["date"]} | {f["node"]} | {f["parameter"]} | '
                     f'{f["reason"]} |' for f in found] or ['| - | - | - | - | none |'])


Draw = Callable[[list[tuple]], Iterable[str]]
"""Runs figure calls (see :func:`draw`), on the fleet's workers or in this process."""


def draw(call: tuple) -> str:
    """Draw one figure: ``call`` is ``(plots function, its arguments)``; return the file name."""
    function, args = call
    try:
        return function(*args)
    except BaseException:
        Path(args[-1]).unlink(missing_ok=True)   # no half-drawn figure (a full disk)
        raise


def _draw_here(calls: list[tuple]) -> list[str]:
    return [draw(call) for call in calls]


def _slim(rows: list[dict[str, Any]], cols: list[str]) -> list[dict[str, Any]]:
    """Return ``rows`` with only what the figures of ``cols`` read (sent to a worker)."""
    keep = ['robot', 'status', 'date'] + [k for c in cols for k in (c, f'{c}_std')]
    return [{k: r[k] for k in keep if k in r} for r in rows]


def _figures(rows: list[dict[str, Any]], found: list[dict[str, Any]], out: Path,
             robots: list[str], draw_all: Draw) -> list[str]:
    """Draw the figures (through ``draw_all``); return the report lines that show them."""
    failed = {f['robot'] for f in found if f['reason'].startswith('failed')}
    cols = plots.tracked(rows)
    if not cols or not figures.available():
        return []
    flagged_bags: dict[str, dict[str, set[float]]] = {}
    for f in found:
        col = f'{f["node"]}.{f["parameter"]}'
        flagged_bags.setdefault(f['robot'], {}).setdefault(col, set()).add(days_of(f['date']))
    (out / 'plots' / 'robots').mkdir(parents=True, exist_ok=True)
    (out / 'plots' / 'estimates').mkdir(parents=True, exist_ok=True)
    drawn = sorted({r['robot'] for r in rows if r['status'] == 'ok'})
    slim = _slim(rows, cols)
    by_robot: dict[str, list[dict[str, Any]]] = {}
    for r in slim:
        by_robot.setdefault(r['robot'], []).append(r)
    calls = [(plots.robot_figure, (by_robot[robot], robot, cols, flagged_bags.get(robot, {}),
                                   out / 'plots' / 'robots' / f'{robot}.png'))
             for robot in drawn]
    calls.append((plots.histograms, (slim, drawn, cols, out / 'plots' / 'fleet_histograms.png')))
    lines = ['', '## Robots with flags', '']
    attention = [r for r in robots if r in flagged_bags or r in failed]
    lines += [f'### {r}\n\n![{r}](plots/robots/{r}.png)\n' if r in drawn else
              f'### {r}\n\nno bag processed\n' for r in attention] or ['none']
    lines += ['', '## Fleet', '', '![latest values](plots/fleet_histograms.png)', '']
    for col in cols:
        flagged = {r for r, by_col in flagged_bags.items() if col in by_col}
        calls.append((plots.overview, (_slim(rows, [col]), drawn, col, flagged,
                                       out / 'plots' / 'estimates' / f'{col}.png')))
        lines.append(f'![{col}](plots/estimates/{col}.png)')
    lines += ['', '## Every robot', '',
              ', '.join(f'[{r}](plots/robots/{r}.png)' for r in drawn)]
    list(draw_all(calls))
    return lines


def write_report(rows: list[dict[str, Any]], found: list[dict[str, Any]], out: Path,
                 seconds: float, draw_all: Draw = _draw_here, notes: Iterable[str] = ()) -> None:
    """
    Write ``report.md`` and its figures into ``out``.

    ``draw_all`` runs the figure calls (a list of :func:`draw` arguments): the
    fleet hands them to its workers, since a figure costs about 0.3-0.5 s and a
    fleet has one per robot. ``notes``: said under the summary line (bags counted
    once, bags replayed again because they changed).
    """
    bags = {(r['robot'], r['bag']) for r in rows}
    failed = {(r['robot'], r['bag']) for r in rows if r['status'] == 'failed'}
    robots = sorted({r['robot'] for r in rows})
    lines = ['# Fleet report', '',
             f'{len(bags)} bags of {len(robots)} robots in {seconds:.1f} s; '
             f'{len(failed)} failed; {len(found)} flags.', '']
    notes = list(notes)
    if notes:
        lines += ['## Notes', ''] + [f'- {n}' for n in notes] + ['']
    lines += _flag_table(found)
    lines += _figures(rows, found, out, robots, draw_all)
    slow = sorted((r for r in rows if r['status'] == 'ok'), key=lambda r: -r['runtime_s'])[:5]
    lines += ['', '## Slowest bags', '', '| robot | bag | node | runtime (s) |',
              '|---|---|---|---|']
    lines += [f'| {r["robot"]} | {Path(r["bag"]).name} | {r["node"]} | {r["runtime_s"]:.2f} |'
              for r in slow]
    peaks = [r['peak_rss_mb'] for r in rows if isinstance(r.get('peak_rss_mb'), (int, float))]
    if peaks:
        lines += ['', f'Peak resident memory of a worker: {max(peaks):.0f} MB.']
    atomic_write(out / 'report.md', lambda p: p.write_text('\n'.join(lines) + '\n'))
