# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Furnished home rooms for robot-vacuum scenarios, and a boustrophedon coverage path.

Layouts (all drawn with the scenario's own random generator, so a seed gives
one room):

- ``rect``: a rectangular room, a sofa and a cabinet against the walls, a
  small table (four thin legs) in the free space;
- ``chamfer``: a rectangle with one corner cut by a wall at 30-60 deg to the
  others (non-Manhattan), furniture against the walls;
- ``l_shape``: an L-shaped room (six walls), a bed in the larger part;
- ``slanted``: a trapezoid whose right wall leans by 30-60 deg from the
  vertical, plus a cabinet standing at 45 deg in a corner;
- ``parallel``: a rectangle with a low shelf running parallel to one wall
  0.6-1.0 m in front of it (two parallel lines close together: the classic
  wrong-wall trap).

Every layout returns the room outline (a polygon) and the obstacles; the
coverage path keeps ``margin`` metres from every segment.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from robot_calib.sim.world import World

LAYOUTS = ('rect', 'chamfer', 'l_shape', 'slanted', 'parallel')


@dataclass
class Room:
    """A room: outline polygon (N, 2) (m), obstacle polygons, world, facts for truth.json."""

    layout: str
    outline: np.ndarray
    obstacles: list
    world: World
    facts: dict = field(default_factory=dict)


def _box(cx: float, cy: float, w: float, h: float, yaw: float = 0.0) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    corners = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    return corners @ np.array([[c, s], [-s, c]]) + [cx, cy]


def make_room(layout: str, rng: np.random.Generator) -> Room:
    """Return a furnished room of ``layout`` (one of :data:`LAYOUTS`), drawn with ``rng``."""
    if layout not in LAYOUTS:
        raise ValueError(f'unknown room layout {layout!r}; known: {", ".join(LAYOUTS)}')
    W = float(rng.uniform(4.5, 7.0))
    D = float(rng.uniform(3.5, 5.5))
    slant = math.radians(float(rng.uniform(30.0, 60.0)))
    obstacles = []
    facts = {'width': W, 'depth': D}
    if layout == 'rect':
        outline = np.array([[0, 0], [W, 0], [W, D], [0, D]], float)
        obstacles.append(_box(1.4, D - 0.5, 2.0, 0.9))        # sofa against the top wall
        obstacles.append(_box(W - 0.35, 0.5, 0.6, 0.8))       # cabinet in a corner
        tx, ty = W * 0.6, D * 0.45
        for dx in (-0.4, 0.4):
            for dy in (-0.3, 0.3):
                a = np.linspace(0, 2 * math.pi, 6, endpoint=False)
                obstacles.append(np.column_stack((tx + dx + 0.03 * np.cos(a),
                                                  ty + dy + 0.03 * np.sin(a))))
    elif layout == 'chamfer':
        a = 2.0 * math.cos(slant)
        b = 2.0 * math.sin(slant)
        outline = np.array([[0, 0], [W, 0], [W, D - b], [W - a, D], [0, D]], float)
        obstacles.append(_box(0.5, D / 2, 0.8, 1.8))          # bookcase on the left wall
        facts['slanted_wall_deg'] = math.degrees(math.atan2(b, -a)) % 180.0
    elif layout == 'l_shape':
        cw, cd = W * float(rng.uniform(0.35, 0.5)), D * float(rng.uniform(0.35, 0.5))
        outline = np.array([[0, 0], [W, 0], [W, D - cd], [W - cw, D - cd], [W - cw, D],
                            [0, D]], float)
        obstacles.append(_box(1.1, 1.0, 1.6, 1.4))            # bed in the corner
    elif layout == 'slanted':
        off = D / math.tan(slant)
        outline = np.array([[0, 0], [W, 0], [W - off, D], [0, D]], float)
        if W - off < 3.0:
            outline[1, 0] = off + 3.0
            outline[2, 0] = 3.0
        obstacles.append(_box(0.6, 0.6, 0.6, 0.6, math.pi / 4))  # cabinet at 45 deg
        facts['slanted_wall_deg'] = math.degrees(math.atan2(D, -off)) % 180.0
    else:  # parallel
        outline = np.array([[0, 0], [W, 0], [W, D], [0, D]], float)
        gap = float(rng.uniform(0.6, 1.0))
        obstacles.append(_box(W / 2, D - gap - 0.15, W * 0.45, 0.3))  # shelf parallel to a wall
        facts['shelf_gap'] = gap
    world = World().add_polygon(outline)
    for ob in obstacles:
        world.add_polygon(ob)
    return Room(layout, outline, obstacles, world, facts)


