# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Evidence that holds on real recordings: block-robust covariances and significance.

Real residuals are not white: the noise is coloured, outliers occur, and
structure the library cannot explain (a ground truth's own errors, an
unmodelled vibration) stays in them. A least-squares covariance computed as
if the residual were white makes every such structure "significant". Here
the evidence for an effect is judged by how consistently it shows across
independent stretches of the recording:

- the time line is cut into ``K`` contiguous blocks, each longer than the
  residual's correlation time;
- the covariance of the coefficients is the cluster-robust sandwich
  ``V = A^-1 (sum_b s_b s_b^T) A^-1 K / (K - p)`` with ``s_b`` the block's score
  ``sum_{i in b} x_i w e_i`` (Liang & Zeger 1986; Cameron & Miller 2015, eq. 11
  with the small-sample factor), which needs no model of the noise spectrum;
- an effect with ``p`` coefficients is significant when its Wald statistic
  ``W = beta^T V^-1 beta`` exceeds the ``1 - alpha`` quantile of ``p F(p, K_e - p)``,
  ``K_e`` the number of blocks in which the effect's regressor acts.

A constant offset that shows in every block passes with a few blocks; a
"scale" that only follows the ground truth's errors in some stretches does
not.

An effect in a window claims that it changes at the window's edges.
:func:`window_prune` fits it inside and outside the window and judges the
difference the same way; a window whose edges fail (a residual that wanders
slowly sits lower in a stretch left out) is dropped and the effect is global.

A gain (a scale, a cross-axis term) acts the same on slow and on fast motion.
:func:`band_prune` splits its regressor into a slow part (a moving average)
and the fast rest and fits both. When the two coefficients differ by the same
robust test and the slow part alone does not pass it, the "gain" lives in fast
motion only: it follows a difference of bandwidth (a reference carrying less
fast motion than the real sensor), not a sensor's gain, and is dropped. A real
gain shows on slow motion too, even where the fast part differs (a gain added
to a sensor whose fast motion the reference also misses).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from robot_calib.mismatch import effects as E
from robot_calib.mismatch import select as S
from robot_calib.mismatch.locate import moving_average
from robot_calib.mismatch.problem import Problem

GAIN_EFFECTS = ('gyro_scale', 'gyro_cross_axis', 'accel_scale')
"""Effects whose model is one constant gain on a simulated signal (:func:`band_prune`)."""


