# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The fleet result set: the table (CSV and Parquet) and the flags.

Flags, per robot and node, in date order:

- ``moved``: an estimate that comes with its standard deviation (``<name>_std``)
  more than ``k`` sigma from the median of that robot's earlier bags (at least
  two), sigma combining the estimate's own standard deviation and the spread of
  the earlier values; with one earlier bag, more than ``k`` sigma from it, sigma
  combining both bags' standard deviations (a change is flagged from the second
  bag on); numbers without an uncertainty (counts, adaptive noise scales) are
  tabled but not flagged, as their normal spread is unknown;
- ``trend``: with at least :data:`TREND_MIN_BAGS` bags, an estimate with a standard
  deviation whose straight-line fit over the dates has a slope more than ``k``
  sigma from zero (a tyre wearing, a bias creeping): each bag weighted by the
  larger of its own standard deviation and the scatter about the line, so an
  estimate whose stated uncertainty is too small is not flagged for its noise;
- ``stopped_converging``: a verdict other than ``converged`` after a converged one;
- ``alert``: a method raised alerts (a fall);
- ``corrupt_chunks``: corrupt mcap chunks of the bag were skipped, so its
  estimates come from incomplete data (one flag a bag, node empty);
- ``failed``: the bag could not be processed (the reason is the evidence).
"""

from __future__ import annotations

import csv
import datetime
import math
import os
from pathlib import Path
import statistics
from typing import Any, Optional

import numpy as np

FIRST = ('robot', 'date', 'bag', 'node', 'status', 'reason', 'corrupt_chunks', 'runtime_s',
         'peak_rss_mb')
TREND_MIN_BAGS = 4
"""Fewest bags of a robot for a trend flag: a line and the scatter about it need four."""
FLAG_COLUMNS = ('robot', 'date', 'bag', 'node', 'parameter', 'reason')


def sort_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Return the rows in a fixed order (robot, date, bag, node), whatever ran them."""
    return sorted(rows, key=lambda r: (r['robot'], r['date'] or '', r['bag'], r['node']))


def columns(rows: list[dict[str, Any]]) -> list[str]:
    """Return the table's columns: the fixed ones, then every estimate column sorted."""
    extra = sorted({k for r in rows for k in r} - set(FIRST))
    return list(FIRST) + extra


def atomic_write(path: Path, write: Any) -> None:
    """Write ``path`` through ``write(temporary path)`` and move it into place; no half file."""
    tmp = path.with_name(f'.{path.name}.tmp')
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_table(rows: list[dict[str, Any]], out: Path) -> list[str]:
    """Write ``results.csv`` and ``results.parquet`` into ``out``; return the files written."""
    cols = columns(rows)

    def to_csv(path: Path) -> None:
        with open(path, 'w', newline='') as f:
            writer = csv.DictWriter(f, fieldnames=cols, restval='')
            writer.writeheader()
            writer.writerows(rows)
    atomic_write(out / 'results.csv', to_csv)
    written = ['results.csv']
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return written
    table = pa.table({c: [r.get(c) for r in rows] for c in cols})
    atomic_write(out / 'results.parquet', lambda p: pq.write_table(table, str(p)))
    return written + ['results.parquet']


