# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A finding as findings.json holds it: parameters, interval, fit, evidence, confidence.

The confidence of a finding is the evidence that something real is there
times its share among the explanations that fit about as well.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from robot_calib.mismatch import effects as E
from robot_calib.mismatch import select as S
from robot_calib.mismatch.explain import explain
from robot_calib.mismatch.problem import Problem


def evidence(strength: float, fitd: dict, motion: float = 1.0,
             support: Optional[tuple] = None) -> float:
    """
    Return how strongly (0..1) the data say that a finding is real, whatever its name.

    The product of how far the robust statistic clears its bar
    (``1 - bar / statistic``) and the credit of held-out time, by the RMSEs of
    ``fitd`` (in-sample and held-out, before and after the effect): full when
    held-out time confirms at least half of the in-sample improvement, partial
    below. ``motion`` is how much more the effect changes the fitted time than
    the held-out time (the mean squares of its change there, see
    :func:`motion_ratio`): an effect shows in proportion to the motion that
    excites it, so held-out time that happens to move less is not held against
    it. Held-out time too short or too still to tell is no evidence either way:
    given ``support`` (:func:`heldout_support`), the credit is at least the
    probability that the held-out improvement comes from the effect rather
    than from none (equal priors), which is one half when it cannot tell.
    """
    s = float(np.clip(strength, 0.0, 1.0))
    hb, ha = fitd.get('heldout_rmse_before'), fitd.get('heldout_rmse_after')
    ib, ia = fitd.get('rmse_before'), fitd.get('rmse_after')
    gen = 1.0
    if None not in (hb, ha, ib, ia) and ib ** 2 - ia ** 2 > 0:
        gain = hb ** 2 - ha ** 2
        gen = float(np.clip(2.0 * motion * gain / (ib ** 2 - ia ** 2), 0.0, 1.0))
        if support is not None and support[1] > 0:
            expected, se = support
            # log odds of a held-out gain ~ N(expected, se) against ~ N(0, se)
            z = float(np.clip(expected * (gain - 0.5 * expected) / se ** 2, -50.0, 50.0))
            gen = max(gen, 1.0 / (1.0 + float(np.exp(-z))))
        elif support is not None and support[0] == 0.0:
            gen = max(gen, 0.5)  # the effect does not touch held-out time: it cannot tell
    return round(s * gen, 3)


def heldout_support(change: np.ndarray, held: np.ndarray, resid: np.ndarray,
                    phi: float = 1.0) -> tuple[float, float]:
    """
    Return what an effect predicts held-out time to gain, and its standard error.

    The expected gain in mean square is the mean square of the effect's
    ``change`` on the ``held`` samples; the gain measured there varies by
    ``2 sqrt(phi mean(e^2 c^2) / N)`` with ``e`` the ``resid`` left after the
    effect (its variance inflated ``phi`` times by the noise's colour).
    """
    c, e = change[held], resid[held]
    ok = np.isfinite(c) & np.isfinite(e)
    if not ok.any():
        return 0.0, 0.0
    c, e = c[ok], e[ok]
    return (float(np.mean(c * c)),
            2.0 * float(np.sqrt(max(phi, 1.0) * np.mean((e * c) ** 2) / c.size)))


def motion_ratio(change: np.ndarray, fitted: np.ndarray, held: np.ndarray) -> float:
    """
    Return the mean square of an effect's ``change`` on ``fitted`` samples over ``held`` ones.

    Noise in the change (a noisy simulation shifted or scaled) is alike on both
    parts and only pulls the ratio towards 1; it is kept within [0.25, 4].
    """
    a, b = change[fitted], change[held]
    if a.size == 0 or b.size == 0:
        return 1.0
    ms_held = float(np.mean(b * b))
    if ms_held <= 0.0:
        return 1.0
    return float(np.clip(float(np.mean(a * a)) / ms_held, 0.25, 4.0))


def confidence(evidence: float, alt_deltas: list) -> float:
    """
    Return the trust (0..1) in a finding's name: its evidence times its share.

    The share among the explanations that fit about as well is a BIC weight,
    ``1 / (1 + sum exp(-delta / 2))`` over the alternatives (Schwarz 1978).
    """
    alt = 1.0 / (1.0 + sum(float(np.exp(-max(d, 0.0) / 2.0)) for d in alt_deltas))
    return round(evidence * alt, 3)


