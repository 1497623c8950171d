# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Wheel-speed saturation of a differential drive (:mod:`.drive` fits the axes first).

The faster wheel's rim speed ``|v| + h |omega|`` (m/s, ``h`` the half track)
cannot exceed a limit ``L``; above it both wheels are scaled alike, so the
forward speed and the turn rate shrink together and the path keeps its
curvature (the simulator's ``drive.max_wheel_speed``, there in wheel rad/s):

    s = min(1, L / (|v_hat| + h |omega_hat|)),   v = s v_hat,   omega = s omega_hat

``v_hat`` and ``omega_hat`` are the two axes' chains. The cap is fitted on
both axes together (each weighted by its residual variance), judged by the
held-out test of the chain's other parts, and when it passes the axes are
fitted again on the real motion divided by ``s`` (a drive held at its cap
most of the time would otherwise show no lag).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from robot_calib.mismatch import latency as L
from robot_calib.mismatch.findings import confidence

HALVES = np.geomspace(0.05, 0.6, 12)  # m, half tracks searched
QUANTILES = (50.0, 60.0, 70.0, 80.0, 85.0, 90.0, 94.0, 97.0, 99.0)  # of |v| + h |omega|
MIN_SCALE = 0.3  # the real motion is divided by s no further than this
ROUNDS = 3  # the axes and the cap fitted in turn
HALF_TOLERANCE = 0.05  # a half track 40 % off fitting within this share is not told apart
STRAIGHT = 0.8  # share of the capped rim speed from the forward speed: a straight-line cap


@dataclass
class WheelCap:
    """The cap: rim speed ``limit`` (m/s) of the faster wheel, ``half`` track (m)."""

    limit: float
    half: float
    half_known: bool = True  # False: the cap bound only while driving nearly straight


def scale(v: np.ndarray, w: np.ndarray, cap: Optional[WheelCap]) -> np.ndarray:
    """Return the factor ``s`` (1 where the faster wheel is under the cap)."""
    if cap is None:
        return np.ones(np.shape(v))
    fastest = np.abs(v) + cap.half * np.abs(w)
    with np.errstate(divide='ignore', invalid='ignore'):
        s = np.where(fastest > cap.limit, cap.limit / np.maximum(fastest, 1e-12), 1.0)
    return np.clip(s, MIN_SCALE, 1.0)


def fit(vh: np.ndarray, wh: np.ndarray, yv: np.ndarray, yw: np.ndarray,
        w: np.ndarray) -> tuple[Optional[WheelCap], float, float]:
    """
    Return (cap, weighted SSE with it, without it) on the samples ``w`` (grids).

    Each axis is weighted by the inverse of its residual variance without the cap.
    """
    rv, rw = (yv - vh)[w], (yw - wh)[w]
    wv = 1.0 / max(float(np.mean(rv * rv)), 1e-12)
    ww = 1.0 / max(float(np.mean(rw * rw)), 1e-12)
    base = wv * float(rv @ rv) + ww * float(rw @ rw)
    best = (base, None)
    for half in HALVES:
        fastest = np.abs(vh[w]) + half * np.abs(wh[w])
        for lim in np.percentile(fastest, QUANTILES):
            cap = WheelCap(float(lim), float(half))
            s = scale(vh[w], wh[w], cap)
            ev, ew = yv[w] - s * vh[w], yw[w] - s * wh[w]
            sse = wv * float(ev @ ev) + ww * float(ew @ ew)
            if sse < best[0]:
                best = (sse, cap)
    cap = best[1]
    if cap is not None:
        cap = _refine(vh[w], wh[w], yv[w], yw[w], wv, ww, cap)
        s = scale(vh[w], wh[w], cap)
        ev, ew = yv[w] - s * vh[w], yw[w] - s * wh[w]
        best = (wv * float(ev @ ev) + ww * float(ew @ ew), cap)
    return best[1], best[0], base


def _refine(vh, wh, yv, yw, wv, ww, cap: WheelCap) -> WheelCap:
    """Return ``cap`` with limit and half track refined between grid points (log scale)."""
    from scipy.optimize import minimize

    def sse(x: np.ndarray) -> float:
        s = scale(vh, wh, WheelCap(math.exp(x[0]), math.exp(x[1])))
        ev, ew = yv - s * vh, yw - s * wh
        return wv * float(ev @ ev) + ww * float(ew @ ew)

    x0 = np.log([cap.limit, cap.half])
    r = minimize(sse, x0, method='Nelder-Mead', options={'xatol': 1e-4, 'fatol': 1e-9})
    return WheelCap(*map(float, np.exp(r.x))) if r.fun < sse(x0) else cap


def _half_known(vh, wh, yv, yw, w: np.ndarray, cap: WheelCap) -> bool:
    """
    Return True when the data tell the half track: moving it by 40 % either way worsens the fit.

    Each other half track gets its own limit; a cap that binds only while the
    robot drives nearly straight fits as well with any (the fit changes by
    under :data:`HALF_TOLERANCE` of its residual).
    """
    from scipy.optimize import minimize_scalar

    vh, wh, yv, yw = vh[w], wh[w], yv[w], yw[w]

    def sse(c: WheelCap) -> tuple:
        s = scale(vh, wh, c)
        return yv - s * vh, yw - s * wh
    ev, ew = sse(cap)
    wv, ww = 1.0 / max(float(ev @ ev) / ev.size, 1e-12), 1.0 / max(float(ew @ ew) / ew.size,
                                                                   1e-12)
    best = wv * float(ev @ ev) + ww * float(ew @ ew)
    for factor in (0.7, 1.4):
        half = cap.half * factor

        def cost(x: float) -> float:
            a, b = sse(WheelCap(math.exp(x), half))
            return wv * float(a @ a) + ww * float(b @ b)
        r = minimize_scalar(cost, bounds=(math.log(cap.limit / 3), math.log(cap.limit * 3)),
                            method='bounded')
        if r.fun - best < HALF_TOLERANCE * best:
            return False
    return True


def _axes(models: dict, sim_d: dict, wabs, acd, dt: float, gain: bool = True) -> tuple:
    """Return the two axes' chains (forward, turn) on the block grid (``gain``: with it)."""
    from robot_calib.mismatch import drive as D

    V, W = D.V, D.W
    return (D.predict(D._filled(sim_d[V]), wabs, dt, models[V], acmd=acd, gain=gain),
            D.predict(D._filled(sim_d[W]), None, dt, models[W], gain=gain))


def _refit(chosen: dict, sim_d: dict, real_d: dict, s, wabs, acd, w: np.ndarray, dt: float,
           prm) -> dict:
    """Return the chosen axes' parts fitted again on the samples ``w`` of the real / ``s``."""
    from robot_calib.mismatch import drive as D

    return {f: D.fit_axis(D._filled(sim_d[f]), wabs if f == D.V else None,
                          np.nan_to_num(real_d[f]) / s, w, dt, prm.drive_max_dead_time,
                          chosen[f][0].parts, refine=True, acmd=acd if f == D.V else None)
            for f in (D.V, D.W)}


def judge(sim_d: dict, real_d: dict, wabs, acd, held: np.ndarray, piece: int, dt: float,
          prm, late: frozenset, period: float, chosen: dict) -> Optional[tuple]:
    """
    Return (cap, the axes chosen again on the real motion divided by s, test) or None.

    ``chosen``: per field (model, stats, fitted samples) of :func:`.drive._choose_axis`.
    The cap and the axes' named parts are fitted on the fitted part of the time
    line; the held-out pieces' log ratio of the weighted SSE without / with the
    cap passes Student's t at ``prm.drive_alpha`` on the pieces where it binds.
    """
    from robot_calib.mismatch import drive as D

    V, W = D.V, D.W
    if V not in chosen or W not in chosen:
        return None
    yv, yw = np.nan_to_num(real_d[V]), np.nan_to_num(real_d[W])
    ok = chosen[V][2] & chosen[W][2]
    fitw = ok & ~held
    models = {f: chosen[f][0] for f in (V, W)}
    # the axes' dynamics without their gains: a gain fitted without the cap has taken part of
    # it (a drive capped half the time reads as one that settles 20-40 % short)
    vh, wh = _axes(models, sim_d, wabs, acd, dt, gain=False)
    cap, with_cap, without = fit(vh, wh, yv, yw, fitw)
    if cap is None or (without - with_cap) < prm.min_improvement * without or \
            np.mean(scale(vh[ok], wh[ok], cap) < 0.99) < 0.02:
        return None
    # the axes chosen again on the real motion divided by the cap's factor, and the cap fitted
    # again on them; the factor always from axes fitted on the fitted part alone (one from
    # axes fitted on all the time line would carry the held-out noise into the next choice)
    for _ in range(ROUNDS):
        s = scale(vh, wh, cap)
        again = {f: D._choose_axis(f, sim_d[f], real_d[f] / s, wabs if f == V else None,
                                   acd if f == V else None, held, piece, dt, prm, f in late,
                                   period) or chosen[f] for f in (V, W)}
        vh, wh = _axes(_refit(again, sim_d, real_d, s, wabs, acd, fitw, dt, prm), sim_d,
                       wabs, acd, dt)
        cap, _, _ = fit(vh, wh, yv, yw, fitw)
        if cap is None:
            return None
    # the test: both models fitted on the fitted part only
    reduced = _refit(chosen, sim_d, real_d, 1.0, wabs, acd, fitw, dt, prm)
    full = _refit(again, sim_d, real_d, scale(vh, wh, cap), wabs, acd, fitw, dt, prm)
    rv, rw = _axes(reduced, sim_d, wabs, acd, dt)
    fv, fw = _axes(full, sim_d, wabs, acd, dt)
    cap, _, _ = fit(fv, fw, yv, yw, fitw)
    if cap is None:
        return None
    s = scale(fv, fw, cap)
    if not _half_known(fv, fw, yv, yw, fitw, cap):
        # a cap met only while driving nearly straight is the top speed, its half track
        # unknown; one met turning in place gives only limit / half: not named
        capped = fitw & (s < 0.99)
        rim = np.abs(fv[capped]) + cap.half * np.abs(fw[capped])
        if not capped.any() or \
                float(np.mean(np.abs(fv[capped]))) < STRAIGHT * float(np.mean(rim)):
            return None
        cap.half_known = False
    test = _heldout(yv, yw, (rv, rw), (fv, fw), s, ok, fitw, held, piece, prm)
    return (cap, again, test) if test else None


def _heldout(yv, yw, reduced: tuple, full: tuple, s: np.ndarray, ok: np.ndarray,
             fitw: np.ndarray, held: np.ndarray, piece: int, prm) -> Optional[tuple]:
    """
    Return the cap's held-out test (z, threshold, pieces, fit RMSEs) when it passes, else None.

    ``reduced``, ``full``: the two axes' chains without and with the cap (its factor ``s``),
    both fitted on ``fitw``; judged on the held-out pieces where the cap binds.
    """
    from robot_calib.mismatch import drive as D

    V, W = D.V, D.W
    (rv, rw), (fv, fw) = reduced, full
    er = {V: yv - rv, W: yw - rw}
    ef = {V: yv - s * fv, W: yw - s * fw}
    wts = {f: 1.0 / max(float(np.mean(er[f][fitw] ** 2)), 1e-12) for f in (V, W)}
    binds = ok & held & (s < 0.99)
    idx = np.flatnonzero(ok & held)
    sse_r = sum(wts[f] * np.bincount(idx // piece, weights=er[f][idx] ** 2,
                                     minlength=s.size // piece + 1) for f in (V, W))
    sse_f = sum(wts[f] * np.bincount(idx // piece, weights=ef[f][idx] ** 2,
                                     minlength=s.size // piece + 1) for f in (V, W))
    has = np.bincount(np.flatnonzero(binds) // piece, minlength=sse_r.size) >= 3
    if has.sum() < 3:
        return None
    dlt = np.log((sse_r[has] + 1e-300) / (sse_f[has] + 1e-300))
    spread = float(np.std(dlt, ddof=1))
    z = float(np.mean(dlt) / (spread / math.sqrt(dlt.size))) if spread > 0 else 0.0
    thr = L.t_quantile(prm.drive_alpha, dlt.size - 1)
    if not z > thr:
        return None
    # the forward speed's residual where the cap binds, without and with it
    fit_rmse = {key: float(np.sqrt(np.mean(e[V][m] ** 2))) if m.any() else None
                for key, e, m in (('rmse_before', er, fitw & (s < 0.99)),
                                  ('rmse_after', ef, fitw & (s < 0.99)),
                                  ('heldout_rmse_before', er, binds),
                                  ('heldout_rmse_after', ef, binds))}
    return z, thr, int(dlt.size), fit_rmse


def finding(topic: str, cap: WheelCap, test: tuple, bound: float) -> dict:
    """Return the cap as reported (``wheel_speed_limit``; ``bound``: the share of time capped)."""
    from robot_calib.mismatch import drive as D

    z, thr, pieces, fit_rmse = test
    # it passed the test at drive_alpha; its strength grows from the 5 % bar, as the axes' parts
    strength = 1.0 - (L.t_quantile(0.05, max(pieces - 1, 1)) / max(z, 1e-12)) ** 2
    return {'channel': f'{topic}.{D.V}', 'effect': 'wheel_speed_limit',
            'parameters': {'limit': cap.limit,
                           'half_track': cap.half if cap.half_known else None},
            'units': {'limit': 'm/s', 'half_track': 'm'}, 'window': None,
            'channels': [f'{topic}.{D.V}', f'{topic}.{D.W}'],
            'explanation': (f"The faster wheel's rim speed is capped at {cap.limit:.3g} m/s "
                            f'(half track {cap.half:.3g} m): where |v| + {cap.half:.3g} |omega| '
                            'would exceed it, speed and turn rate shrink together'
                            if cap.half_known else
                            f'The forward speed is capped at {cap.limit:.3g} m/s (a wheel-speed '
                            'cap met only while driving nearly straight: the half track it '
                            'acts about cannot be told from these data)') +
            f' ({100 * bound:.0f} % of the time). Against '
            f'the same drive without the cap the held-out fit improves (z {z:.1f} > {thr:.1f} '
            f'over {pieces} pieces).',
            'evidence': {'z': z, 'z_threshold': thr, 'blocks': pieces,
                         'test': 'held-out pieces of both axes with and without the cap'},
            'confidence': confidence(max(0.0, min(1.0, strength)), []), 'fit': fit_rmse}