def inside(poly: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Return whether points (m) are inside polygon (N, 2) (even-odd rule)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    res = np.zeros(np.broadcast(x, y).shape, dtype=bool)
    n = poly.shape[0]
    for i in range(n):
        x0, y0 = poly[i]
        x1, y1 = poly[(i + 1) % n]
        cond = (y0 > y) != (y1 > y)
        with np.errstate(divide='ignore', invalid='ignore'):
            xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        res ^= cond & (x < xc)
    return res


def _segment_distance(world: World, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    seg = world.segments
    a = seg[:, :2]
    ab = seg[:, 2:] - a
    p = np.stack((px, py), axis=-1)[:, None, :]
    den = np.maximum(np.einsum('mi,mi->m', ab, ab), 1e-12)
    t = np.clip(np.einsum('nmi,mi->nm', p - a, ab) / den, 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.linalg.norm(p - closest, axis=-1).min(axis=1)


def free(room: Room, px, py, margin: float) -> np.ndarray:
    """Return whether points (m) are in the room, off obstacles and ``margin`` from walls."""
    px = np.atleast_1d(np.asarray(px, dtype=float))
    py = np.atleast_1d(np.asarray(py, dtype=float))
    ok = inside(room.outline, px, py)
    for ob in room.obstacles:
        ok &= ~inside(ob, px, py)
    ok &= _segment_distance(room.world, px, py) > margin
    return ok


def _segment_free(room: Room, a, b, margin: float) -> bool:
    n = max(2, int(math.hypot(b[0] - a[0], b[1] - a[1]) / 0.05))
    s = np.linspace(0.0, 1.0, n)
    return bool(np.all(free(room, a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), margin)))


def boustrophedon(room: Room, lane: float = 0.3, margin: float = 0.25,
                  axis: int = 0) -> list:
    """
    Return coverage waypoints (x, y) (m): lanes along x (``axis=0``) or y, snaking.

    Each lane is the longest free run at that offset; a lane whose connection
    from the previous lane end is blocked is skipped.
    """
    lo = room.outline.min(axis=0)
    hi = room.outline.max(axis=0)
    other = 1 - axis
    offsets = np.arange(lo[other] + margin + 0.01, hi[other] - margin, lane)
    along = np.arange(lo[axis] + 0.01, hi[axis], 0.05)
    points: list = []
    flip = False
    for off in offsets:
        if axis == 0:
            ok = free(room, along, np.full(along.size, off), margin)
        else:
            ok = free(room, np.full(along.size, off), along, margin)
        if not np.any(ok):
            continue
        edges = np.diff(np.concatenate(([0], ok.astype(int), [0])))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
        k = int(np.argmax(ends - starts))
        if ends[k] - starts[k] < 4:
            continue
        run = [along[starts[k]], along[ends[k]]]
        if flip:
            run = run[::-1]
        pts = [(r, off) if axis == 0 else (off, r) for r in run]
        if points and not _segment_free(room, points[-1], pts[0], margin * 0.8):
            continue
        points.extend(pts)
        flip = not flip
    return points


def route(room: Room, a, b, margin: float, step: float = 0.1) -> list | None:
    """
    Return waypoints (x, y) (m) leading from ``a`` to ``b`` through free space, ``b`` last.

    Straight when the segment is free; otherwise the shortest path over a grid
    of ``step`` metres (8-connected, every cell ``margin`` from walls and
    furniture), shortened where a straight segment is free. None when ``b``
    cannot be reached or is not free itself.
    """
    a, b = (float(a[0]), float(a[1])), (float(b[0]), float(b[1]))
    if not free(room, b[0], b[1], margin)[0]:
        return None
    if _segment_free(room, a, b, margin):
        return [b]
    lo = room.outline.min(axis=0)
    hi = room.outline.max(axis=0)
    xs = np.arange(lo[0], hi[0] + step, step)
    ys = np.arange(lo[1], hi[1] + step, step)
    gx, gy = np.meshgrid(xs, ys, indexing='ij')
    ok = free(room, gx.ravel(), gy.ravel(), margin).reshape(gx.shape)

    def nearest_free(p):
        d = np.where(ok, (gx - p[0]) ** 2 + (gy - p[1]) ** 2, np.inf)
        k = np.unravel_index(int(np.argmin(d)), d.shape)
        return k if np.isfinite(d[k]) else None

    start, goal = nearest_free(a), nearest_free(b)
    if start is None or goal is None:
        return None
    came = {start: None}
    frontier = [start]
    while frontier and goal not in came:  # breadth-first: the cells are few (a room)
        nxt = []
        for i, j in frontier:
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    c = (i + di, j + dj)
                    if 0 <= c[0] < ok.shape[0] and 0 <= c[1] < ok.shape[1] and ok[c] \
                            and c not in came:
                        came[c] = (i, j)
                        nxt.append(c)
        frontier = nxt
    if goal not in came:
        return None
    cells = [goal]
    while came[cells[-1]] is not None:
        cells.append(came[cells[-1]])
    path = [a] + [(float(gx[c]), float(gy[c])) for c in reversed(cells)] + [b]
    out, i = [], 0
    while i < len(path) - 1:  # keep the farthest point reachable in a straight line
        j = len(path) - 1
        while j > i + 1 and not _segment_free(room, path[i], path[j], margin):
            j -= 1
        out.append(path[j])
        i = j
    return out
