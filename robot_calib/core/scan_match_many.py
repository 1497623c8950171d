# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Many 2D registrations at once: the point-to-line refinement in lock step over stacked pairs.

:func:`register_many` gives, for each (source, target, guess), what
:func:`robot_calib.core.scan_match.register` gives with ``coarse='none'``: the
same iterations (gate schedule, Cauchy weights, Gauss-Newton step, stopping
rules) and the same quality check, but each iteration runs over the points of
all pairs still iterating as one set of arrays, so numpy's fixed cost per call
(most of a 360-point registration's time) is paid once per iteration, not once
per pair. Nearest target points are tracked as in ``scan_match._Nearest``,
searching each pair's own KD-tree, so the correspondences are the KD-tree's;
the sums and the 3x3 solves run in another order than the single registration,
so poses agree to rounding (about 1e-15 m), not bit for bit.

Wheel calibration uses it to re-match all key-frame pairs after the re-deskew.
"""

from __future__ import annotations

from typing import Optional, Sequence, Union

import numpy as np
from robot_calib.core.geometry import wrap_angle
from robot_calib.core.scan_match import (_Nearest, _quality, _SEARCH_REACH, clean_points,
                                         MatchResult, PreparedScan, register, ScanMatchParams,
                                         search_slack, stale_rows)


class _Stack:
    """Sources and targets of the pairs as flat arrays (a point's pair: ``pid``)."""

    def __init__(self, sources: list[np.ndarray], targets: list[PreparedScan]):
        """Stack the (cleaned) sources and the prepared targets."""
        self.sources, self.targets = sources, targets
        sizes = np.array([len(s) for s in sources])
        self.pid = np.repeat(np.arange(len(sources)), sizes)
        self.points = np.concatenate(sources) if sources else np.zeros((0, 2))
        tsizes = np.array([len(t) for t in targets])
        self.toff = np.concatenate(([0], np.cumsum(tsizes)[:-1])).astype(np.intp)
        self.tsize = tsizes
        self.miss = int(tsizes.sum())                  # index of the far, unusable row
        self.tpoints = np.vstack([t.points for t in targets] + [np.full((1, 2), np.inf)])
        self.normals = np.vstack([t.normals for t in targets] + [np.zeros((1, 2))])
        self.usable = np.concatenate([t.normal_ok for t in targets] + [np.zeros(1, bool)])
        n = len(self.points)
        self.at = np.zeros((n, 2))                     # tracked nearest (scan_match._Nearest)
        self.idx = np.full(n, self.miss, dtype=np.intp)
        self.slack = np.full(n, -1.0)
        self.nomatch = np.zeros(n)

    def query(self, sel: np.ndarray, moved: np.ndarray,
              gate: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the global nearest index (``miss`` beyond ``gate``) and offset of ``sel``."""
        again = stale_rows(moved, self.at[sel], self.slack[sel], self.nomatch[sel], gate)
        if len(again):
            self._search(sel[again], moved[again], gate)
        idx = self.idx[sel]
        offset = moved - self.tpoints[idx]
        sq = np.einsum('ij,ij->i', offset, offset)
        return np.where(sq < gate * gate, idx, self.miss), offset

    def nearest(self, pair: int, rows: slice) -> _Nearest:
        """Return the tracked nearest points of ``pair`` (its points: ``rows``) for one pair."""
        near = _Nearest(self.targets[pair], rows.stop - rows.start)
        near.at[:] = self.at[rows]
        local = self.idx[rows] - self.toff[pair]
        near.idx[:] = np.where(self.idx[rows] == self.miss, self.tsize[pair], local)
        near.slack[:] = self.slack[rows]
        near.miss[:] = self.nomatch[rows]
        return near

    def _search(self, rows: np.ndarray, pts: np.ndarray, gate: float) -> None:
        """Search ``rows`` (global point indices, grouped by pair) in their pairs' KD-trees."""
        bound = _SEARCH_REACH * gate
        pairs = self.pid[rows]
        cut = np.flatnonzero(np.diff(pairs)) + 1
        dist = np.empty((len(rows), 2))
        idx = np.empty(len(rows), dtype=np.intp)
        for lo, hi in zip(np.concatenate(([0], cut)), np.concatenate((cut, [len(rows)]))):
            b = pairs[lo]
            d, i = self.targets[b].tree.query(pts[lo:hi], k=2, distance_upper_bound=bound)
            dist[lo:hi] = d
            idx[lo:hi] = np.where(i[:, 0] < self.tsize[b], i[:, 0] + self.toff[b], self.miss)
        found = idx != self.miss
        self.at[rows] = pts
        self.idx[rows] = idx
        self.slack[rows] = search_slack(dist, found, bound)
        self.nomatch[rows] = ~found


def _step_sums(st: _Stack, sel: np.ndarray, turned: np.ndarray, idx: np.ndarray,
               offset: np.ndarray, n_pairs: int, scale: float) -> tuple[np.ndarray, ...]:
    """Return each pair's used points, Gauss-Newton Hessian (P, 3, 3) and gradient (P, 3)."""
    use = np.flatnonzero(st.usable[idx])
    count = np.bincount(st.pid[sel[use]], minlength=n_pairs)
    nrm = st.normals[idx[use]]
    off = offset[use]
    tu = turned[use]
    n0, n1 = nrm[:, 0], nrm[:, 1]
    res = n0 * off[:, 0] + n1 * off[:, 1]                               # point-line (m)
    j2 = n1 * tu[:, 0] - n0 * tu[:, 1]                                 # n . d(R p)/d yaw
    w = 1.0 / (1.0 + (res / scale) ** 2)                               # Cauchy weights
    terms = np.empty((len(use), 9))
    wn0, wn1, wj2 = w * n0, w * n1, w * j2
    for col, (a, b) in enumerate(((wn0, n0), (wn0, n1), (wn0, j2), (wn1, n1), (wn1, j2),
                                  (wj2, j2), (wn0, res), (wn1, res), (wj2, res))):
        np.multiply(a, b, out=terms[:, col])
    sums = np.zeros((n_pairs, 9))
    some = count > 0
    if len(use):
        starts = np.concatenate(([0], np.cumsum(count)[:-1]))
        sums[some] = np.add.reduceat(terms, starts[some], axis=0)
    h = sums[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)
    return count, h, sums[:, 6:]


def _solve(h: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the steps ``-h^-1 g`` (k, 3) and which could be solved (singular: False)."""
    try:
        return -np.linalg.solve(h, g[:, :, None])[:, :, 0], np.ones(len(h), dtype=bool)
    except np.linalg.LinAlgError:
        out, ok = np.zeros_like(g), np.ones(len(h), dtype=bool)
        for k in range(len(h)):
            try:
                out[k] = -np.linalg.solve(h[k], g[k])
            except np.linalg.LinAlgError:
                ok[k] = False
        return out, ok


def _refine_many(st: _Stack, poses: np.ndarray,
                 p: ScanMatchParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run ``scan_match._refine`` on every pair together; return poses, converged, iterations."""
    n_pairs = len(poses)
    poses = np.array(poses, dtype=float)
    active = np.ones(n_pairs, dtype=bool)
    converged = np.zeros(n_pairs, dtype=bool)
    iters = np.zeros(n_pairs, dtype=int)
    last_step = np.full((n_pairs, 2), np.inf)
    n_it = p.refine_iterations
    n_anneal = max(1, min(p.refine_anneal_iterations, n_it - 1))
    ratio = p.refine_min_correspondence / p.refine_max_correspondence
    damping = 1e-9 * np.eye(3)
    for it in range(1, n_it + 1):
        if not active.any():
            break
        frac = min(1.0, (it - 1) / n_anneal)
        gate = p.refine_max_correspondence * ratio ** frac
        iters[active] = it
        sel = np.flatnonzero(active[st.pid])
        ps = st.pid[sel]
        src = st.points[sel]
        c, s = np.cos(poses[:, 2])[ps], np.sin(poses[:, 2])[ps]
        turned = np.column_stack((c * src[:, 0] - s * src[:, 1], s * src[:, 0] + c * src[:, 1]))
        idx, offset = st.query(sel, turned + poses[ps, :2], gate)
        count, h, g = _step_sums(st, sel, turned, idx, offset, n_pairs, p.robust_scale)
        active &= count >= 3                           # too few correspondences: stop there
        act = np.flatnonzero(active)
        delta, ok = _solve(h[act] + damping, g[act])
        active[act[~ok]] = False
        act, delta = act[ok], delta[ok]
        poses[act, :2] += delta[:, :2]
        poses[act, 2] = wrap_angle(poses[act, 2] + delta[:, 2])
        last_step[act] = np.column_stack((np.hypot(delta[:, 0], delta[:, 1]),
                                          np.abs(delta[:, 2])))
        if frac >= 1.0:
            done = act[(last_step[act, 0] < p.convergence_translation)
                       & (last_step[act, 1] < p.convergence_rotation)]
            converged[done] = True
            active[done] = False
    # a slow final creep (sub-mm, sub-mrad steps) still counts as converged
    creep = ~converged & (iters == n_it)
    converged[creep] = (last_step[creep, 0] < 1e-3) & (last_step[creep, 1] < 1e-3)
    return poses, converged, iters


def register_many(sources: Sequence[np.ndarray],
                  targets: Sequence[Union[np.ndarray, PreparedScan]],
                  guesses: Sequence[Sequence[float]],
                  params: Optional[ScanMatchParams] = None) -> list[MatchResult]:
    """
    Register each source to its target from its guess, the refinement alone (no coarse).

    :param sources: (N_i, 2) source points (m) per pair, in the source frame.
    :param targets: (M_i, 2) target points (m) or PreparedScan per pair.
    :param guesses: (x, y, yaw) per pair (m, m, rad), source frame in the target frame.
    :param params: registration parameters (``coarse`` is ignored: none runs).
    :return: one :class:`MatchResult` per pair, as ``register(..., coarse='none')`` gives.
    """
    p = params if params is not None else ScanMatchParams(coarse='none')
    if p.coarse != 'none':
        p = ScanMatchParams(**{**p.__dict__, 'coarse': 'none'})
    out: list[Optional[MatchResult]] = [None] * len(sources)
    jobs, srcs, tgts, starts = [], [], [], []
    for k, (s, t, g) in enumerate(zip(sources, targets, guesses)):
        src = clean_points(s)
        tgt = t if isinstance(t, PreparedScan) else PreparedScan(t, p)
        guess = np.array(g, dtype=float).reshape(3)
        if (not p.refine or not np.all(np.isfinite(guess)) or len(src) < p.min_points
                or len(tgt) < p.min_points):
            out[k] = register(src, tgt, guess, p)      # the reason, or no refinement
            continue
        jobs.append(k)
        srcs.append(src)
        tgts.append(tgt)
        starts.append(guess)
    if jobs:
        st = _Stack(srcs, tgts)
        poses, converged, iters = _refine_many(st, np.array(starts), p)
        first = np.concatenate(([0], np.cumsum([len(s) for s in srcs])))
        for j, k in enumerate(jobs):
            out[k] = _result(srcs[j], tgts[j], starts[j], poses[j], converged[j], iters[j], p,
                             st.nearest(j, slice(first[j], first[j + 1])))
    return out


def _result(src: np.ndarray, tgt: PreparedScan, guess: np.ndarray, pose: np.ndarray,
            converged: bool, iters: int, p: ScanMatchParams, nearest: _Nearest) -> MatchResult:
    """Return the MatchResult of one pair, quality included (as ``register`` fills it)."""
    result = MatchResult(pose=guess.copy(), n_source=len(src), n_target=len(tgt))
    result.coarse_pose = guess.copy()
    result.iterations = int(iters)
    result.pose = np.array([pose[0], pose[1], wrap_angle(float(pose[2]))])
    result.converged = bool(converged)
    _quality(src, tgt, result.pose, p, result, nearest)
    if result.inlier_ratio < p.min_inlier_ratio:
        result.converged = False
    return result