def term_finding(prob: Problem, final: S.Fit, sel: list, i: int, fitd: dict,
                 test: tuple, alts: list, weighted: Optional[dict] = None,
                 motion: float = 1.0, support: Optional[tuple] = None) -> dict:
    """
    Return the finding of the selected term ``sel[i]`` (contract keys plus evidence).

    :param final: the joint fit of ``sel``
    :param fitd: its held-out fit dict (reported)
    :param test: its robust test ``(W, threshold, blocks)``
    :param alts: the alternatives ``[(term, fit, delta BIC)]``
    :param weighted: the same RMSEs weighted as the fit weighs each sample, which
        judge the evidence (``fitd`` when None)
    :param motion: the effect's change on fitted over held-out time (:func:`motion_ratio`)
    :param support: what it predicts held-out time to gain, and the error of that gain
        (:func:`heldout_support`)
    """
    pt = prob.pt
    t = sel[i]
    params, sds = E.to_params(t, final.betas[i], final.covs[i])
    window = None
    if t.window is not None:
        i0, i1 = t.window
        window = [round(float(pt.t[i0]), 4), round(float(pt.t[min(i1, prob.n) - 1]), 4)]
    base = S.score(prob, final)
    without = S.score(prob, S.fit(prob, sel[:i] + sel[i + 1:]))
    w, thr, kb = test
    fd = {'channel': t.channel, 'effect': t.effect,
          'parameters': {k: float(v) for k, v in params.items()},
          'window': window, 'fit': fitd,
          'explanation': explain(t.effect, params, window, fitd, t.meta),
          'std': sds,
          'ci95': {k: [params[k] - 1.96 * sds[k], params[k] + 1.96 * sds[k]] for k in params},
          'units': dict(zip(E.SPECS[t.effect].params, E.SPECS[t.effect].units)),
          'evidence': {'delta_bic': float(without - base), 'robust_wald': w,
                       'robust_threshold': thr, 'blocks': kb}}
    if len(t.cols) > 1:
        fd['channels'] = [f'{pt.name}.{f}' for f in t.cols]
    if 'source' in t.meta:
        fd['source_channel'] = t.meta['source']
    deltas = []
    if alts:
        fd['alternatives'] = []
        for c, cf, d in alts:
            j = len(cf.terms) - 1
            cp, _ = E.to_params(c, cf.betas[j], cf.covs[j])
            fd['alternatives'].append({
                'effect': c.effect, 'channel': c.channel,
                'parameters': {k: float(v) for k, v in cp.items()}, 'delta_bic': d,
                'separating_motion': E.separating_motion(t.effect, c.effect)})
            deltas.append(d)
        names = ', '.join(sorted({a['effect'] for a in fd['alternatives']}))
        fd['explanation'] += f' This recording cannot clearly tell it from {names}; ' \
            f'{fd["alternatives"][0]["separating_motion"]}.'
    fd['evidence_strength'] = evidence(1.0 - thr / max(w, 1e-12),
                                       fitd if weighted is None else weighted, motion, support)
    fd['confidence'] = confidence(fd['evidence_strength'], deltas)
    return fd


def unsupported(fd: dict, margin: float) -> str:
    """
    Return why a finding does not back what it claims ('' when it does).

    A finding must make the residual smaller where it was fitted and on
    held-out time, each RMSE by at least the fraction ``margin`` of its value
    before; a ``timing_drift`` whose start and end delays do not differ by more
    than twice their combined standard deviation is no drift. ``unexplained``
    findings claim no fit and pass.
    """
    if fd.get('effect') == 'unexplained':
        return ''
    fit = fd.get('fit') or {}
    for part, b, a in (('the fitted part', 'rmse_before', 'rmse_after'),
                       ('held-out time', 'heldout_rmse_before', 'heldout_rmse_after')):
        before, after = fit.get(b), fit.get(a)
        if before is None or after is None or not np.isfinite(before) or not np.isfinite(after):
            continue
        if not after < (1.0 - margin) * before:
            return f'it does not make the residual smaller on {part} (RMSE {before:.4g} -> ' \
                f'{after:.4g})'
    if fd.get('effect') == 'timing_drift':
        p, s = fd.get('parameters', {}), fd.get('std', {})
        diff = abs(p.get('tau_end', 0.0) - p.get('tau_start', 0.0))
        sd = float(np.hypot(s.get('tau_start', 0.0), s.get('tau_end', 0.0)))
        if not diff > 2.0 * sd or diff == 0.0:
            return f'its start and end delays do not differ ({p.get("tau_start", 0.0):.4g} s, ' \
                f'{p.get("tau_end", 0.0):.4g} s, standard deviation {sd:.2g} s): no drift'
    return ''
