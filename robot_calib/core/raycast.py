# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Ray casting in an occupancy grid: the ranges an ideal 2D lidar reads in a map.

The grid is square cells of side ``resolution`` (m); cell ``(ix, iy)`` covers
``[x0 + ix res, x0 + (ix + 1) res) x [y0 + iy res, ...)`` in the map frame
(``occupied[iy, ix]``, row 0 at the bottom, as map_server's ``origin`` is the
lower-left pixel). A map frame turned by ``origin_yaw`` (rad) is handled by
turning the rays into it.

:func:`raycast` walks every ray's cells with the grid traversal of Amanatides
and Woo ("A fast voxel traversal algorithm for ray tracing", Eurographics 1987),
all rays at once in numpy: each pass moves every live ray one cell along the
axis whose next boundary is nearer; a ray ends at the entry of its first
occupied cell, past ``range_max`` or outside the grid (inf). Rays still live
are packed together every few passes, so the cost is the number of cells
actually crossed.

The range in the hit cell is the projection on the ray of the cell's surface
point (its centre, as AMCL's ``map_calc_range`` takes the distance to the hit
cell's centre; or, for a grid built from scan end points, their mean in the
cell), clipped to the ray's span inside the cell. Taking the entry face
instead would make every range short by half a cell over the cosine of the
incidence.

:func:`grid_from_points` builds a grid from scan end points (hits counted per
cell; a cell is occupied with ``min_hits`` or more; their mean point kept).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np


