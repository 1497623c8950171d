# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Obstacle grid, wall-segment extraction and line fitting (seed 000, condition 1).

The obstacle grid keeps, per cell of ``resolution`` metres, the running mean
of the scan hits that fell into it (a sub-cell centroid, so the fitted angle
is not limited by the cell size) and the time it was last hit. It is bounded
in memory for a whole-life run: cells not hit for ``cell_lifetime`` seconds
are cleared, at most ``max_cells`` cells are kept (the stalest go first), and
the owner clears it after a heading correction or an odometry reset (its hits
were placed with the old pose).

Segment extraction: the cells hit by the current scan, in beam order, are
split where two consecutive cells are farther apart than ``max_gap``, then
split recursively at the cell farthest from the chord while it is farther
than ``split_distance`` (iterative end-point fit). Each piece is a candidate
wall and must pass condition 1.

Condition 1 (seed 000, S11-S13): least-squares line fit of the cells; drop
it when it is shorter than ``min_length``; pass when the variance of the
cell-to-line distances is at most ``max_variance``; otherwise remove the
``remove_count`` farthest cells and refit, until it passes, or it is shorter
than ``min_length`` (or has fewer than ``min_cells`` cells) and is dropped.

The fit is TOTAL least squares (principal axis of the cells' scatter, i.e.
the perpendicular distances are minimised), not ordinary least squares
(``y = a x + b``, vertical residuals): walls come in every direction, OLS is
biased for steep lines and undefined for vertical ones, and condition 1
itself measures perpendicular cell-to-line distances. ``fit_method =
'ordinary'`` keeps OLS for comparison only (see the tests).
"""

from __future__ import annotations

from dataclasses import dataclass
import itertools
import math
from typing import Optional

import numpy as np

from robot_calib.core.params import param


@dataclass
class LineParams:
    """Obstacle grid, segment extraction and condition 1 parameters."""

    resolution: float = param(0.05, 'm', 'Obstacle grid cell size.', minimum=0.005)
    max_cells: int = param(20000, '', 'Most grid cells kept (the stalest are dropped first).',
                           minimum=100)
    cell_lifetime: float = param(3.0, 's', 'A cell not hit for this long is cleared.',
                                 minimum=0.0)
    max_hits_per_cell: int = param(20, '', 'Hits averaged per cell (older hits fade).',
                                   minimum=1)
    max_range: float = param(6.0, 'm', 'Beams longer than this are not put into the grid.',
                             minimum=0.1)
    max_gap: float = param(0.2, 'm', 'Consecutive cells farther apart start a new segment.',
                           minimum=0.0)
    split_distance: float = param(0.06, 'm', 'Split a segment at a cell this far from its chord.',
                                  minimum=0.0)
    min_length: float = param(0.6, 'm', 'Condition 1: shortest line kept (seed preset length).',
                              minimum=0.0)
    max_variance: float = param(1.0e-4, 'm^2', 'Condition 1: largest variance of cell-to-line '
                                'distances (seed preset value).', minimum=0.0)
    remove_count: int = param(2, '', 'Condition 1: farthest cells removed before a refit.',
                              minimum=1)
    min_cells: int = param(8, '', 'Fewest cells in a line.', minimum=2)
    fit_method: str = param('total', '', 'Least-squares fit: total (perpendicular) or '
                            'ordinary (y on x, for comparison only).',
                            choices=('total', 'ordinary'))


class _cached:
    """
    A lazily computed attribute, stored on the instance on first use.

    Like :class:`functools.cached_property` without its per-access lock (Python
    3.11), which cost more than the values (a 2-vector) it guards.
    """

    def __init__(self, func):
        """Wrap ``func(instance)``."""
        self.func = func
        self.name = func.__name__
        self.__doc__ = func.__doc__

    def __get__(self, obj, owner=None):
        """Compute the value once and keep it in the instance's ``__dict__``."""
        if obj is None:
            return self
        value = obj.__dict__[self.name] = self.func(obj)
        return value


