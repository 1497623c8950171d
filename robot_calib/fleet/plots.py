# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The fleet report's figures: each robot's trends, the fleet's spread, one estimate across robots.

Only estimates that come with a standard deviation are drawn (those the flags
judge): per robot one panel per estimate, the value at each bag's date with a
2-sigma bar, flagged bags in red; per estimate a histogram of each robot's
latest value; per estimate every robot's series over time, flagged robots in
colour.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from robot_calib.core import figures
from robot_calib.fleet.results import days_of

MAX_OVERVIEW_COLOURED = 10
"""Flagged robots drawn in colour in an estimate's overview (the rest stay grey)."""


def tracked(rows: list[dict[str, Any]]) -> list[str]:
    """Return the estimate columns that have a standard deviation column, sorted."""
    cols = {k for r in rows for k in r}
    return sorted(c for c in cols if f'{c}_std' in cols and '.' in c)


def _series(rows: list[dict[str, Any]], robot: str, col: str) -> np.ndarray:
    """Return (days, value, std) rows of one robot's estimate, in date order."""
    out = []
    for r in rows:
        if r['robot'] != robot or r['status'] != 'ok' or col not in r:
            continue
        v, s = r.get(col), r.get(f'{col}_std')
        if isinstance(v, (int, float)) and isinstance(s, (int, float)) and math.isfinite(v):
            out.append((days_of(r['date']), float(v), float(s)))
    return np.array(sorted(out)).reshape(-1, 3)


def _panels(n: int) -> tuple[Any, np.ndarray]:
    """Return a figure with a grid of ``n`` small panels (4 a row) and its axes, flat."""
    cols = min(n, 4)
    rows = int(math.ceil(n / cols))
    height = 2.4 * rows + 0.5
    fig, axes = figures.new_figure(3.2 * cols, height, rows, cols)
    fig.subplots_adjust(top=1.0 - 0.6 / height, hspace=0.7, wspace=0.4)
    axes = np.atleast_1d(axes).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes


def _date_axis(ax: Any, days: np.ndarray, day0: float) -> None:
    ax.set_xlabel(f'days since {_iso(day0)}', fontsize=7)
    if len(days):
        ax.set_xlim(min(days.min() - day0, 0.0) - 1.0, days.max() - day0 + 1.0)


def _iso(day: float) -> str:
    import datetime
    return datetime.datetime.fromtimestamp(day * 86400.0, datetime.timezone.utc).date().isoformat()


def robot_figure(rows: list[dict[str, Any]], robot: str, cols: list[str],
                 flagged: dict[str, set[float]], path: Path) -> str:
    """Draw one robot's estimates over time (2-sigma bars, flagged bags red); return the name."""
    fig, axes = _panels(len(cols))
    day0 = min((d for r in rows if r['robot'] == robot
                for d in [days_of(r['date'])] if math.isfinite(d)), default=0.0)
    for ax, col in zip(axes, cols):
        s = _series(rows, robot, col)
        ax.errorbar(s[:, 0] - day0, s[:, 1], yerr=2.0 * s[:, 2], fmt='o-', ms=3, lw=0.8,
                    capsize=2, color='C0')
        bad = np.array([d in flagged.get(col, set()) for d in s[:, 0]], dtype=bool)
        if bad.any():
            ax.plot(s[bad, 0] - day0, s[bad, 1], 'o', color='C3', ms=6)
        ax.set_title(col, fontsize=7)
        ax.tick_params(labelsize=7)
        _date_axis(ax, s[:, 0], day0)
    fig.suptitle(f'{robot}: estimates with 2-sigma bars (red: flagged)', fontsize=9)
    return figures.save(fig, path, dpi=80)


def histograms(rows: list[dict[str, Any]], robots: list[str], cols: list[str],
               path: Path) -> str:
    """Draw, per estimate, the histogram of every robot's latest value; return the name."""
    fig, axes = _panels(len(cols))
    for ax, col in zip(axes, cols):
        latest = [s[-1, 1] for s in (_series(rows, r, col) for r in robots) if len(s)]
        ax.hist(latest, bins=max(5, min(30, len(latest) // 2)), color='C0')
        ax.set_title(col, fontsize=7)
        ax.tick_params(labelsize=7)
        ax.set_ylabel('robots', fontsize=7)
    fig.suptitle('latest value of each robot', fontsize=9)
    return figures.save(fig, path, dpi=80)


def overview(rows: list[dict[str, Any]], robots: list[str], col: str, flagged: set[str],
             path: Path) -> str:
    """Draw every robot's series of one estimate, flagged robots in colour; return the name."""
    fig, ax = figures.new_figure(7, 3.5)
    day0 = min((d for r in rows for d in [days_of(r['date'])] if math.isfinite(d)),
               default=0.0)
    coloured = [r for r in robots if r in flagged][:MAX_OVERVIEW_COLOURED]
    for robot in robots:
        s = _series(rows, robot, col)
        if robot in coloured:
            ax.plot(s[:, 0] - day0, s[:, 1], 'o-', ms=3, lw=1.2, label=robot)
        else:
            ax.plot(s[:, 0] - day0, s[:, 1], '-', color='0.75', lw=0.6)
    ax.set_title(f'{col} of every robot (flagged in colour)', fontsize=9)
    ax.set_xlabel(f'days since {_iso(day0)}')
    if coloured:
        ax.legend(fontsize=7)
    return figures.save(fig, path, dpi=80)
