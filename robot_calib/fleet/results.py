# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The fleet result set: the table (CSV and Parquet), the flags and the report.

Flags, per robot and node, in date order:

- ``moved``: an estimate that comes with its standard deviation (``<name>_std``)
  more than ``k`` sigma from the median of that robot's earlier bags (at least
  two), sigma combining the estimate's own standard deviation and the spread of
  the earlier values; numbers without an uncertainty (counts, adaptive noise
  scales) are tabled but not flagged, as their normal spread is unknown;
- ``stopped_converging``: a verdict other than ``converged`` after a converged one;
- ``alert``: a method raised alerts (a fall);
- ``failed``: the bag could not be processed (the reason is the evidence).
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
import statistics
from typing import Any

FIRST = ('robot', 'date', 'bag', 'node', 'status', 'reason', 'runtime_s')
FLAG_COLUMNS = ('robot', 'date', 'bag', 'node', 'parameter', 'reason')


def sort_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Return the rows in a fixed order (robot, date, bag, node), whatever ran them."""
    return sorted(rows, key=lambda r: (r['robot'], r['date'] or '', r['bag'], r['node']))


def columns(rows: list[dict[str, Any]]) -> list[str]:
    """Return the table's columns: the fixed ones, then every estimate column sorted."""
    extra = sorted({k for r in rows for k in r} - set(FIRST))
    return list(FIRST) + extra


def _atomic_write(path: Path, write: Any) -> None:
    tmp = path.with_name(f'.{path.name}.tmp')
    write(tmp)
    os.replace(tmp, path)


def write_table(rows: list[dict[str, Any]], out: Path) -> list[str]:
    """Write ``results.csv`` and ``results.parquet`` into ``out``; return the files written."""
    cols = columns(rows)

    def to_csv(path: Path) -> None:
        with open(path, 'w', newline='') as f:
            writer = csv.DictWriter(f, fieldnames=cols, restval='')
            writer.writeheader()
            writer.writerows(rows)
    _atomic_write(out / 'results.csv', to_csv)
    written = ['results.csv']
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return written
    table = pa.table({c: [r.get(c) for r in rows] for c in cols})
    _atomic_write(out / 'results.parquet', lambda p: pq.write_table(table, str(p)))
    return written + ['results.parquet']


def _number(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        else math.nan


def _moved(history: list[float], value: float, std: float, k: float) -> str:
    if len(history) < 2 or not (math.isfinite(value) and math.isfinite(std)):
        return ''
    centre = statistics.median(history)
    sigma = math.hypot(std, statistics.stdev(history))
    if sigma > 0.0 and abs(value - centre) > k * sigma:
        return (f'moved to {value:.6g} from {centre:.6g} (median of {len(history)} earlier bags), '
                f'{abs(value - centre) / sigma:.1f} sigma')
    return ''


def flags(rows: list[dict[str, Any]], k: float = 4.0) -> list[dict[str, Any]]:
    """Return the flags of the table's rows (see the module docstring)."""
    out = []
    history: dict[tuple, list[float]] = {}
    converged: set[tuple] = set()
    for r in sort_rows(rows):
        where = {c: r[c] for c in ('robot', 'date', 'bag', 'node')}
        if r['status'] == 'failed':
            out.append({**where, 'parameter': '', 'reason': f'failed: {r["reason"]}'})
            continue
        for col, value in r.items():
            if not col.startswith(f'{r["node"]}.') or col.endswith('_std'):
                continue
            name = col.split('.', 1)[1]
            key = (r['robot'], col)
            if name == 'verdict':
                if value == 'converged':
                    converged.add(key)
                elif key in converged:
                    out.append({**where, 'parameter': name,
                                'reason': f'stopped converging: {value}'})
            elif name == 'alerts' and _number(value) > 0:
                out.append({**where, 'parameter': name, 'reason': f'{int(value)} alert(s)'})
            elif name != 'alerts':
                x = _number(value)
                why = _moved(history.get(key, []), x, _number(r.get(f'{col}_std')), k)
                if why:
                    out.append({**where, 'parameter': name, 'reason': why})
                if math.isfinite(x):
                    history.setdefault(key, []).append(x)
    return out


def write_flags(found: list[dict[str, Any]], out: Path) -> None:
    """Write ``flags.csv``."""
    def to_csv(path: Path) -> None:
        with open(path, 'w', newline='') as f:
            writer = csv.DictWriter(f, fieldnames=FLAG_COLUMNS)
            writer.writeheader()
            writer.writerows(found)
    _atomic_write(out / 'flags.csv', to_csv)


def write_report(rows: list[dict[str, Any]], found: list[dict[str, Any]], out: Path,
                 seconds: float) -> None:
    """Write ``report.md``: counts, the flags with their evidence, the slowest bags."""
    bags = {(r['robot'], r['bag']) for r in rows}
    failed = {(r['robot'], r['bag']) for r in rows if r['status'] == 'failed'}
    robots = sorted({r['robot'] for r in rows})
    lines = ['# Fleet report', '',
             f'{len(bags)} bags of {len(robots)} robots in {seconds:.1f} s; '
             f'{len(failed)} failed; {len(found)} flags.', '',
             '## Flags', '', '| robot | date | node | parameter | reason |',
             '|---|---|---|---|---|']
    lines += [f'| {f["robot"]} | {f["date"]} | {f["node"]} | {f["parameter"]} | '
              f'{f["reason"]} |' for f in found] or ['| - | - | - | - | none |']
    slow = sorted((r for r in rows if r['status'] == 'ok'), key=lambda r: -r['runtime_s'])[:5]
    lines += ['', '## Slowest bags', '', '| robot | bag | node | runtime (s) |',
              '|---|---|---|---|']
    lines += [f'| {r["robot"]} | {Path(r["bag"]).name} | {r["node"]} | {r["runtime_s"]:.2f} |'
              for r in slow]
    _atomic_write(out / 'report.md', lambda p: p.write_text('\n'.join(lines) + '\n'))