@dataclass(frozen=True)
class Line:
    """
    A fitted wall line in the grid (world) frame.

    :ivar p1: start point (m); endpoints are ordered along the direction
        ``(cos angle, sin angle)``, so start and end are comparable between lines.
    :ivar p2: end point (m).
    :ivar angle: direction to the x axis (rad), modulo pi in (-pi/2, pi/2].
    :ivar length: |p2 - p1| (m).
    :ivar variance: mean squared cell-to-line distance (m^2).
    :ivar n_cells: cells used.
    :ivar t: time of the scan it was fitted in (s).
    """

    p1: np.ndarray
    p2: np.ndarray
    angle: float
    length: float
    variance: float
    n_cells: int
    t: float = 0.0

    @_cached
    def midpoint(self) -> np.ndarray:
        """Return the middle of the segment (m)."""
        return 0.5 * (self.p1 + self.p2)

    @_cached
    def direction(self) -> np.ndarray:
        """Return the unit vector along the line, (cos angle, sin angle)."""
        return np.array([math.cos(self.angle), math.sin(self.angle)])

    @_cached
    def normal(self) -> np.ndarray:
        """Return the unit vector across the line, (-sin angle, cos angle)."""
        return np.array([-math.sin(self.angle), math.cos(self.angle)])

    @_cached
    def rho(self) -> float:
        """Return the signed distance (m) of the line from the origin along :attr:`normal`."""
        return float(self.normal @ self.midpoint)

    def angle_sigma(self) -> float:
        """
        Return the 1-sigma angle uncertainty (rad) of the fit from its scatter.

        Total least squares with n points spread uniformly over length L and
        perpendicular noise variance s2: var(angle) = 12 s2 / (n L^2).
        """
        s2 = max(self.variance, 1e-6)
        return math.sqrt(12.0 * s2 / (max(self.n_cells, 2) * max(self.length, 1e-3) ** 2))


def line_from_endpoints(p1, p2, t: float = 0.0, variance: float = 0.0,
                        n_cells: int = 2) -> Line:
    """Return a :class:`Line` through two points (m), endpoints ordered canonically."""
    p1 = np.asarray(p1, dtype=float)
    p2 = np.asarray(p2, dtype=float)
    (x1, y1), (x2, y2) = p1.tolist(), p2.tolist()
    return _line_xy(x1, y1, x2, y2, t, variance, n_cells, p1, p2)


def _line_xy(x1: float, y1: float, x2: float, y2: float, t: float, variance: float,
             n_cells: int, p1: Optional[np.ndarray] = None,
             p2: Optional[np.ndarray] = None) -> Line:
    """Return :func:`line_from_endpoints` of (x1, y1), (x2, y2) (m) (the arrays when given)."""
    if p1 is None:
        p1, p2 = np.array([x1, y1]), np.array([x2, y2])
    dx, dy = x2 - x1, y2 - y1
    angle = math.atan2(dy, dx)
    if angle > math.pi / 2:
        angle -= math.pi
    elif angle <= -math.pi / 2:
        angle += math.pi
    if math.cos(angle) * dx + math.sin(angle) * dy < 0.0:
        p1, p2 = p2, p1
    return Line(p1, p2, angle, math.hypot(dx, dy), float(variance), int(n_cells), t)


