# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Lost returns of a scanner beam by beam: a rate stepping up beyond a range or an incidence.

A beam the simulated scan returns and the real one does not is a loss
(``y = 1``). Two models of the extra loss over the simulation's own ``q``:

    P(loss) = p0 + rate [r_sim > beyond]         (range, m)
    P(loss) = p0 + rate [inc_sim > incidence]    (incidence, rad from the surface normal)

where ``inc_sim`` is the incidence of the simulated beam, the surface's
direction taken from the neighbouring beams' hit points of the simulated scan
(the simulator's own rule, :func:`robot_calib.core.scan_incidence.incidence`, on the
side it picks, but as the chord to the ``SPAN``-th beam when the beams between
lie within 3 noise sigma of it: one beam's chord turned by the range noise
makes grazing beams look less grazing, |cos| folded at 0, and the step found
low and weak; a chord k beams long turns k times less). Each
step is fitted by maximum likelihood (Bernoulli) over candidate thresholds
and judged alone: a rate above a floor, z = rate / its block-jackknife
standard error >= Z_MIN, and a lower Brier score on the held-out chunks.
When both pass, the one with the higher held-out log-likelihood is kept; when
the whole recording's log-likelihoods differ by less than ``TELL`` (a
deviance of 10: "very strong" on the scale of Kass and Raftery, J. Am. Stat.
Assoc. 90, 1995; both models have the same number of parameters, so this is
their BIC difference) or the held-out part disagrees, the other is listed
under ``alternatives``.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from robot_calib.core.scan_incidence import incidence

SPAN = 5

__all__ = ['dropout_findings']

TELL = 10.0
FLOOR_RATE = 0.02  # as the other beam effects: a floor and z >= 5 (lidar_beams)


