# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The keyframe map both variants keep, and the similarity check of loop detection.

Keyframes sit in a spatial grid (``cell_size`` m): at most ``max_per_cell``
per cell (the oldest are kept) and ``max_keyframes`` overall, so memory
grows with the area covered, not with the time driven. A keyframe that does
not fit is kept only as the reference of the local (kidnap) check, under
id -1.
"""

from __future__ import annotations

from collections import defaultdict
import math
from typing import Optional, Sequence, TYPE_CHECKING

import numpy as np
from robot_calib.core.geometry import se2_apply
from robot_calib.methods.loop_closure_correction.common import Keyframe
from robot_calib.methods.loop_closure_correction.params import DetectionParams, KeyframeParams

if TYPE_CHECKING:  # the KD-tree is built in core.scan_match
    from scipy.spatial import cKDTree


class KeyframeMap:
    """Keyframes by id (``keyframes``) and by grid cell (``grid``); ids count up from 0."""

    def __init__(self, params: KeyframeParams):
        """Start empty."""
        self.params = params
        self.keyframes: dict[int, Keyframe] = {}
        self.grid: dict[tuple, list] = defaultdict(list)
        self.next_id = 0
        self._stats: Optional[tuple[int, int]] = None

    def cell(self, pose: np.ndarray) -> tuple[int, int]:
        """Return the grid cell of a pose (m, m, rad)."""
        size = self.params.cell_size
        return (int(math.floor(pose[0] / size)), int(math.floor(pose[1] / size)))

    def add(self, kf: Keyframe) -> bool:
        """
        Store ``kf`` under the next id; return False when its cell or the map is full.

        A keyframe that does not fit replaces the previous one kept under id -1
        (the reference of the local check only).
        """
        kp = self.params
        self._stats = None
        self.keyframes.pop(-1, None)
        if len(self.grid[kf.cell]) >= kp.max_per_cell or len(self.keyframes) >= kp.max_keyframes:
            kf.kid = -1
            self.keyframes[-1] = kf
            return False
        kf.kid = self.next_id
        self.next_id += 1
        self.keyframes[kf.kid] = kf
        self.grid[kf.cell].append(kf.kid)
        return True

    def move(self, kf: Keyframe, pose: np.ndarray) -> None:
        """Give ``kf`` a new pose (m, m, rad), and its new cell in the grid."""
        kf.pose = pose
        cell = self.cell(pose)
        if cell != kf.cell:
            if kf.kid in self.grid.get(kf.cell, []):
                self.grid[kf.cell].remove(kf.kid)
            self.grid[cell].append(kf.kid)
            kf.cell = cell

    def clear(self) -> None:
        """Drop every keyframe (a new map); ids keep counting up."""
        self._stats = None
        self.keyframes.clear()
        self.grid.clear()

    def near(self, pose: np.ndarray, radius: float, path: float, min_travel: float,
             count: int) -> list[int]:
        """
        Return the ids of the ``count`` nearest keyframes within ``radius`` (m) of ``pose``.

        Only keyframes made at least ``min_travel`` m of driving before ``path``
        (m, the distance driven now) are loop candidates.
        """
        reach = int(math.ceil(radius / self.params.cell_size))
        cx, cy = self.cell(pose)
        found = []
        for ix in range(cx - reach, cx + reach + 1):
            for iy in range(cy - reach, cy + reach + 1):
                for kid in self.grid.get((ix, iy), ()):
                    kf = self.keyframes[kid]
                    if path - kf.path < min_travel:
                        continue
                    dist = math.hypot(kf.pose[0] - pose[0], kf.pose[1] - pose[1])
                    if dist <= radius:
                        found.append((dist, kid))
        found.sort()
        return [kid for _, kid in found[:count]]

    def stored(self) -> int:
        """Return the number of keyframes in the map (the id -1 reference excluded)."""
        return self._statistics()[0]

    def memory_bytes(self) -> int:
        """Return the bytes held by keyframe points and poses (B)."""
        return self._statistics()[1]

    def _statistics(self) -> tuple[int, int]:
        if self._stats is None:
            self._stats = (len([k for k in self.keyframes if k >= 0]),
                           int(sum(kf.points.nbytes + kf.pose.nbytes
                                   for kf in self.keyframes.values())))
        return self._stats


class OverlapGrid:
    """
    Which query points have a point of the current scan within ``gate`` (m): the KD-tree's answer.

    Most are settled by a grid of cells a little smaller than ``gate / sqrt 2``:
    a query point in an occupied cell has a scan point closer than the cell
    diagonal, under the gate; one with no occupied cell within ``reach`` cells
    (``reach`` cells span the gate) has none within it. Only the rest go to
    the KD-tree. Both margins are 1e-6 of the gate, far above rounding, so the
    answer is the KD-tree's own. A grid that would be too large (more than
    ``MAX_CELLS``), or non-finite points, leave every query to the KD-tree.
    """

    MAX_CELLS = 1 << 20

    def __init__(self, points: np.ndarray, tree: cKDTree, gate: float):
        """Index ``points`` (N, 2) (m), whose KD-tree is ``tree``, for the gate ``gate`` (m)."""
        self.tree = tree
        self.gate = gate
        self.occupied: Optional[np.ndarray] = None
        if len(points) == 0 or gate <= 0.0 or not np.all(np.isfinite(points)):
            return
        self.cell = gate / math.sqrt(2.0) * (1.0 - 1e-6)
        self.reach = int(math.ceil(gate * (1.0 + 1e-6) / self.cell))
        ij = np.floor(points / self.cell).astype(np.int64)
        self.lo = ij.min(axis=0) - self.reach - 1
        self.shape = ij.max(axis=0) - self.lo + self.reach + 2
        if (self.shape[0] * self.shape[1] > self.MAX_CELLS
                or float(np.max(np.abs(points))) * 1e-9 > 1e-6 * gate):
            return
        occupied = np.zeros(self.shape, dtype=bool)
        occupied[ij[:, 0] - self.lo[0], ij[:, 1] - self.lo[1]] = True
        near = occupied.copy()
        for axis in (0, 1):                       # square (Chebyshev) dilation by reach cells
            grown = near.copy()
            for d in range(1, self.reach + 1):
                if axis == 0:
                    grown[d:, :] |= near[:-d, :]
                    grown[:-d, :] |= near[d:, :]
                else:
                    grown[:, d:] |= near[:, :-d]
                    grown[:, :-d] |= near[:, d:]
            near = grown
        self.occupied, self.near = occupied, near

    def within(self, queries: np.ndarray) -> np.ndarray:
        """Return for each query point (M, 2) (m) whether a scan point is within the gate."""
        if self.occupied is None or not np.all(np.isfinite(queries)):
            dist, _ = self.tree.query(queries, distance_upper_bound=self.gate)
            return np.isfinite(dist)
        ij = np.floor(queries / self.cell).astype(np.int64) - self.lo
        inside = np.flatnonzero((ij >= 0).all(axis=1) & (ij < self.shape).all(axis=1))
        found = np.zeros(len(queries), dtype=bool)
        cells = (ij[inside, 0], ij[inside, 1])
        found[inside] = self.occupied[cells]
        unsure = inside[self.near[cells] & ~found[inside]]
        if len(unsure):
            dist, _ = self.tree.query(queries[unsure], distance_upper_bound=self.gate)
            found[unsure] = np.isfinite(dist)
        return found


def similarities(kfs: Sequence[Keyframe], guesses: Sequence[np.ndarray], grid: OverlapGrid,
                 detection: DetectionParams, sigma_yaw: float) -> list[tuple[float, float]]:
    """
    Return each keyframe's best overlap fraction with the current scan, and its yaw offset (rad).

    ``guesses`` are the keyframe frames seen from the current frame (m, m,
    rad), ``grid`` the :class:`OverlapGrid` of the current scan at the
    ``similarity_gate``; the yaw grid spans +- 3 ``sigma_yaw`` (rad), at most
    30 deg. All keyframes' points under every yaw hypothesis are tested at
    once; each point's answer is the same as alone, so are the fractions.
    """
    dp = detection
    n = dp.similarity_yaw_steps
    span = min(math.radians(30.0), 3.0 * sigma_yaw)
    offsets = np.linspace(-span, span, n) if n > 1 else np.zeros(1)
    if not kfs:
        return []
    # All yaw hypotheses of all keyframes at once: rotate each keyframe's predicted points
    # about the current origin by each offset.
    bases = [se2_apply(guess, _similarity_points(kf)) for kf, guess in zip(kfs, guesses)]
    sizes = [len(b) for b in bases]
    base = np.concatenate(bases) if len(bases) > 1 else bases[0]
    c, s = np.cos(offsets), np.sin(offsets)
    xs = c[:, None] * base[None, :, 0] - s[:, None] * base[None, :, 1]
    ys = s[:, None] * base[None, :, 0] + c[:, None] * base[None, :, 1]
    near = grid.within(np.column_stack((xs.ravel(), ys.ravel()))).reshape(len(offsets), -1)
    out = []
    end = 0
    for size in sizes:
        start, end = end, end + size
        frac = near[:, start:end].mean(axis=1)
        k = int(np.argmax(frac))
        out.append((float(frac[k]), float(offsets[k])))
    return out


def _similarity_points(kf: Keyframe) -> np.ndarray:
    """Return the keyframe points the similarity check uses: about 120 of them (m)."""
    pts = kf.points.astype(float)
    if len(pts) > 120:
        pts = pts[::max(1, len(pts) // 120)]
    return pts