class ObstacleGrid:
    """
    A sparse obstacle grid of hit centroids, bounded in memory.

    Cells live in fixed numpy arrays (``max_cells`` slots) addressed through a
    dict from the packed cell index, so a scan updates its cells with a few
    vector operations.

    :param params: the grid parameters.
    """

    def __init__(self, params: Optional[LineParams] = None):
        """Create an empty grid."""
        self.params = params if params is not None else LineParams()
        cap = int(self.params.max_cells)
        self._sum = np.zeros((cap, 2))
        self._n = np.zeros(cap)
        self._t = np.full(cap, -np.inf)
        self._key = np.zeros(cap, dtype=np.int64)
        self._used = np.zeros(cap, dtype=bool)
        self._index: dict[int, int] = {}
        self._free: list[int] = list(range(cap - 1, -1, -1))
        self._last_prune = -math.inf
        self.cleared = 0

    def __len__(self) -> int:
        """Return the number of occupied cells."""
        return len(self._index)

    def clear(self) -> None:
        """Forget every cell (after a heading correction or an odometry reset)."""
        if self._index:
            self._release(np.flatnonzero(self._used))
        self.cleared += 1

    def _release(self, slots: np.ndarray) -> None:
        index = self._index
        for k in self._key[slots].tolist():
            index.pop(k, None)
        self._used[slots] = False
        self._n[slots] = 0.0
        self._sum[slots] = 0.0
        self._free.extend(slots.tolist())

    def _keys(self, pts: np.ndarray) -> np.ndarray:
        ij = np.floor(pts / self.params.resolution).astype(np.int64)
        return (ij[:, 0] << 32) + (ij[:, 1] & 0xFFFFFFFF)

    def add_points(self, pts: np.ndarray, t: float) -> np.ndarray:
        """
        Add world hits (N, 2) (m) at time ``t`` (s); return the hit cells' centroids in order.

        The returned (M, 2) array lists every distinct cell hit, in the order of
        the input points (beam order), each cell's centroid over its recent hits.
        """
        pts = np.asarray(pts, dtype=float).reshape(-1, 2)
        self.prune(t)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        keys = self._keys(pts)
        edge = np.empty(keys.size + 1, dtype=bool)  # where a run of one cell starts, and the end
        edge[0] = edge[-1] = True
        np.not_equal(keys[1:], keys[:-1], out=edge[1:-1])
        bounds = edge.nonzero()[0]
        starts = bounds[:-1]
        sums = np.add.reduceat(pts, starts, axis=0)
        counts = (bounds[1:] - starts).astype(float)
        ukeys = keys[starts].tolist()
        slots = list(map(self._index.get, ukeys, itertools.repeat(-1, len(ukeys))))
        sl = np.asarray(slots, dtype=np.int64)
        if -1 in slots:
            missing = (sl < 0).nonzero()[0].tolist()
            self._new_slots(ukeys, slots, missing)
            sl[missing] = [slots[i] for i in missing]
        unique = len(set(slots)) == len(slots)
        if unique:  # the usual case: each cell once, a plain (same-valued) sum
            self._sum[sl] += sums
            self._n[sl] += counts
        else:  # a cell new in this scan hit twice (not consecutively)
            np.add.at(self._sum, sl, sums)
            np.add.at(self._n, sl, counts)
        self._t[sl] = t
        cap = self.params.max_hits_per_cell
        over = self._n[sl] > cap
        if over.any():
            o = sl[over]
            f = cap / self._n[o]
            self._sum[o] *= f[:, None]
            self._n[o] = cap
        if not unique:
            first = dict.fromkeys(slots)  # the distinct slots in the order first hit
            sl = np.fromiter(first, dtype=np.int64, count=len(first))
        return self._sum[sl] / self._n[sl, None]

    def _new_slots(self, ukeys: list, slots: list, missing: list) -> None:
        """Give the cells ``ukeys[i]`` not in the grid (``i`` in ``missing``) a free slot."""
        index = self._index
        if len(missing) <= len(self._free):  # no eviction: mark the new slots at once
            new, new_keys = [], []
            for i in missing:
                k = ukeys[i]
                sl = index.get(k, -1)  # >= 0: a cell new in this scan, hit twice
                if sl < 0:
                    sl = index[k] = self._free.pop()
                    new.append(sl)
                    new_keys.append(k)
                slots[i] = sl
            self._key[new] = new_keys
            self._used[new] = True
            return
        for i in missing:
            sl = index.get(ukeys[i], -1)
            if sl < 0:
                if not self._free:
                    self._evict()
                sl = self._free.pop()
                index[ukeys[i]] = sl
                self._key[sl] = ukeys[i]
                self._used[sl] = True
            slots[i] = sl

    def prune(self, t: float) -> None:
        """Clear cells not hit for ``cell_lifetime`` seconds (at most once per 0.5 s)."""
        if t - self._last_prune < 0.5 and t >= self._last_prune:
            return
        self._last_prune = t
        stale = self._used & ((self._t < t - self.params.cell_lifetime) | (self._t > t + 1.0))
        if np.any(stale):
            self._release(np.flatnonzero(stale))

    def _evict(self) -> None:
        """Free the stalest tenth of the cells (the grid is full)."""
        used = np.flatnonzero(self._used)
        n_drop = max(1, used.size // 10)
        self._release(used[np.argsort(self._t[used])[:n_drop]])

    def centroids(self) -> np.ndarray:
        """Return every cell's centroid (N, 2) (m)."""
        used = np.flatnonzero(self._used)
        return self._sum[used] / self._n[used, None]


def fit_line(pts: np.ndarray, method: str = 'total') -> tuple[np.ndarray, np.ndarray]:
    """
    Return (centroid, unit direction) of the least-squares line through (N, 2) points (m).

    ``total``: principal axis of the scatter (minimises perpendicular distances).
    ``ordinary``: regression of y on x (minimises vertical distances; undefined
    for a vertical line, where it returns the x axis direction of a degenerate fit).
    """
    c, u, _ = _fit(pts, method)
    return c, u


def _fit(pts: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (centroid, unit direction, points minus centroid) of :func:`fit_line`."""
    c, ux, uy, d = _fit_floats(pts, method)
    return c, np.array([ux, uy]), d


def _fit_floats(pts: np.ndarray, method: str) -> tuple[np.ndarray, float, float, np.ndarray]:
    """Return :func:`_fit` with the unit direction as two floats (cosine and sine)."""
    c = np.add.reduce(pts, axis=0) / pts.shape[0]  # = pts.sum(axis=0), without its wrapper
    d = pts - c
    if method == 'ordinary':
        sxx = float(d[:, 0] @ d[:, 0])
        slope = float(d[:, 0] @ d[:, 1]) / sxx if sxx > 1e-12 else 0.0
        norm = math.hypot(1.0, slope)
        return c, 1.0 / norm, slope / norm, d
    (sxx, sxy), (_, syy) = (d.T @ d).tolist()
    # closed-form principal direction of a 2x2 symmetric matrix
    phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    return c, math.cos(phi), math.sin(phi), d


def condition1(pts: np.ndarray, params: LineParams, t: float = 0.0) -> Optional[Line]:
    """
    Apply the seed's condition 1 loop to candidate cells (N, 2) (m); return the line or None.

    Seed 000, S11-S13: fit; drop when shorter than the preset length; pass when
    the variance of the cells' distances to the line is at most the preset;
    else remove the preset number of farthest cells and refit.
    """
    pts = np.asarray(pts, dtype=float)
    fewest = max(params.min_cells, 2)
    while pts.shape[0] >= fewest:
        c, ux, uy, d = _fit_floats(pts, params.fit_method)
        along = d @ np.array([ux, uy])
        dist = d @ np.array([-uy, ux])
        lo, hi = float(np.minimum.reduce(along)), float(np.maximum.reduce(along))
        if hi - lo < params.min_length:  # seed S11
            return None
        var = float(dist @ dist) / dist.size  # seed S12
        if var <= params.max_variance:  # endpoints c + lo u, c + hi u
            cx, cy = c.tolist()
            return _line_xy(cx + lo * ux, cy + lo * uy, cx + hi * ux, cy + hi * uy, t, var,
                            pts.shape[0])
        # seed S13: remove the farthest cells and refit
        keep = np.abs(dist).argsort()[:pts.shape[0] - params.remove_count]
        keep.sort()
        pts = pts[keep]
    return None


def split_segments(pts: np.ndarray, params: LineParams) -> list[np.ndarray]:
    """Split ordered cells (N, 2) (m) into candidate wall segments (gaps, then end-point fit)."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    return [pts[i:j] for i, j in _split(pts, params)]


def _split(pts: np.ndarray, params: LineParams,
           shortest: Optional[float] = None) -> list[tuple[int, int]]:
    """
    Return :func:`split_segments` as index ranges ``[i, j)`` of ``pts``.

    With ``shortest`` (m), a piece whose length along its cells is below it is
    dropped unsplit, with every segment it would have been split into.
    """
    min_cells = params.min_cells
    if pts.shape[0] < min_cells:
        return []
    step = pts[1:] - pts[:-1]
    steps = np.sqrt(np.add.reduce(step * step, axis=1))  # = np.linalg.norm(axis=1), op for op
    bounds = [0] + ((steps > params.max_gap).nonzero()[0] + 1).tolist() + [pts.shape[0]]
    path = None if shortest is None else np.concatenate(((0.0,), np.cumsum(steps))).tolist()
    out = []
    stack = [(i, j) for i, j in zip(bounds[:-1], bounds[1:]) if j - i >= min_cells]
    split = params.split_distance
    while stack:
        i, j = stack.pop()
        if path is not None and path[j - 1] - path[i] < shortest:
            continue
        seg = pts[i:j]
        a = seg[0]
        ax, ay = a.tolist()
        bx, by = seg[-1].tolist()
        cx, cy = bx - ax, by - ay
        norm = math.hypot(cx, cy)
        if norm < 1e-9:
            d = np.linalg.norm(seg - a, axis=1)
        else:
            d = (seg - a) @ np.array([-cy, cx])
            d /= norm
            np.abs(d, out=d)
        k = int(d.argmax())
        n = j - i
        if d[k] > split and 0 < k < n - 1:
            if k + 1 >= min_cells:
                stack.append((i, i + k + 1))
            if n - k >= min_cells:
                stack.append((i + k, j))
            continue
        out.append((i, j))
    return out


def extract_lines(pts: np.ndarray, params: LineParams, t: float = 0.0) -> list[Line]:
    """Return every line passing condition 1 among the segments of ordered cells (N, 2) (m)."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    # a segment's extent along any direction is at most its length along the cells, so one
    # shorter than min_length (by a margin far above rounding) fails S11 at its first fit;
    # so do the pieces it would be split into, which are shorter still
    lines = []
    for i, j in _split(pts, params, params.min_length - 1e-9):
        line = condition1(pts[i:j], params, t)
        if line is not None:
            lines.append(line)
    return lines
