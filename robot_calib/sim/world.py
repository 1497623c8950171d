# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A 2D world of wall and obstacle segments, terrain features, and vectorised ray casting.

Coordinates are the world frame (m, rad; x east, y north, z up). Walls and
obstacles are line segments; polygons and circles are stored as their edges.
:meth:`World.raycast` intersects many rays with all segments at once (numpy
broadcasting over rays x segments, in chunks), which is what makes the lidar
fast. Terrain (ramps, bumps, steps) only changes the height ``z(x, y)`` the
wheels roll on; it is invisible to the lidar (a 2D scanner above the floor).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Optional

import numpy as np


@dataclass
class Ramp:
    """
    A ramp: height rises linearly from 0 to ``height`` (m) over ``length`` (m).

    The ramp starts on the line through ``(x, y)`` perpendicular to direction
    ``yaw`` (rad), spans ``width`` (m) across, and stays at ``height`` for
    ``plateau`` (m) before an equally long descent (``descend=True``) or ending.
    """

    x: float
    y: float
    yaw: float
    length: float
    height: float
    width: float = 100.0
    plateau: float = 0.0
    descend: bool = True

    def height_at(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Return the terrain height (m) of this feature at points (m)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        u = (px - self.x) * c + (py - self.y) * s
        w = -(px - self.x) * s + (py - self.y) * c
        up = np.clip(u / self.length, 0.0, 1.0)
        h = up
        if self.descend:
            down = np.clip((u - self.length - self.plateau) / self.length, 0.0, 1.0)
            h = up - down
        return self.height * h * (np.abs(w) <= self.width / 2)


@dataclass
class Bump:
    """A smooth bump (raised cosine) of ``height`` (m) and ``radius`` (m) at (x, y)."""

    x: float
    y: float
    radius: float
    height: float

    def height_at(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Return the terrain height (m) of this feature at points (m)."""
        r = np.hypot(px - self.x, py - self.y) / self.radius
        return np.where(r < 1.0, 0.5 * self.height * (1.0 + np.cos(np.pi * np.minimum(r, 1.0))),
                        0.0)


@dataclass
class Step:
    """
    A step of ``height`` (m) on the half plane ahead of the line through (x, y).

    The half plane is the side direction ``yaw`` (rad) points to; the edge is
    smoothed over ``edge`` (m) so that the attitude stays differentiable.
    """

    x: float
    y: float
    yaw: float
    height: float
    edge: float = 0.02

    def height_at(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Return the terrain height (m) of this feature at points (m)."""
        u = (px - self.x) * math.cos(self.yaw) + (py - self.y) * math.sin(self.yaw)
        s = np.clip(u / max(self.edge, 1e-6) + 0.5, 0.0, 1.0)
        return self.height * s * s * (3.0 - 2.0 * s)


@dataclass
class World:
    """Walls/obstacles as segments (M, 4) ``[x0, y0, x1, y1]`` (m), plus terrain features."""

    segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    terrain: list = field(default_factory=list)

    # -- building ------------------------------------------------------------------------
    def add_segment(self, x0: float, y0: float, x1: float, y1: float) -> 'World':
        """Add one wall segment (m); returns self for chaining."""
        self.segments = np.vstack((self.segments, [[x0, y0, x1, y1]]))
        return self

    def add_polyline(self, points, closed: bool = False) -> 'World':
        """Add the edges of a polyline (or closed polygon) through (N, 2) points (m)."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        if closed:
            p = np.vstack((p, p[:1]))
        self.segments = np.vstack((self.segments, np.hstack((p[:-1], p[1:]))))
        return self

    def add_polygon(self, points) -> 'World':
        """Add a closed polygon (an obstacle, or the room outline) through (N, 2) points (m)."""
        return self.add_polyline(points, closed=True)

    def add_box(self, cx: float, cy: float, width: float, height: float,
                yaw: float = 0.0) -> 'World':
        """Add a rectangle centred at (cx, cy) (m), ``width`` along x before rotation by yaw."""
        c, s = math.cos(yaw), math.sin(yaw)
        hw, hh = width / 2, height / 2
        corners = np.array([[-hw, -hh], [hw, -hh], [hw, hh], [-hw, hh]])
        rot = np.array([[c, -s], [s, c]])
        return self.add_polygon(corners @ rot.T + [cx, cy])

    def add_circle(self, cx: float, cy: float, radius: float, sides: int = 16) -> 'World':
        """Add a circular obstacle (a regular polygon of ``sides`` edges) (m)."""
        a = np.linspace(0.0, 2 * math.pi, sides, endpoint=False)
        return self.add_polygon(np.column_stack((cx + radius * np.cos(a),
                                                 cy + radius * np.sin(a))))

    def add_room(self, width: float, depth: float, x0: float = 0.0, y0: float = 0.0) -> 'World':
        """Add the four walls of a rectangular room [x0, x0 + width] x [y0, y0 + depth] (m)."""
        return self.add_polygon([[x0, y0], [x0 + width, y0], [x0 + width, y0 + depth],
                                 [x0, y0 + depth]])

    def add_terrain(self, feature) -> 'World':
        """
        Add a terrain feature: a :class:`Ramp`, :class:`Bump` or :class:`Step`.

        Any object with a method ``height_at(px, py)`` returning heights (m) works.
        """
        self.terrain.append(feature)
        return self

    # -- queries -------------------------------------------------------------------------
    def height(self, px, py) -> np.ndarray:
        """Return the terrain z (m) at points (m), 0 where there is no feature."""
        px = np.asarray(px, dtype=float)
        py = np.asarray(py, dtype=float)
        z = np.zeros(np.broadcast(px, py).shape)
        for feature in self.terrain:
            z = z + feature.height_at(px, py)
        return z

    def raycast(self, ox, oy, angles, max_range: float = np.inf,
                chunk: int = 1 << 16) -> np.ndarray:
        """
        Return the distance (m) along each ray to the nearest segment, inf when none.

        :param ox: ray origins x (m), any shape broadcastable with ``angles``
        :param oy: ray origins y (m)
        :param angles: ray directions (rad, world frame)
        :param max_range: hits beyond this distance (m) count as no hit (inf)
        :param chunk: rays x segments evaluated per numpy pass (memory bound)
        """
        ox, oy, angles = np.broadcast_arrays(np.asarray(ox, float), np.asarray(oy, float),
                                             np.asarray(angles, float))
        shape = angles.shape
        ox, oy, angles = ox.ravel(), oy.ravel(), angles.ravel()
        out = np.full(ox.size, np.inf)
        seg = self.segments
        if seg.shape[0] == 0 or ox.size == 0:
            return out.reshape(shape)
        f4 = np.float32
        ex = (seg[:, 2] - seg[:, 0]).astype(f4)
        ey = (seg[:, 3] - seg[:, 1]).astype(f4)
        dx, dy = np.cos(angles).astype(f4), np.sin(angles).astype(f4)
        step = max(1, chunk // seg.shape[0])
        for i in range(0, ox.size, step):
            sl = slice(i, i + step)
            # float32 arithmetic relative to a local origin (exact to ~1e-5 m, 2x faster)
            rx, ry = ox[i], oy[i]
            px = (seg[:, 0] - rx).astype(f4)
            py = (seg[:, 1] - ry).astype(f4)
            wx = px - (ox[sl] - rx).astype(f4)[:, None]
            wy = py - (oy[sl] - ry).astype(f4)[:, None]
            ddx, ddy = dx[sl, None], dy[sl, None]
            # ray o + t d meets segment p + u e: t = (w x e) / (d x e), u = (w x d) / (d x e)
            den = ddx * ey
            den -= ddy * ex
            tn = wx * ey
            tn -= wy * ex
            un = wx * ddy
            un -= wy * ddx
            with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
                inv = np.reciprocal(den, out=den)
                tn *= inv
                un *= inv
                bad = (un < 0) | (un > 1) | ~(tn > 0)
            tn[bad] = np.inf
            out[sl] = tn.min(axis=1)
        out[out > max_range] = np.inf
        return out.reshape(shape)

    def raycast_fan(self, ox: np.ndarray, oy: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """
        Return ranges (m, inf: no hit) of S fans of B rays, as :meth:`raycast` but faster.

        Row s of ``ox``, ``oy``, ``angles`` (S, B) is one scan: ray origins
        that move little (a rotating lidar on a moving robot) and directions
        (rad) increasing along the row, spanning at most 2 pi plus a little.
        Each segment is tested only against the beams inside its angular
        interval seen from the scan's mean origin, widened by the largest
        angle the origin's motion can change (``asin(d_max / distance)``), so
        the result is exact while most ray x segment pairs are never formed.
        Falls back to :meth:`raycast` when a row is not increasing.
        """
        ox, oy, angles = (np.asarray(a, dtype=float) for a in (ox, oy, angles))
        seg = self.segments
        n_s, n_b = angles.shape
        if seg.shape[0] == 0 or angles.size == 0:
            return np.full(angles.shape, np.inf)
        if n_b < 2 or np.any(np.diff(angles, axis=1) <= 0) or \
                np.any(angles[:, -1] - angles[:, 0] > 2.5 * math.pi):
            return self.raycast(ox, oy, angles)
        two_pi = 2.0 * math.pi
        cx, cy = ox.mean(axis=1), oy.mean(axis=1)
        dmax = np.sqrt(np.max((ox - cx[:, None]) ** 2 + (oy - cy[:, None]) ** 2, axis=1))
        x0, y0, x1, y1 = (seg[:, k][None, :] for k in range(4))
        ax = np.arctan2(y0 - cy[:, None], x0 - cx[:, None])
        bx = np.arctan2(y1 - cy[:, None], x1 - cx[:, None])
        dab = np.mod(bx - ax + math.pi, two_pi) - math.pi
        half = 0.5 * np.abs(dab)
        centre = ax + 0.5 * dab
        # distance from the mean origin to each segment (S, M)
        ex, ey = x1 - x0, y1 - y0
        u = np.clip(((cx[:, None] - x0) * ex + (cy[:, None] - y0) * ey)
                    / np.maximum(ex * ex + ey * ey, 1e-18), 0.0, 1.0)
        dist = np.hypot(x0 + u * ex - cx[:, None], y0 + u * ey - cy[:, None])
        with np.errstate(divide='ignore', invalid='ignore'):
            margin = np.arcsin(np.clip(dmax[:, None] / dist, 0.0, 1.0))
        width = half + margin + 1e-9
        full = (width >= math.pi) | (dist <= dmax[:, None]) | ~np.isfinite(width)
        phi0 = angles[:, :1]
        off = 8.0 * math.pi
        rows = np.arange(n_s)[:, None] * off
        key = (angles - phi0 + rows).ravel()
        lo = np.mod(centre - width - phi0, two_pi)  # in [0, 2 pi) from the row start
        starts, stops = [], []
        for shift in (-two_pi, 0.0, two_pi):
            q_lo = np.where(full, -1.0, lo + shift) + rows
            q_hi = np.where(full, off / 2, lo + shift + 2 * width) + rows
            starts.append(np.searchsorted(key, q_lo.ravel(), 'left'))
            stops.append(np.searchsorted(key, q_hi.ravel(), 'right'))
            if shift == 0.0:
                full_flat = full.ravel()
        start = np.concatenate(starts)
        stop = np.concatenate(stops)
        seg_of = np.tile(np.tile(np.arange(seg.shape[0]), n_s), 3)
        keep = stop > start
        # a full row is covered once by the shift-0 query only
        keep[:full_flat.size][full_flat] = False
        keep[2 * full_flat.size:][full_flat] = False
        start, stop, seg_of = start[keep], stop[keep], seg_of[keep]
        counts = stop - start
        total = int(counts.sum())
        out = np.full(n_s * n_b, np.inf)
        if total == 0:
            return out.reshape(n_s, n_b)
        first = np.repeat(start - np.concatenate(([0], np.cumsum(counts)[:-1])), counts)
        beam = first + np.arange(total)
        sidx = np.repeat(seg_of, counts)
        ox_f, oy_f, an_f = ox.ravel()[beam], oy.ravel()[beam], angles.ravel()[beam]
        dx, dy = np.cos(an_f), np.sin(an_f)
        px, py = seg[sidx, 0], seg[sidx, 1]
        sx, sy = seg[sidx, 2] - px, seg[sidx, 3] - py
        wx, wy = px - ox_f, py - oy_f
        # ray o + t d meets segment p + u s: t = (w x s) / (d x s), u = (w x d) / (d x s)
        den = dx * sy - dy * sx
        with np.errstate(divide='ignore', invalid='ignore'):
            t = (wx * sy - wy * sx) / den
            uu = (wx * dy - wy * dx) / den
            ok = (uu >= 0.0) & (uu <= 1.0) & (t > 0.0)
        np.minimum.at(out, beam[ok], t[ok])
        return out.reshape(n_s, n_b)

    def nearest_distance(self, x: float, y: float,
                         direction: Optional[float] = None) -> float:
        """Return the distance (m) from (x, y) to the nearest segment (or along ``direction``)."""
        if direction is not None:
            return float(self.raycast(x, y, direction))
        seg = self.segments
        if seg.shape[0] == 0:
            return math.inf
        p = np.array([x, y])
        a, b = seg[:, :2], seg[:, 2:]
        ab = b - a
        t = np.clip(np.einsum('ij,ij->i', p - a, ab) / np.maximum(
            np.einsum('ij,ij->i', ab, ab), 1e-18), 0.0, 1.0)
        d = a + ab * t[:, None] - p
        return float(np.sqrt(np.min(np.einsum('ij,ij->i', d, d))))
