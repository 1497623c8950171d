# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What the library leaves unexplained: an honest ``unexplained`` finding instead of a wrong name.

After the effects found are removed, a channel's residual should be noise.
Structure slower than the noise is told from noise without a model of the
noise spectrum, by comparing the spread of block means at two scales (an
Allan-variance-like ratio): for noise whose correlation is shorter than a
quarter block, the variance of the means of blocks of ``m`` samples is a
quarter of that of quarter blocks, ``var(mean_m) = var(mean_(m/4)) / 4``;
slow structure keeps the block means apart, up to ``var(mean_m) =
var(mean_(m/4))``. The ratio ``4 var(mean_m) / var(mean_(m/4))`` is about 1 for
noise and up to 4 for structure; the excess variance
``var(mean_m) - var(mean_(m/4)) / 4`` (scaled back to the whole) is the size of
what is left.

The finding names where it acts (the windows where the residual is beyond
noise), how large it is (RMS, channel units) and what it follows best among
the forward speed, the acceleration, the turn rate, the simulated channel
itself and time (correlation of the slowly varying parts). It is never counted
as a physical effect.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from robot_calib.mismatch import select as S
from robot_calib.mismatch.explain import unexplained as sentence
from robot_calib.mismatch.locate import active_windows, moving_average
from robot_calib.mismatch.problem import Problem

RATIO_BAR = 2.0
"""Two-scale variance ratio above which a residual holds structure (1 for noise, up to 4)."""
MIN_EXCESS = 0.5
"""Least size of an unexplained structure, in units of the channel's noise level."""
MIN_CORR = 0.3
"""Least correlation for naming the signal an unexplained residual follows."""


def _block_means(x: np.ndarray, m: np.ndarray, edges: np.ndarray) -> np.ndarray:
    s = np.add.reduceat(np.where(m, x, 0.0)[:edges[-1]], edges[:-1])
    c = np.add.reduceat(m[:edges[-1]].astype(float), edges[:-1])
    return np.where(c > 0.5 * np.diff(edges), s / np.maximum(c, 1.0), np.nan)


def structure(e: np.ndarray, m: np.ndarray, edges: np.ndarray) -> tuple[float, float]:
    """
    Return (two-scale ratio, excess RMS) of a residual ``e`` (channel units) on ``edges``.

    :param e: residual after the effects found
    :param m: valid samples
    :param edges: block boundaries (sample indices)
    """
    fine = np.unique(np.concatenate([np.linspace(a, b, 5).astype(int)
                                     for a, b in zip(edges[:-1], edges[1:])]))
    big = _block_means(e, m, edges)
    small = _block_means(e, m, fine)
    big, small = big[np.isfinite(big)], small[np.isfinite(small)]
    if big.size < 4 or small.size < 16:
        return 1.0, 0.0
    vb, vs = float(np.var(big)), float(np.var(small))
    if vs <= 0:
        return 1.0, 0.0
    ratio = 4.0 * vb / vs
    # the structure's variance: slow enough that every quarter block carries it whole
    excess = max(0.0, (vb - vs / 4.0) * 4.0 / 3.0)
    return ratio, float(np.sqrt(excess))


def _follows(e: np.ndarray, m: np.ndarray, signals: dict, width: int) -> Optional[tuple]:
    """Return (name, correlation) of the signal the slow residual follows best, or None."""
    slow = moving_average(np.where(m, e, 0.0), width)
    best = None
    for name, x in signals.items():
        if x is None:
            continue
        xs = moving_average(np.nan_to_num(x), width)[m]
        ys = slow[m]
        sx, sy = float(np.std(xs)), float(np.std(ys))
        if sx <= 0 or sy <= 0:
            continue
        c = float(np.mean((xs - xs.mean()) * (ys - ys.mean())) / (sx * sy))
        if abs(c) >= MIN_CORR and (best is None or abs(c) > abs(best[1])):
            best = (name, c)
    return best


def _signals(prob: Problem, f: str, aux: dict) -> dict:
    pt = prob.pt
    v = aux.get('v')
    acc = aux.get('acmd')
    if acc is None and v is not None:
        acc = np.gradient(v, pt.t)
    return {'speed': v, 'acceleration': acc, 'turn rate': aux.get('omega'),
            f'the simulated {f}': pt.sim_reg.get(f), 'time': pt.t}


def unexplained(prob: Problem, final: S.Fit, aux: dict, edges: np.ndarray,
                implausible: list) -> Optional[dict]:
    """
    Return one ``unexplained`` finding for a topic, or None when its residual is noise.

    :param prob: the topic's (aligned) residual problem
    :param final: the fit of the effects found (with contributions)
    :param aux: simulated speed ``v``, turn rate ``omega``, acceleration ``acmd``
    :param edges: block boundaries (sample indices)
    :param implausible: [(term, parameters)] fitted far beyond a physical value
    """
    pt = prob.pt
    per = {}
    for f in prob.fields:
        e = prob.r[f] - final.contrib.get(f, 0.0)
        ratio, excess = structure(e, prob.mask[f], edges)
        scale = float(np.sqrt(np.mean(np.nan_to_num(pt.sim[f][prob.mask[f]]) ** 2)))
        if ratio >= RATIO_BAR and excess >= MIN_EXCESS * prob.sigma[f] and \
                excess > 1e-4 * scale:
            per[f] = (excess, ratio, e)
    bad = {t.channel[len(pt.name) + 1:]: (t, p) for t, p in implausible}
    if not per and not bad:
        return None
    if per:
        f = max(per, key=lambda k: per[k][0] / prob.sigma[k])
        excess, ratio, e = per[f]
    else:
        f = next(iter(bad))
        e = prob.r[f] - final.contrib.get(f, 0.0)
        ratio, excess = structure(e, prob.mask[f], edges)
        excess = max(excess, float(np.sqrt(np.mean(e[prob.mask[f]] ** 2))))
    m = prob.mask[f]
    width = max(3, int(np.median(np.diff(edges)) // 4))
    corr = _follows(e, m, _signals(prob, f, aux), width)
    wins = active_windows(pt.t, e, m, prob.sigma[f], prob.phi[f])
    span = None
    if wins and (wins[-1][1] - wins[0][0]) < 0.9 * (pt.t[-1] - pt.t[0]):
        span = [round(float(wins[0][0]), 4), round(float(wins[-1][1]), 4)]
    channel = f'{pt.name}.{f}'
    text = sentence(channel, excess, prob.sigma[f], corr, span)
    if f in bad:
        t, p = bad[f]
        desc = ', '.join(f'{k} = {v:.3g}' for k, v in p.items())
        text += f' The nearest named effect, {t.effect} ({desc}), is far beyond a physical ' \
            'value, so it is not reported as one.'
    return {'channel': channel, 'effect': 'unexplained',
            'parameters': {'rms': excess, 'correlates_with': corr[0] if corr else 'none'},
            'window': span, 'explanation': text,
            'fit': {'rmse_before': float(np.sqrt(np.mean(e[m] ** 2))), 'rmse_after': None,
                    'heldout_rmse_before': None, 'heldout_rmse_after': None},
            'channels': {f'{pt.name}.{k}': v[0] for k, v in per.items()},
            'evidence': {'two_scale_ratio': ratio, 'correlation': corr[1] if corr else None,
                         'noise': prob.sigma[f]},
            'confidence': round(float(np.clip((ratio - 1.0) / 3.0, 0.0, 1.0)), 3)}