def _ll(k: np.ndarray, n: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Return the Bernoulli log-likelihood of ``k`` losses in ``n`` beams at rate ``p``."""
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return k * np.log(p) + (n - k) * np.log(1 - p)


def _step(r: np.ndarray, y: np.ndarray, q: float, cands: np.ndarray) -> tuple:
    """
    Return (rate, threshold, log-likelihood) of the best step of extra loss beyond a threshold.

    ``r`` is the covariate (range m, or incidence rad). Threshold 0 is a rate at
    every value above the simulation's own loss ``q``; otherwise the rate is
    the loss beyond minus the loss below (at least 50 beams beyond). Counts
    from the beams sorted by the covariate.
    """
    order = np.argsort(r, kind='stable')
    rs, cum = r[order], np.r_[0.0, np.cumsum(y[order])]
    n, tot = float(r.size), float(cum[-1])
    c = np.asarray(cands, float)
    i0 = np.searchsorted(rs, c, side='left')
    n1, k1 = n - i0, tot - cum[i0]
    n0, k0 = i0.astype(float), cum[i0]
    p1 = np.maximum(k1 / np.maximum(n1, 1), q)
    p0 = np.where(n0 > 0, k0 / np.maximum(n0, 1), q)
    ll = _ll(k1, n1, p1) + _ll(k0, n0, p0)
    ll = np.where(n1 >= 50, ll, -np.inf)
    best = (max(tot / max(n, 1) - q, 0.0), 0.0, -np.inf)
    if n >= 50:
        p = max(tot / n, q)
        best = (p - q, 0.0, float(_ll(np.array(tot), np.array(n), np.array(p))))
    if c.size and np.isfinite(ll).any():
        k = int(np.argmax(ll))
        if ll[k] > best[2] + 1e-9:
            best = (float(p1[k] - p0[k]), float(c[k]), float(ll[k]))
    return best


def _cands(r: np.ndarray) -> np.ndarray:
    """
    Return candidate thresholds: every percent, finer towards both ends.

    Down to 50 beams from either end, so a step near the smallest or the
    largest values is found where it is.
    """
    n = r.size
    if not n:
        return np.array([])
    ends = np.geomspace(50, max(n / 2, 51), 40) if n > 100 else np.array([])
    pos = np.unique(np.r_[np.linspace(0.01, 0.99, 99) * n, ends, n - ends].astype(int))
    return np.unique(np.sort(r)[np.clip(pos, 0, n - 1)])


def _pred(r: np.ndarray, y: np.ndarray, q: float, rate: float, thr: float) -> np.ndarray:
    """Return each beam's loss probability under the step fitted (rate, threshold)."""
    below = r < thr
    base = float(y[below].mean()) if thr > 0 and below.any() else q
    return np.where(r >= thr, base + rate, base)


def _judge(r: np.ndarray, y: np.ndarray, q: float, bk: np.ndarray, hd: np.ndarray,
           jack: Callable) -> dict | None:
    """Return the step fitted on covariate ``r`` with its tests, or None when not supported."""
    cands = _cands(r)
    rate, thr, _ = _step(r, y, q, cands)
    if rate < FLOOR_RATE:
        return None
    sd = float(jack(lambda m: np.array(_step(r[m], y[m], q, np.array([thr]))[:1]), bk)[0])
    z = rate / max(sd, 1e-9)
    if z < 5.0:
        return None
    rf, tf, _ = _step(r[~hd], y[~hd], q, cands)
    # the held-out chunks are predicted from the fitted part only (its level below the step)
    below = r[~hd] < tf
    p0 = float(y[~hd][below].mean()) if tf > 0 and below.any() else q
    pred_all = np.where(r >= tf, p0 + rf, p0)
    res = [float(np.mean((y[m] - (p if np.ndim(p) == 0 else p[m])) ** 2))
           for p in (q, pred_all) for m in (~hd, hd)]
    if not res[3] < res[1]:
        return None
    full = _pred(r, y, q, rate, thr)
    pc = np.clip(pred_all[hd], 1e-6, 1 - 1e-6)
    pa = np.clip(full, 1e-6, 1 - 1e-6)
    return {'rate': float(rate), 'thr': float(thr), 'sd': sd, 'z': float(z), 'res': res,
            'held_ll': float(np.sum(y[hd] * np.log(pc) + (1 - y[hd]) * np.log(1 - pc))),
            'll': float(np.sum(y * np.log(pa) + (1 - y) * np.log(1 - pa)))}


def _conf_z(z: float) -> float:
    return float(1.0 - 0.5 ** ((max(z, 0.0) / 5.0) ** 2.1))


def dropout_findings(rs: np.ndarray, rr: np.ndarray, ang: np.ndarray, blk_s: np.ndarray,
                     held_s: np.ndarray, topic: str, jack: Callable, notes: list,
                     sim_noise: float = 0.01) -> list:
    """
    Return the ``dropout_rate`` finding of paired scans (a list of at most one).

    ``rs``, ``rr``: simulated and real ranges (S, B) (m, NaN: no return);
    ``ang``: beam angles (rad); ``blk_s``, ``held_s``: each scan's jackknife block
    and whether it is held out; ``jack(fun, blocks)``: the block jackknife;
    ``sim_noise``: the simulated scan's range noise (m), 3 of which keep a chord
    of the incidence on one surface.
    """
    sim_ok = np.isfinite(rs)
    y = (~np.isfinite(rr))[sim_ok].astype(float)
    rows = np.nonzero(sim_ok)[0]
    bk, hd = blk_s[rows], held_s[rows]
    q = float(np.mean(~np.isfinite(rs)[np.isfinite(rr)])) if np.isfinite(rr).any() else 0.0
    # the simulator's rule on the simulated scan: no return is +inf there
    inc = incidence(np.where(sim_ok, rs, np.inf), np.broadcast_to(ang, rs.shape), SPAN,
                    max(3.0 * sim_noise, 0.01))[sim_ok]
    fits = {'beyond': _judge(rs[sim_ok], y, q, bk, hd, jack),
            'incidence': _judge(inc, y, q, bk, hd, jack)}
    if fits['incidence'] is not None and fits['incidence']['thr'] <= 0.0:
        fits['incidence'] = None  # a rate at every incidence is the same as at every range
    kept = {k: v for k, v in fits.items() if v is not None}
    if not kept:
        return []
    kind = max(kept, key=lambda k: kept[k]['held_ll'])
    f = kept[kind]
    other = 'incidence' if kind == 'beyond' else 'beyond'
    alt = kept.get(other)
    if alt is not None and (f['ll'] - alt['ll']) * 2.0 >= TELL:
        notes.append(f'{topic}: lost returns by {"range" if kind == "beyond" else "incidence"} '
                     f'rather than {"incidence" if kind == "beyond" else "range"} (deviance '
                     f'{2.0 * (f["ll"] - alt["ll"]):.0f} on all beams)')
        alt = None
    rate, thr = f['rate'], f['thr']
    if kind == 'beyond':
        where = f'beyond {thr:.1f} m' if thr > 0 else 'at every range'
    else:
        where = f'at incidences beyond {math.degrees(thr):.0f} deg from the surface normal'
    res = f['res']
    out = {'channel': f'{topic}.ranges', 'effect': 'dropout_rate',
           'parameters': {'rate': rate, kind: thr},
           'std': {'rate': f['sd']}, 'window': None,
           'fit': {'rmse_before': res[0], 'rmse_after': res[2], 'heldout_rmse_before': res[1],
                   'heldout_rmse_after': res[3], 'measure': 'Brier score of a lost beam'},
           'confidence': _conf_z(f['z']), 'evidence': {'z': f['z'], 'sim_loss': q},
           'explanation': f'{rate:.0%} more real beams return nothing {where} where the '
           'simulation sees a surface.'}
    if alt is not None:
        out['alternatives'] = [{
            'effect': 'dropout_rate', 'channel': f'{topic}.ranges',
            'parameters': {'rate': alt['rate'], other: alt['thr']},
            'delta_bic': float(2.0 * (f['ll'] - alt['ll'])),
            'separating_motion': 'scans where range and incidence vary apart (near surfaces '
            'seen at grazing angles, far ones head-on) tell them apart'}]
        out['explanation'] += (' A step by ' + ('incidence' if other == 'incidence' else
                                                'range') + ' explains the losses about as well.')
    return [out]