def _number(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        else math.nan


def _moved(history: list[float], value: float, std: float, k: float,
           first_std: float = math.nan) -> str:
    """
    Return why ``value`` (standard deviation ``std``) moved from ``history``, or ''.

    :param first_std: the standard deviation of the one earlier value, when there is one
    """
    if not (math.isfinite(value) and math.isfinite(std)):
        return ''
    if len(history) == 1:
        sigma = math.hypot(std, first_std)
        if math.isfinite(sigma) and sigma > 0.0 and abs(value - history[0]) > k * sigma:
            return (f'moved to {value:.6g} from {history[0]:.6g} (the one earlier bag), '
                    f'{abs(value - history[0]) / sigma:.1f} sigma of both bags')
        return ''
    if len(history) < 2:
        return ''
    centre = statistics.median(history)
    sigma = math.hypot(std, statistics.stdev(history))
    if sigma > 0.0 and abs(value - centre) > k * sigma:
        return (f'moved to {value:.6g} from {centre:.6g} (median of {len(history)} earlier bags), '
                f'{abs(value - centre) / sigma:.1f} sigma')
    return ''


def days_of(date: Any) -> float:
    """Return an ISO 8601 date as days since the epoch (NaN when missing or unreadable)."""
    try:
        when = datetime.datetime.fromisoformat(str(date))
    except ValueError:
        return math.nan
    if when.tzinfo is None:
        when = when.replace(tzinfo=datetime.timezone.utc)
    return when.timestamp() / 86400.0


def trend(days: list[float], values: list[float], stds: list[float]) -> Optional[tuple]:
    """
    Return ``(slope per day, its sigma)`` of a weighted straight line, or None.

    Weighted least squares with each bag's sigma the larger of its own standard
    deviation and the RMS scatter about an unweighted line (n - 2 degrees of
    freedom); None with fewer than :data:`TREND_MIN_BAGS` usable bags or no time
    span.
    """
    ok = [(d, v, s) for d, v, s in zip(days, values, stds)
          if math.isfinite(d) and math.isfinite(v) and math.isfinite(s)]
    if len(ok) < TREND_MIN_BAGS:
        return None
    d, v, s = (np.array(c, dtype=float) for c in zip(*ok))
    d = d - d.mean()
    if not np.ptp(d) > 0:
        return None
    line = np.polyfit(d, v, 1)
    scatter = math.sqrt(float(np.sum((v - np.polyval(line, d)) ** 2)) / (len(v) - 2))
    w = 1.0 / np.maximum(s, scatter) ** 2
    if not np.all(np.isfinite(w)):
        return None
    dw = d - np.sum(w * d) / np.sum(w)
    sxx = float(np.sum(w * dw ** 2))
    return float(np.sum(w * dw * v) / sxx), 1.0 / math.sqrt(sxx)


def _trend_flags(series: dict[tuple, list], k: float) -> list[dict[str, Any]]:
    """Return the trend flags, each on the robot's last bag of that estimate."""
    out = []
    for (_, col), points in series.items():
        fit = trend([p[1] for p in points], [p[2] for p in points], [p[3] for p in points])
        if fit is None or not abs(fit[0]) > k * fit[1]:
            continue
        slope, sigma = fit
        span = max(p[1] for p in points) - min(p[1] for p in points)
        out.append({**points[-1][0], 'parameter': col.split('.', 1)[1],
                    'reason': f'trend {slope * 7:+.3g} per week over {len(points)} bags '
                              f'({span:.0f} days, {slope * span:+.3g} in all), '
                              f'{abs(slope) / sigma:.1f} sigma'})
    return out


def flags(rows: list[dict[str, Any]], k: float = 4.0) -> list[dict[str, Any]]:
    """Return the flags of the table's rows (see the module docstring)."""
    out = []
    history: dict[tuple, list[float]] = {}
    first_std: dict[tuple, float] = {}
    series: dict[tuple, list] = {}
    converged: set[tuple] = set()
    corrupt: set[str] = set()
    for r in sort_rows(rows):
        where = {c: r[c] for c in ('robot', 'date', 'bag', 'node')}
        if r['status'] == 'failed':
            out.append({**where, 'parameter': '', 'reason': f'failed: {r["reason"]}'})
            continue
        if _number(r.get('corrupt_chunks')) > 0 and r['bag'] not in corrupt:
            corrupt.add(r['bag'])
            out.append({**where, 'node': '', 'parameter': 'corrupt_chunks',
                        'reason': f'{int(r["corrupt_chunks"])} corrupt mcap chunk(s) skipped: '
                                  "the bag's data are incomplete"})
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
                std = _number(r.get(f'{col}_std'))
                why = _moved(history.get(key, []), x, std, k, first_std.get(key, math.nan))
                if why:
                    out.append({**where, 'parameter': name, 'reason': why})
                if math.isfinite(x):
                    history.setdefault(key, []).append(x)
                    first_std.setdefault(key, std)
                    if math.isfinite(std):
                        series.setdefault(key, []).append((where, days_of(r['date']), x, std))
    return sorted(out + _trend_flags(series, k),
                  key=lambda f: (f['robot'], f['date'] or '', f['bag'], f['node']))


def write_flags(found: list[dict[str, Any]], out: Path) -> None:
    """Write ``flags.csv``."""
    def to_csv(path: Path) -> None:
        with open(path, 'w', newline='') as f:
            writer = csv.DictWriter(f, fieldnames=FLAG_COLUMNS)
            writer.writeheader()
            writer.writerows(found)
    atomic_write(out / 'flags.csv', to_csv)