def block_edges(n: int, dt: float, target: int = 40, min_block_s: float = 1.0,
                least: int = 6) -> np.ndarray:
    """
    Return the sample indices bounding ``K`` contiguous blocks of a time line.

    :param n: number of samples
    :param dt: sample period (s)
    :param target: number of blocks wanted
    :param min_block_s: shortest block (s): longer than the residual's correlation time
    :param least: fewest blocks (shorter blocks rather than fewer)
    """
    k = int(min(target, max(least, n * max(dt, 1e-9) / max(min_block_s, 1e-9))))
    k = max(2, min(k, n // 4 if n >= 8 else 2))
    return np.unique(np.linspace(0, n, k + 1).astype(int))


def _block_energy(prob: Problem, term, edges: np.ndarray) -> np.ndarray:
    energy = np.zeros(edges.size - 1)
    for f in term.cols:
        if f not in prob.fields:
            continue
        X = S.term_cols(term, f, prob)
        e = np.einsum('ij,ij->i', X, X) * prob.w[f]
        energy += np.add.reduceat(e[:edges[-1]], edges[:-1])
    return energy


def focused_edges(prob: Problem, term, edges: np.ndarray, min_block_s: float,
                  frac: float = 0.02) -> np.ndarray:
    """
    Return ``edges``, or finer ones where the term acts when it acts in few blocks.

    An effect excited only in a short manoeuvre (one rotation of a protocol,
    an effect in a window) would otherwise be judged on two or three blocks,
    whose spread says nothing; its active blocks are cut into pieces until it
    spans half as many blocks as the whole recording has. A piece is no
    shorter than a quarter of ``min_block_s`` nor than ten correlation lengths
    of the residual's noise (``10 phi`` samples), so neighbouring pieces stay
    nearly independent.
    """
    energy = _block_energy(prob, term, edges)
    top = float(energy.max()) if energy.size else 0.0
    active = np.flatnonzero(energy > frac * top) if top > 0 else np.zeros(0, int)
    want = (edges.size - 1) // 2
    if active.size == 0 or active.size >= want:
        return edges
    phi = max((prob.phi[f] for f in term.cols if f in prob.fields), default=1.0)
    shortest = max(4, int(round(0.25 * min_block_s / max(prob.pt.dt, 1e-9))),
                   int(np.ceil(10.0 * phi)))
    parts = int(np.ceil(want / active.size))
    extra = []
    for b in active:
        a0, a1 = int(edges[b]), int(edges[b + 1])
        m = max(1, min(parts, (a1 - a0) // shortest))
        extra.append(np.linspace(a0, a1, m + 1).astype(int))
    return np.unique(np.concatenate([edges] + extra))


def _term_index(terms: list) -> list:
    idx, k0 = [], 0
    for t in terms:
        idx.append(np.arange(k0, k0 + t.p))
        k0 += t.p
    return idx


def block_scores(prob: Problem, terms: list, fit: S.Fit, edges: np.ndarray) -> np.ndarray:
    """
    Return the per-block scores ``s_b`` (K, P) of a fitted model.

    ``s_b = sum_c sum_{i in b} w_c x_ci e_ci`` with ``e`` the residual after the
    fit; ``fit`` must carry the contributions (``S.fit(..., contributions=True)``).
    """
    idx = _term_index(terms)
    scores = np.zeros((edges.size - 1, idx[-1][-1] + 1 if idx else 0))
    starts = edges[:-1]
    for f in prob.fields:
        js = [j for j, t in enumerate(terms) if f in t.cols]
        if not js:
            continue
        e = (prob.r[f] - fit.contrib.get(f, 0.0)) * prob.sw[f] * prob.w[f]
        for j in js:
            X = S.term_cols(terms[j], f, prob)
            scores[:, idx[j]] += np.add.reduceat(X[:edges[-1]] * e[:edges[-1], None], starts,
                                                 axis=0)
    return scores


def active_blocks(prob: Problem, term, edges: np.ndarray, frac: float = 0.02) -> int:
    """Return the number of blocks holding at least ``frac`` of the term's peak block energy."""
    energy = _block_energy(prob, term, edges)
    top = float(energy.max()) if energy.size else 0.0
    return int(np.sum(energy > frac * top)) if top > 0 else 0


def sandwich(prob: Problem, terms: list, fit: S.Fit,
             edges: np.ndarray) -> Optional[np.ndarray]:
    """Return the cluster-robust covariance (P, P) of all coefficients, or None if undefined."""
    if not terms:
        return None
    if not fit.contrib:
        fit = S.fit(prob, terms, contributions=True)
    sc = block_scores(prob, terms, fit, edges)
    k, p = sc.shape
    if k <= p:
        return None
    C = fit.cov_full
    B = sc.T @ sc
    return C @ B @ C * (k / (k - p))


def wald_bar(p: int, blocks: float, alpha: float) -> float:
    """
    Return the bar a robust Wald statistic of ``p`` coefficients over ``blocks`` must pass.

    ``p F(p, K_e - p)`` at false-alarm probability ``alpha``.
    """
    from scipy import special
    return p * float(special.fdtri(p, max(blocks - p, 1), 1.0 - alpha))


def wald(prob: Problem, terms: list, fit: S.Fit, edges: np.ndarray,
         alpha: float, min_block_s: float = 1.0) -> list:
    """
    Return per term ``(W, threshold, blocks)``: its robust Wald statistic and the bar it must pass.

    A term whose covariance cannot be estimated (fewer active blocks than
    coefficients plus one) gets ``W = 0``. A term acting only in part of the
    recording is judged on blocks cut finer there (:func:`focused_edges`).
    """
    if not fit.contrib:
        fit = S.fit(prob, terms, contributions=True)
    V = sandwich(prob, terms, fit, edges)
    out = []
    for j, (t, idx) in enumerate(zip(terms, _term_index(terms))):
        e_t = focused_edges(prob, t, edges, min_block_s)
        V_t = V if e_t is edges else sandwich(prob, terms, fit, e_t)
        kb = active_blocks(prob, t, e_t)
        p = t.p
        thr = wald_bar(p, kb, alpha)
        if V_t is None or kb <= p:
            out.append((0.0, thr, kb))
            continue
        Vj = V_t[np.ix_(idx, idx)]
        b = np.asarray(fit.betas[j], float)
        if 'theta' in t.meta:  # a refined nonlinear term: its value is theta + the correction
            b = np.asarray(t.meta['theta'], float) + b
        try:
            w = float(b @ np.linalg.solve(Vj + 1e-300 * np.eye(p), b))
        except np.linalg.LinAlgError:
            w = 0.0
        out.append((w if np.isfinite(w) else 0.0, thr, kb))
    return out


def block_spread(prob: Problem, terms: list, fit: S.Fit, edges: np.ndarray, j: int,
                 share: float = 0.25) -> Optional[tuple]:
    """
    Return (whole, low, high) of the one-coefficient term ``terms[j]``: its value and spread.

    Each block's own estimate, the others held, is one Gauss-Newton step from
    the whole recording's: ``beta_b = beta + s_b / E_b`` (``s_b`` the block's
    score, :func:`block_scores`, ``E_b`` its weighted regressor energy); only
    blocks with at least ``share`` of the median active block's energy count
    (a block that hardly excites the term says nothing of it). ``low`` and
    ``high`` are the 10th and 90th percentiles of those estimates. In the
    term's table units (:func:`~robot_calib.mismatch.effects.to_params`, first
    parameter); None for a term of more coefficients or fewer than 3 blocks.
    """
    t = terms[j]
    if t.p != 1:
        return None
    if not fit.contrib:
        fit = S.fit(prob, terms, contributions=True)
    energy = _block_energy(prob, t, edges)
    score = block_scores(prob, terms, fit, edges)[:, _term_index(terms)[j][0]]
    active = energy[energy > 0.02 * energy.max()] if energy.size and energy.max() > 0 else []
    use = energy >= share * float(np.median(active)) if len(active) else energy < 0
    if use.sum() < 3:
        return None
    beta = float(np.asarray(fit.betas[j], float)[0])
    per = beta + score[use] / energy[use]

    def unit(b: float) -> float:
        return next(iter(E.to_params(t, np.array([b]), np.zeros((1, 1)))[0].values()))
    lo, hi = sorted((unit(float(np.percentile(per, q))) for q in (10.0, 90.0)))
    return unit(beta), lo, hi


def robust_prune(prob: Problem, sel: list, edges: np.ndarray, alpha: float,
                 refine=None, min_block_s: float = 1.0) -> tuple[list, list]:
    """
    Drop, weakest first, the terms that fail the robust Wald test; return (kept, dropped).

    ``dropped`` holds ``(term, (W, threshold, blocks, spread))``, ``spread`` the
    term's value and its spread between blocks (:func:`block_spread`) or None.

    :param refine: called on the kept terms after each drop (e.g. nonlinear refinement)
    """
    out = list(sel)
    dropped = []
    while out:
        f = S.fit(prob, out, contributions=True)
        tests = wald(prob, out, f, edges, alpha, min_block_s)
        ratios = [w / max(thr, 1e-12) for w, thr, _ in tests]
        i = int(np.argmin(ratios))
        if ratios[i] >= 1.0:
            break
        spread = block_spread(prob, out, f, edges, i)
        dropped.append((out.pop(i), tests[i] + (spread,)))
        if refine is not None and out:
            out = refine(out)
    return out, dropped


def dropped_note(term, test: tuple) -> str:
    """Return the report's note on a candidate :func:`robust_prune` dropped (its size, spread)."""
    w, thr, kb, spread = test
    size = '' if spread is None else \
        f' ({spread[0]:+.3g} over the recording, {spread[1]:+.3g} to {spread[2]:+.3g} ' \
        'from block to block, 10th to 90th percentile)'
    return (f'{term.channel}: a candidate {term.effect} fits{size}, but not consistently '
            f'across the recording (robust test {w:.3g} < {thr:.3g} over {kb} blocks); '
            'not reported')


def band_test(prob: Problem, sel: list, j: int, edges: np.ndarray, alpha: float,
              width_s: float) -> Optional[tuple]:
    """
    Return ``(slow, fast, W, threshold, W_slow)`` of the gain ``sel[j]`` split by frequency.

    The term's regressor is cut into its moving average over ``width_s`` seconds
    (the slow part, below about ``0.44 / width_s`` Hz) and the rest; both are
    fitted with the other selected terms. ``W`` is the robust Wald statistic of
    their difference and ``W_slow`` that of the slow coefficient, both judged
    like :func:`wald` (``F(1, K_e - 1)`` at ``alpha``). None when the blocks
    cannot tell.
    """
    t = sel[j]
    width = max(3, int(round(width_s / max(prob.pt.dt, 1e-9))) | 1)
    slow = {f: moving_average(c, width) for f, c in t.cols.items()}
    parts = [t.with_cols(slow, f'{t.group}:slow'),
             t.with_cols({f: c - slow[f] for f, c in t.cols.items()}, f'{t.group}:fast')]
    model = sel[:j] + sel[j + 1:] + parts
    fit = S.fit(prob, model, contributions=True)
    V = sandwich(prob, model, fit, edges)
    kb = active_blocks(prob, t, edges)
    if V is None or kb <= 2:
        return None
    b_slow, b_fast = float(fit.betas[-2][0]), float(fit.betas[-1][0])
    var = V[-2, -2] + V[-1, -1] - 2.0 * V[-2, -1]
    w = (b_slow - b_fast) ** 2 / var if var > 0 else 0.0
    w_slow = b_slow ** 2 / V[-2, -2] if V[-2, -2] > 0 else 0.0
    return b_slow, b_fast, w, wald_bar(1, kb, alpha), w_slow


def band_prune(prob: Problem, sel: list, edges: np.ndarray, alpha: float,
               width_s: float) -> tuple[list, list]:
    """
    Drop the gains that act on fast motion only (:func:`band_test`); return (kept, dropped).

    A gain is dropped when its slow and fast coefficients differ and the slow one
    is not significant. ``dropped`` holds ``(term, (slow, fast, W, threshold, W_slow))``.
    """
    out, dropped = [], []
    for j, t in enumerate(sel):
        test = band_test(prob, sel, j, edges, alpha, width_s) \
            if t.effect in GAIN_EFFECTS and t.p == 1 and t.window is None else None
        if test is not None and test[2] > test[3] and test[4] < test[3]:
            dropped.append((t, test))
        else:
            out.append(t)
    return out, dropped


def effective_blocks(prob: Problem, term, edges: np.ndarray) -> float:
    """
    Return the effective number of blocks carrying the term: ``(sum E_b)^2 / sum E_b^2``.

    ``E_b`` is the term's weighted regressor energy in block ``b`` (its share of
    the information). Blocks weighted unequally (quiet stretches weigh more)
    count for fewer (Kish 1965, effective sample size of a weighted sample).
    """
    e = _block_energy(prob, term, edges)
    s2 = float(np.sum(e * e))
    return float(np.sum(e)) ** 2 / s2 if s2 > 0 else 0.0


def _outside(term):
    """Return ``term`` acting everywhere except in its window (its own group)."""
    i0, i1 = term.window
    cols = {}
    for f, c in term.cols.items():
        c = np.array(c, dtype=float)
        c[i0:i1] = 0.0
        cols[f] = c
    return term.with_window(None).with_cols(cols, f'{term.group}:outside')


def window_test(prob: Problem, sel: list, j: int, edges: np.ndarray, alpha: float,
                min_block_s: float = 1.0) -> Optional[tuple]:
    """
    Return ``(inside, outside, W, threshold, K_e)`` of the windowed term ``sel[j]``.

    A window claims the effect changes at its edges. The term is fitted inside
    its window and, as a second term, outside it (the same regressors, zero
    inside), with the other selected terms. ``W`` is the robust Wald statistic
    of the difference of the two coefficients (block sandwich on the blocks
    that judge the term itself, :func:`focused_edges`: a short window is cut
    finer, as in :func:`wald`); it must pass ``p F(p, K_e - p)`` at ``alpha``,
    ``K_e`` the effective number of blocks (:func:`effective_blocks`) of the
    side holding fewer. A residual that wanders slowly makes a step at any edge
    significant to the selection's white-noise score, but not consistently
    across blocks: a window leaving out a stretch of a few blocks, where the
    residual happens to sit lower, is no evidence that the effect is absent
    there. None when a side has too few blocks for a covariance (or the term
    is nonlinear).
    """
    t = sel[j]
    if t.window is None or 'offset' in t.meta or 'theta' in t.meta:
        return None
    out = _outside(t)
    model = sel[:j] + sel[j + 1:] + [t, out]
    fit = S.fit(prob, model, contributions=True)
    edges = focused_edges(prob, t, edges, min_block_s)
    V = sandwich(prob, model, fit, edges)
    p = t.p
    ke = min(effective_blocks(prob, t, edges), effective_blocks(prob, out, edges))
    if V is None or ke <= p:
        return None
    d = np.asarray(fit.betas[-2], float) - np.asarray(fit.betas[-1], float)
    P = V.shape[0]
    ii, io = np.arange(P - 2 * p, P - p), np.arange(P - p, P)
    Vd = V[np.ix_(ii, ii)] + V[np.ix_(io, io)] - V[np.ix_(ii, io)] - V[np.ix_(io, ii)]
    try:
        w = float(d @ np.linalg.solve(Vd + 1e-300 * np.eye(p), d))
    except np.linalg.LinAlgError:
        return None
    if not np.isfinite(w):
        return None
    return (fit.betas[-2], fit.betas[-1], w, wald_bar(p, ke, alpha), ke)


def window_prune(prob: Problem, sel: list, edges: np.ndarray, alpha: float,
                 min_block_s: float = 1.0) -> tuple[list, list]:
    """
    Make global the windowed terms whose change at the window's edges fails :func:`window_test`.

    Returns (terms, widened) with ``widened`` holding ``(term as it was, test)``.
    """
    out, widened = list(sel), []
    for j, t in enumerate(sel):
        test = window_test(prob, out, j, edges, alpha, min_block_s)
        if test is not None and test[2] < test[3]:
            out[j] = t.with_window(None)
            widened.append((t, test))
    return out, widened
