# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Select the smallest set of effects that explains a topic's residual.

Forward stepwise sparse regression with the Bayesian information criterion
on the whitened residual (Schwarz 1978): a model's score is
``S = chi2 + k ln(N_eff)`` with ``chi2 = sum_c sum_i r_ci^2 / (sigma_c^2 phi_c)``
(sigma_c the channel's noise level, phi_c its variance inflation for
coloured noise), ``N_eff = sum_c n_c / phi_c`` and ``k`` the number of
coefficients (+2 for a window's edges). A term enters when it lowers S by
more than ``margin``; a term of the same group (e.g. a bias on a channel that
already has a drifting bias) replaces the old one. Nonlinear effects
(time offset, mounting tilt) are refined afterwards with their exact model
by Gauss-Newton. Confidence intervals come from the joint least-squares
covariance (already inflated by phi). Effects that explain the residual
about as well as a selected one (score within ``alt_margin``) are returned
as alternatives.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from robot_calib.mismatch import effects as E
from robot_calib.mismatch.locate import scan_window
from robot_calib.mismatch.problem import Problem

NONLINEAR = ('imu_mounting_tilt', 'imu_mounting_rotation')


@dataclass
class Fit:
    """A joint least-squares fit of terms: coefficients, covariance, chi2 and contributions."""

    terms: list
    betas: list
    covs: list
    chi2: float
    k: int
    contrib: dict
    cov_full: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def tdot(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """
    Return X^T Y for tall X (n, p) and Y (n,) or (n, q) with column dot products.

    Tall-skinny products through einsum: a threaded BLAS dot/gemv is tens of
    times slower for these shapes on a busy machine.
    """
    if Y.ndim == 1:
        return np.einsum('ij,i->j', X, Y)
    return np.einsum('ij,ik->jk', X, Y)


def mdot(X: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return X b for tall X (n, p) as a sum of scaled columns."""
    out = X[:, 0] * b[0]
    for i in range(1, X.shape[1]):
        out = out + X[:, i] * b[i]
    return out


def term_cols(term: E.Term, f: str, prob: Problem) -> np.ndarray:
    """Return the term's regressors on field ``f``, zero outside its window and invalid samples."""
    X = _mcols(prob, term, f)
    if term.window is None:
        return X
    out = np.zeros_like(X)
    i0, i1 = term.window
    out[i0:i1] = X[i0:i1]
    return out


def _mcols(prob: Problem, term: E.Term, f: str) -> np.ndarray:
    """Return the term's global regressors on ``f`` with invalid samples zeroed (cached)."""
    key = ('m', term.uid, f)
    X = prob.cache.get(key)
    if X is None:
        X = term.cols[f] * prob.sw[f][:, None]
        prob.cache[key] = X
    return X


def _span(term: E.Term, n: int) -> tuple:
    return term.window if term.window is not None else (0, n)


def _xtx(prob: Problem, a: E.Term, b: E.Term, f: str) -> np.ndarray:
    key = ('xx', a.uid, a.window, b.uid, b.window, f)
    M = prob.cache.get(key)
    if M is None:
        lo = max(_span(a, prob.n)[0], _span(b, prob.n)[0])
        hi = min(_span(a, prob.n)[1], _span(b, prob.n)[1])
        if hi <= lo:
            M = np.zeros((a.p, b.p))
        else:
            M = tdot(_mcols(prob, a, f)[lo:hi], _mcols(prob, b, f)[lo:hi])
        prob.cache[key] = M
        prob.cache[('xx', b.uid, b.window, a.uid, a.window, f)] = M.T
    return M


def _xtv(prob: Problem, a: E.Term, f: str, v: np.ndarray, tag: object) -> np.ndarray:
    key = ('xr', a.uid, a.window, f, tag)
    if tag is not None and key in prob.cache:
        return prob.cache[key]
    lo, hi = _span(a, prob.n)
    out = tdot(_mcols(prob, a, f)[lo:hi], v[lo:hi])
    if tag is not None:
        prob.cache[key] = out
    return out


def term_offset(term: E.Term, f: str, prob: Problem,
                weighted: bool = False) -> Optional[np.ndarray]:
    """Return the fixed (exact-model) contribution of a refined nonlinear term, or None."""
    off = term.meta.get('offset')
    if off is None or f not in off:
        return None
    return off[f] * (prob.sw[f] if weighted else prob.mask[f])


def n_coef(terms: list) -> int:
    """Return the number of coefficients of a model (+2 per window)."""
    return int(sum(t.p + (2 if t.window is not None else 0) for t in terms))


def fit(prob: Problem, terms: list, contributions: bool = False) -> Fit:
    """
    Fit ``terms`` jointly by weighted least squares; chi2 of the whitened residual.

    Cross products are cached per (term, window, channel), so refitting
    subsets during the selection costs only small matrix algebra.
    """
    K = sum(t.p for t in terms)
    idx = []
    k0 = 0
    for t in terms:
        idx.append(np.arange(k0, k0 + t.p))
        k0 += t.p
    A = np.zeros((K, K))
    b = np.zeros(K)
    rr = 0.0
    resid = {}
    for f in prob.fields:
        offs = [o for o in (term_offset(t, f, prob, True) for t in terms) if o is not None]
        if offs:
            r = prob.rw(f) - sum(offs)
            tag = None
            rr += prob.w[f] * float(np.einsum('i,i->', r, r))
        else:
            r = prob.rw(f)
            tag = 'r'
            key = ('rr', f)
            if key not in prob.cache:
                prob.cache[key] = float(np.einsum('i,i->', r, r))
            rr += prob.w[f] * prob.cache[key]
        resid[f] = r
        js = [j for j, t in enumerate(terms) if f in t.cols]
        w = prob.w[f]
        for a_ in js:
            b[idx[a_]] += w * _xtv(prob, terms[a_], f, r, tag)
            for c_ in js:
                if c_ < a_:
                    continue
                M = w * _xtx(prob, terms[a_], terms[c_], f)
                A[np.ix_(idx[a_], idx[c_])] += M
                if c_ != a_:
                    A[np.ix_(idx[c_], idx[a_])] += M.T
    if K:
        reg = 1e-12 * (np.trace(A) / K + 1e-300)
        try:
            cov = np.linalg.inv(A + reg * np.eye(K))
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(A)
        beta = cov @ b
        chi2 = rr - float(b @ beta)
    else:
        cov = np.zeros((0, 0))
        beta = np.zeros(0)
        chi2 = rr
    contrib = {}
    if contributions:
        for f in prob.fields:
            c = np.zeros(prob.n)
            for j, t in enumerate(terms):
                if f not in t.cols:
                    continue
                off = term_offset(t, f, prob)
                if off is not None:
                    c += off
                lo, hi = _span(t, prob.n)
                X = t.cols[f][lo:hi] * prob.mask[f][lo:hi, None]
                c[lo:hi] += mdot(X, beta[idx[j]])
            contrib[f] = c
    return Fit(list(terms), [beta[i] for i in idx], [cov[np.ix_(i, i)] for i in idx],
               max(float(chi2), 0.0), n_coef(terms), contrib, cov)


def score(prob: Problem, f: Fit) -> float:
    """Return the BIC-like score chi2 + k ln N_eff of a fit."""
    return f.chi2 + f.k * np.log(max(prob.n_eff, 2.0))


def _residuals(prob: Problem, cur: Fit) -> dict:
    if not cur.contrib and cur.terms:
        cur = fit(prob, cur.terms, contributions=True)
    return {f: prob.r[f] - cur.contrib.get(f, 0.0) for f in prob.fields}


def _screen(prob: Problem, cand: E.Term, res: dict, min_len: int,
            allow_window: bool) -> tuple[float, Optional[tuple]]:
    """Return the approximate BIC gain of adding ``cand`` (global or windowed) and its window."""
    fs = [f for f in cand.cols if f in prob.fields]
    if not fs:
        return -np.inf, None
    xs = [term_cols(cand, f, prob) for f in fs]
    es = [res[f] * prob.sw[f] for f in fs]
    ws = [prob.w[f] for f in fs]
    p = cand.p
    A = sum(w * _xtx(prob, cand, cand, f) for f, w in zip(fs, ws))
    h = sum(w * tdot(X, e) for X, e, w in zip(xs, es, ws))
    if not np.all(np.isfinite(A)) or np.trace(A) <= 0:
        return -np.inf, None
    try:
        d_glob = float(h @ np.linalg.solve(A + 1e-12 * np.trace(A) * np.eye(p), h))
    except np.linalg.LinAlgError:
        d_glob = 0.0
    logn = np.log(max(prob.n_eff, 2.0))
    best = (d_glob - p * logn, None)
    if allow_window and cand.windowable:
        sw = scan_window(xs, es, ws, min_len)
        if sw is not None:
            i0, i1, d = sw
            if (i1 - i0) < 0.9 * prob.n and excited(cand, (i0, i1)):
                g = d - (p + 2) * logn
                if g > best[0]:
                    best = (g, (i0, i1))
    return best


def excited(term: E.Term, window: tuple, rel: float = 0.1) -> bool:
    """
    Return True when the term's regressors vary inside ``window`` (sample indices).

    A scale acting in a stretch where its regressor stays nearly constant (a
    gravity component at rest) cannot be told from an offset there, so it is
    not offered in that window: the regressor's spread, less what its own
    sample-to-sample noise explains (``var(diff x) / 2``), must reach ``rel``
    of its RMS. Constant regressors (offsets) always pass.
    """
    i0, i1 = window
    for X in term.cols.values():
        seg = np.nan_to_num(X[i0:i1])
        for j in range(seg.shape[1]):
            x = seg[:, j]
            if np.ptp(x) == 0 or x.size < 3:
                continue
            spread = float(np.var(x)) - 0.5 * float(np.var(np.diff(x)))
            if spread < (rel ** 2) * float(np.mean(x * x)):
                return False
    return True


def _steady(term: E.Term) -> E.Term:
    """Return ``term`` with each regressor column held at its mean inside the term's window."""
    i0, i1 = term.window
    cols = {}
    for f, X in term.cols.items():
        Y = np.array(X, dtype=float)
        Y[i0:i1] = np.nanmean(Y[i0:i1], axis=0)
        cols[f] = Y
    return term.with_cols(cols, term.group)


def _model_with(sel: list, cand: E.Term) -> list:
    return [t for t in sel if t.group != cand.group] + [cand]


def forward_select(prob: Problem, cands: list, margin: float, min_len: int,
                   max_terms: int = 8, n_exact: int = 4) -> tuple[list, Fit]:
    """Greedy forward selection of terms by the score; returns (selected terms, their fit)."""
    sel: list = []
    cur = fit(prob, sel)
    s_cur = score(prob, cur)
    for _ in range(max_terms):
        res = _residuals(prob, cur)
        screened = []
        for c in cands:
            if any(c is t for t in sel):
                continue
            g, win = _screen(prob, c, res, min_len, True)
            if np.isfinite(g):
                screened.append((g, c, win))
        screened.sort(key=lambda z: -z[0])
        best = None
        for g, c, win in screened[:n_exact]:
            for w in ([None, win] if win is not None else [None]):
                model = _model_with(sel, c.with_window(w))
                f = fit(prob, model)
                # a window must beat the global effect by a further margin
                s = score(prob, f) + (margin if w is not None else 0.0)
                if best is None or s < best[0]:
                    best = (s, model, f)
        if best is None or s_cur - best[0] <= margin:
            break
        sel, cur = best[1], best[2]
        s_cur = score(prob, cur)
    return sel, cur


def backward_eliminate(prob: Problem, sel: list, margin: float) -> list:
    """Drop, one at a time, terms whose removal costs less than ``margin`` in score."""
    out = list(sel)
    while out:
        base = score(prob, fit(prob, out))
        gains = [score(prob, fit(prob, out[:i] + out[i + 1:])) - base for i in range(len(out))]
        i = int(np.argmin(gains))
        if gains[i] >= margin:
            break
        out.pop(i)
    return out


def unexcited_windows(prob: Problem, sel: list, frac: float = 0.03) -> list:
    """
    Make windowed terms global when their regressor hardly acts outside the window.

    When less than ``frac`` of a term's regressor energy lies outside its
    window, the recording cannot tell "acts only here" from "acts always";
    the simpler claim (no window) is reported.
    """
    out = list(sel)
    for i, t in enumerate(out):
        if t.window is None:
            continue
        i0, i1 = t.window
        tot = inside = 0.0
        for f in t.cols:
            if f not in prob.fields:
                continue
            X = _mcols(prob, t, f)
            e = np.einsum('ij,ij->i', X, X) * prob.w[f]
            tot += float(e.sum())
            inside += float(e[i0:i1].sum())
        if tot > 0 and (tot - inside) < frac * tot:
            out[i] = t.with_window(None)
    return out


def refine_windows(prob: Problem, sel: list, min_len: int) -> list:
    """Re-locate each windowed term's window given all the other terms."""
    out = list(sel)
    for i, t in enumerate(out):
        if t.window is None:
            continue
        others = out[:i] + out[i + 1:]
        res = _residuals(prob, fit(prob, others))
        fs = [f for f in t.cols if f in prob.fields]
        glob = t.with_window(None)
        sw = scan_window([term_cols(glob, f, prob) for f in fs],
                         [res[f] * prob.sw[f] for f in fs], [prob.w[f] for f in fs], min_len)
        if sw is not None and sw[1] - sw[0] < 0.9 * prob.n and excited(t, sw[:2]):
            cand = out[:i] + [t.with_window((sw[0], sw[1]))] + out[i + 1:]
            if score(prob, fit(prob, cand)) <= score(prob, fit(prob, out)):
                out = cand
    return out


def _rotation_exact(prob: Problem, theta: np.ndarray, term: E.Term) -> dict:
    """Return the exact change of the rotated channels for a mounting tilt or rotation."""
    pt = prob.pt
    out = {}
    gyro = term.effect == 'imu_mounting_rotation' or term.meta.get('gyro')
    kinds = ['linear_acceleration'] + (['angular_velocity'] if gyro else [])
    yaw = float(theta[2]) if theta.size > 2 else 0.0
    for kind in kinds:
        fs = tuple(f'{kind}.{a}' for a in 'xyz')
        v = tuple(np.nan_to_num(pt.sim_reg[f]) for f in fs)
        rot = E.rotate(v, float(theta[0]), float(theta[1]), yaw)
        out.update({f: r - x for f, r, x in zip(fs, rot, v)})
    return out


def _linearise(prob: Problem, term: E.Term, theta: np.ndarray) -> E.Term:
    """Return the term linearised at ``theta``: exact offset + Jacobian columns."""
    off = _rotation_exact(prob, theta, term)
    h = 1e-6
    jac = []
    for j in range(theta.size):
        step = np.zeros(theta.size)
        step[j] = h
        jac.append(_rotation_exact(prob, theta + step, term))
    cols = {f: np.column_stack([(jj[f] - off[f]) / h for jj in jac]) for f in off}
    meta = dict(term.meta)
    meta['offset'] = off
    meta['theta'] = np.asarray(theta, float)
    return E.Term(term.effect, term.topic, cols, term.group, term.channel, term.windowable,
                  term.window, meta)


def refine_nonlinear(prob: Problem, sel: list, iters: int = 8) -> list:
    """Gauss-Newton refinement of mounting tilts and rotations with their exact models."""
    nl = [i for i, t in enumerate(sel) if t.effect in NONLINEAR]
    if not nl:
        return sel
    f0 = fit(prob, sel)
    out = list(sel)
    for i in nl:
        t = out[i]
        b = f0.betas[i]
        theta = (np.asarray(t.meta['theta'], float) + b) if 'theta' in t.meta \
            else np.array(b, float)
        out[i] = _linearise(prob, t, theta)
    for _ in range(iters):
        f = fit(prob, out)
        step = 0.0
        for i in nl:
            t = out[i]
            step = max(step, float(np.max(np.abs(f.betas[i]))))
            out[i] = _linearise(prob, t, t.meta['theta'] + f.betas[i])
        if step < 1e-10:
            break
    return out


def alternatives(prob: Problem, sel: list, cands: list, min_len: int,
                 alt_margin: float, only: Optional[int] = None) -> dict:
    """
    Return {index of selected term: [(candidate, its fit, score difference)]}.

    A candidate is an alternative to a selected term when it acts on no
    channel the selected term leaves alone (so it competes for the same
    residual, not for others), names a different effect, and the model with
    it in place of the selected term (in its own window or the selected
    term's) scores within ``alt_margin``. With
    ``only``, the alternatives of that selected term alone.
    """
    base = score(prob, fit(prob, sel))
    out: dict = {}
    for i, t in enumerate(sel):
        if only is not None and i != only:
            continue
        others = sel[:i] + sel[i + 1:]
        res = _residuals(prob, fit(prob, others))
        chans = set(t.cols)
        for c in cands:
            # a refinement of the same quantity (an offset that drifts) is not another physics
            if c.effect == t.effect or c.group == t.group or not set(c.cols) <= chans:
                continue
            if any(c.group == o.group for o in others):
                continue
            g, win = _screen(prob, c, res, min_len, t.window is not None)
            tried = [c.with_window(win)]
            # in the selected term's window a gain whose regressor stays constant there (so
            # never offered as a window of its own, see excited) is the offset's twin: its
            # regressor read as its mean (what varies is the simulation's own noise)
            if (t.window is not None and t.window != win and c.windowable
                    and not excited(c, t.window)):
                tried.append(_steady(c.with_window(t.window)))
            best = None
            for cw in tried:
                model = others + [cw]
                f = fit(prob, model)
                d = float(score(prob, f) - base)
                if best is None or d < best[2]:
                    best = (cw, f, d)
            if best[2] < alt_margin:
                out.setdefault(i, []).append(best)
        if i in out:
            out[i].sort(key=lambda z: z[2])
    return out