@dataclass
class OccupancyGrid:
    """An occupancy grid: ``occupied[iy, ix]`` (bool), cell side (m), origin (m, m, rad)."""

    occupied: np.ndarray
    resolution: float
    origin_x: float = 0.0
    origin_y: float = 0.0
    origin_yaw: float = 0.0
    points: Optional[np.ndarray] = None
    """(H, W, 2) surface point of each cell (m from the origin, map frame); None: centres."""
    weights: Optional[np.ndarray] = None
    """(H, W) end points per cell: with them a hit is the weighted mean of the hit cell and
    the next cell along the ray when that is occupied too (a wall blurred over two cells)."""

    def to_map(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return points (m, world frame) in the map frame relative to the grid origin."""
        dx, dy = np.asarray(x, float) - self.origin_x, np.asarray(y, float) - self.origin_y
        if self.origin_yaw == 0.0:
            return dx, dy
        c, s = math.cos(self.origin_yaw), math.sin(self.origin_yaw)
        return c * dx + s * dy, -s * dx + c * dy


PACK_EVERY = 8
"""Passes between packings of the rays still live."""
WALL_DEPTH = 5
"""Cells along a ray (the hit one included) whose end points a hit averages (weighted grids)."""


def raycast(grid: OccupancyGrid, ox: np.ndarray, oy: np.ndarray, angles: np.ndarray,
            range_max: float = math.inf, chunk: int = 1 << 19) -> np.ndarray:
    """
    Return the range (m) along each ray to the first occupied cell, inf when none.

    :param grid: the map
    :param ox: ray origins x (m, world frame), broadcastable with ``angles``
    :param oy: ray origins y (m)
    :param angles: ray directions (rad, world frame)
    :param range_max: rays are followed this far (m); farther hits are inf
    :param chunk: rays handled per batch (bounds the memory)
    """
    ox, oy, angles = np.broadcast_arrays(np.asarray(ox, float), np.asarray(oy, float),
                                         np.asarray(angles, float))
    shape = angles.shape
    px, py = grid.to_map(ox.ravel(), oy.ravel())
    ang = angles.ravel() - grid.origin_yaw
    out = np.full(ang.size, np.inf)
    occ = np.ascontiguousarray(grid.occupied, dtype=bool)
    if occ.size == 0:
        return out.reshape(shape)
    limit = range_max if math.isfinite(range_max) else \
        grid.resolution * (occ.shape[0] + occ.shape[1]) * 2.0
    pts = None
    if grid.points is not None:
        pts = np.asarray(grid.points, float).reshape(-1, 2) / grid.resolution
    wts = None if grid.weights is None or pts is None else \
        np.asarray(grid.weights, float).ravel()
    for i in range(0, ang.size, chunk):
        sl = slice(i, i + chunk)
        out[sl] = _cast(occ, grid.resolution, px[sl], py[sl], ang[sl], limit, pts, wts)
    out[out > range_max] = np.inf
    return out.reshape(shape)


def _cast(occ: np.ndarray, res: float, px: np.ndarray, py: np.ndarray, ang: np.ndarray,
          limit: float, pts: Optional[np.ndarray],
          wts: Optional[np.ndarray] = None) -> np.ndarray:
    """Return the ranges (m) of rays from (px, py) (m, grid frame) along ``ang`` (rad)."""
    h, w = occ.shape
    flat = occ.ravel()
    out = np.full(ang.size, np.inf)
    dx, dy = np.cos(ang), np.sin(ang)
    gx, gy = px / res, py / res  # in cells
    with np.errstate(divide='ignore', invalid='ignore'):
        adx, ady = np.abs(dx), np.abs(dy)
        # distance (cells) between boundaries along x and y
        tdx = np.where(adx > 1e-12, 1.0 / adx, np.inf)
        tdy = np.where(ady > 1e-12, 1.0 / ady, np.inf)
        # a ray from outside the grid starts where it enters it (slab test)
        tx0, tx1 = (0.0 - gx) / dx, (w - gx) / dx
        ty0, ty1 = (0.0 - gy) / dy, (h - gy) / dy
    t_lo = np.maximum(np.fmax(np.minimum(tx0, tx1), np.minimum(ty0, ty1)), 0.0)
    t_hi = np.fmin(np.maximum(tx0, tx1), np.maximum(ty0, ty1))
    t_lo = np.where((adx > 1e-12) | ((gx >= 0) & (gx < w)), t_lo, np.inf)
    t_lo = np.where((ady > 1e-12) | ((gy >= 0) & (gy < h)), t_lo, np.inf)
    never = ~(t_lo <= t_hi)
    t0 = np.where(never, 0.0, t_lo)
    qx = gx + np.where(t0 > 0, t0 + 1e-9, 0.0) * dx
    qy = gy + np.where(t0 > 0, t0 + 1e-9, 0.0) * dy
    ix, iy = np.floor(qx).astype(np.int64), np.floor(qy).astype(np.int64)
    entering = t0 > 0
    ix[entering] = np.clip(ix[entering], 0, w - 1)
    iy[entering] = np.clip(iy[entering], 0, h - 1)
    sx = np.where(dx > 0, 1, -1).astype(np.int64)
    sy = np.where(dy > 0, 1, -1).astype(np.int64)
    with np.errstate(invalid='ignore'):
        tmx = np.where(dx > 0, (ix + 1 - qx), (qx - ix)) * tdx + t0
        tmy = np.where(dy > 0, (iy + 1 - qy), (qy - iy)) * tdy + t0
    tmx = np.where(np.isfinite(tmx), tmx, np.inf)
    tmy = np.where(np.isfinite(tmy), tmy, np.inf)
    lim = limit / res
    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h) & ~never & (t0 <= lim)
    start_occ = np.zeros(ang.size, dtype=bool)
    start_occ[inside] = flat[iy[inside] * w + ix[inside]]
    out[start_occ] = t0[start_occ] * res
    never |= ~inside
    idx = np.flatnonzero(~start_occ & ~never)
    state = [a[idx] for a in (ix, iy, sx, sy, tmx, tmy, tdx, tdy)]
    while idx.size:
        ix, iy, sx, sy, tmx, tmy, tdx, tdy = state
        alive = np.ones(idx.size, dtype=bool)
        for _ in range(PACK_EVERY):
            step_x = tmx < tmy
            t = np.where(step_x, tmx, tmy)
            ix = np.where(step_x, ix + sx, ix)
            iy = np.where(step_x, iy, iy + sy)
            tmx = np.where(step_x, tmx + tdx, tmx)
            tmy = np.where(step_x, tmy, tmy + tdy)
            ok = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h) & (t <= lim)
            hit = np.zeros(idx.size, dtype=bool)
            hit[ok] = flat[(iy[ok] * w + ix[ok])]
            hit &= alive
            if hit.any():
                j = idx[hit]
                t_out = np.minimum(tmx[hit], tmy[hit])
                r = _in_cell(pts, w, ix[hit], iy[hit], t[hit], t_out, gx[j], gy[j], dx[j],
                             dy[j])
                if wts is not None:
                    r = _with_next(occ, pts, wts, ix[hit], iy[hit], sx[hit], sy[hit],
                                   tmx[hit], tmy[hit], tdx[hit], tdy[hit], t[hit], r,
                                   (gx[j], gy[j], dx[j], dy[j]))
                out[j] = r * res
            alive &= ok & ~hit
        keep = np.flatnonzero(alive)
        idx = idx[keep]
        state = [a[keep] for a in (ix, iy, sx, sy, tmx, tmy, tdx, tdy)]
    return out


def _in_cell(pts: Optional[np.ndarray], w: int, ix: np.ndarray, iy: np.ndarray,
             t_in: np.ndarray, t_out: np.ndarray, gx: np.ndarray, gy: np.ndarray,
             dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Return the range (cells) to the hit cells' surface points, within their span."""
    if pts is None:
        cx, cy = ix + 0.5, iy + 0.5
    else:
        cx, cy = pts[iy * w + ix, 0], pts[iy * w + ix, 1]
    proj = (cx - gx) * dx + (cy - gy) * dy
    return np.clip(proj, t_in, np.maximum(t_out, t_in))


def _with_next(occ: np.ndarray, pts: np.ndarray, wts: np.ndarray, ix: np.ndarray,
               iy: np.ndarray, sx: np.ndarray, sy: np.ndarray, tmx: np.ndarray,
               tmy: np.ndarray, tdx: np.ndarray, tdy: np.ndarray, t_in: np.ndarray,
               r: np.ndarray, ray: tuple) -> np.ndarray:
    """
    Return hits (cells) averaged over the run of occupied cells that follows along the ray.

    Up to :data:`WALL_DEPTH` cells in all, weighted by their end points and
    stopping at the first free cell: a wall blurred over a few cells by noise
    or pose error is placed at the mean of its points, not at its near edge.
    """
    h, w = occ.shape
    flat = occ.ravel()
    num = wts[iy * w + ix] * r
    den = wts[iy * w + ix].copy()
    t_end = np.minimum(tmx, tmy)
    going = np.ones(r.size, dtype=bool)
    ix, iy, tmx, tmy = ix.copy(), iy.copy(), tmx.copy(), tmy.copy()
    for _ in range(WALL_DEPTH - 1):
        step_x = tmx < tmy
        t_next = np.minimum(tmx, tmy)
        ix = np.where(step_x, ix + sx, ix)
        iy = np.where(step_x, iy, iy + sy)
        tmx = np.where(step_x, tmx + tdx, tmx)
        tmy = np.where(step_x, tmy, tmy + tdy)
        ok = going & (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        occ_next = np.zeros(r.size, dtype=bool)
        occ_next[ok] = flat[iy[ok] * w + ix[ok]]
        going &= occ_next
        if not going.any():
            break
        k = np.flatnonzero(going)
        t_out = np.minimum(tmx[k], tmy[k])
        rk = _in_cell(pts, w, ix[k], iy[k], t_next[k], t_out, *(a[k] for a in ray))
        wk = wts[iy[k] * w + ix[k]]
        num[k] += wk * rk
        den[k] += wk
        t_end[k] = t_out
    return np.clip(num / np.maximum(den, 1e-300), t_in, t_end)


def grid_from_points(x: np.ndarray, y: np.ndarray, resolution: float, min_hits: int = 2,
                     margin: float = 1.0) -> OccupancyGrid:
    """
    Return a grid (map frame = world frame) with the cells hit ``min_hits`` times occupied.

    :param x: end points x (m), NaN ignored
    :param y: end points y (m)
    :param resolution: cell side (m)
    :param min_hits: hits that make a cell occupied (>= 2 keeps single stray returns out)
    :param margin: free border around the points (m)
    """
    x, y = np.asarray(x, float).ravel(), np.asarray(y, float).ravel()
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size == 0:
        return OccupancyGrid(np.zeros((1, 1), dtype=bool), resolution)
    x0 = math.floor((x.min() - margin) / resolution) * resolution
    y0 = math.floor((y.min() - margin) / resolution) * resolution
    w = int(math.ceil((x.max() + margin - x0) / resolution)) + 1
    h = int(math.ceil((y.max() + margin - y0) / resolution)) + 1
    ix = np.floor((x - x0) / resolution).astype(np.int64)
    iy = np.floor((y - y0) / resolution).astype(np.int64)
    cell = iy * w + ix
    counts = np.bincount(cell, minlength=w * h)
    with np.errstate(invalid='ignore', divide='ignore'):
        mean = np.stack((np.bincount(cell, x - x0, w * h) / counts,
                         np.bincount(cell, y - y0, w * h) / counts), axis=1)
    every = np.arange(w * h)
    centre = np.stack(((every % w + 0.5) * resolution, (every // w + 0.5) * resolution), axis=1)
    mean = np.where(counts[:, None] > 0, mean, centre)
    occ = (counts >= max(1, int(min_hits))).reshape(h, w)
    return OccupancyGrid(occ, resolution, x0, y0, 0.0, mean.reshape(h, w, 2),
                         counts.reshape(h, w).astype(float))


def scan_end_points(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, angles: np.ndarray,
                    ranges: np.ndarray, range_min: float = 0.0,
                    range_max: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the world end points (m) of scans (S, B) taken from laser poses (S,) (m, m, rad).

    Beams outside ``[range_min, range_max)`` or not finite give NaN.
    """
    r = np.asarray(ranges, float)
    ok = np.isfinite(r) & (r >= range_min) & (r < range_max)
    r = np.where(ok, r, np.nan)
    a = np.asarray(yaw, float)[:, None] + np.asarray(angles, float)[None, :]
    return (np.asarray(x, float)[:, None] + r * np.cos(a),
            np.asarray(y, float)[:, None] + r * np.sin(a))


def grid_from_segments(segments: np.ndarray, resolution: float,
                       margin: float = 1.0) -> OccupancyGrid:
    """
    Return a grid with the cells crossed by line segments (N, 4: x0 y0 x1 y1, m) occupied.

    Each segment is sampled every quarter cell; the cells' surface points are
    the mean of their samples (on the segments), so a cast hits the line.
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    n = np.maximum(2, np.ceil(length / (0.25 * resolution)).astype(int) + 1)
    u = np.concatenate([np.linspace(0.0, 1.0, k) for k in n])
    s = np.repeat(np.arange(seg.shape[0]), n)
    x = seg[s, 0] + u * (seg[s, 2] - seg[s, 0])
    y = seg[s, 1] + u * (seg[s, 3] - seg[s, 1])
    grid = grid_from_points(x, y, resolution, 1, margin)
    grid.weights = None
    return grid
