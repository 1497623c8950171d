# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Wheel-speed saturation of a differential drive (:mod:`.drive` fits the axes first).

The faster wheel's rim speed ``|v| + h |omega|`` (m/s, ``h`` the half track)
cannot exceed a limit ``L``; above it both wheels are scaled alike, so the
forward speed and the turn rate shrink together and the path keeps its
curvature (the simulator's ``drive.max_wheel_speed``, there in wheel rad/s):

    s = min(1, L / (|v_hat| + h |omega_hat|)),   v = s v_hat,   omega = s omega_hat

``v_hat`` and ``omega_hat`` are the two axes' chains. On a joint-state topic
with two wheel rates the same cap acts on the wheels' own chains, the load the
faster wheel's rate and ``W`` in rad/s (exactly ``drive.max_wheel_speed``; no
half track):

    s = min(1, W / max(|wl_hat|, |wr_hat|)),   wl = s wl_hat,   wr = s wr_hat

The cap is fitted on the channels together (each weighted by its residual
variance), judged by the held-out test of the chain's other parts, and when
it passes the channels are fitted again on the real motion divided by ``s``
(a drive held at its cap most of the time would otherwise show no lag).
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
SIDE = 0.1  # two wheels: each the faster one in at least this share of the capped time


@dataclass
class WheelCap:
    """The cap: ``limit`` of the faster wheel (rim m/s; rad/s on wheel rates), ``half`` (m)."""

    limit: float
    half: Optional[float]  # None: a cap on two wheels' rates (no half track)
    half_known: bool = True  # False: the cap bound only while driving nearly straight


def load(xs: tuple, half: Optional[float]) -> np.ndarray:
    """Return the faster wheel's speed: ``|v| + half |omega|`` (m/s), or max |x_i| (half None)."""
    if half is None:
        return np.max(np.abs(np.vstack(xs)), axis=0)
    return np.abs(xs[0]) + half * np.abs(xs[1])


def factor(xs: tuple, cap: Optional[WheelCap]) -> np.ndarray:
    """Return the factor ``s`` of channels ``xs`` (1 where the faster wheel is under the cap)."""
    if cap is None:
        return np.ones(np.shape(xs[0]))
    fastest = load(xs, cap.half)
    with np.errstate(divide='ignore', invalid='ignore'):
        s = np.where(fastest > cap.limit, cap.limit / np.maximum(fastest, 1e-12), 1.0)
    return np.clip(s, MIN_SCALE, 1.0)


def _wsse(xs: tuple, ys: tuple, wts: list, cap: Optional[WheelCap]) -> float:
    """Return the weighted SSE of the channels ``ys`` against ``s xs``."""
    s = factor(xs, cap)
    return sum(wt * float((y - s * x) @ (y - s * x)) for wt, x, y in zip(wts, xs, ys))


def fit(hats: tuple, ys: tuple, w: np.ndarray,
        wheels: bool = False) -> tuple[Optional[WheelCap], float, float]:
    """
    Return (cap, weighted SSE with it, without it) on the samples ``w`` (grids).

    ``hats``: the channels' chains, ``ys`` the real channels (forward speed and
    turn rate, or with ``wheels`` the wheels' rates). Each channel is weighted
    by the inverse of its residual variance without the cap.
    """
    xs, ys = tuple(x[w] for x in hats), tuple(y[w] for y in ys)
    wts = [1.0 / max(float(np.mean((y - x) ** 2)), 1e-12) for x, y in zip(xs, ys)]
    base = _wsse(xs, ys, wts, None)
    best = (base, None)
    for half in (None,) if wheels else HALVES:
        for lim in np.percentile(load(xs, half), QUANTILES):
            cap = WheelCap(float(lim), None if half is None else float(half))
            sse = _wsse(xs, ys, wts, cap)
            if sse < best[0]:
                best = (sse, cap)
    cap = best[1]
    if cap is not None:
        cap = _refine(xs, ys, wts, cap)
        best = (_wsse(xs, ys, wts, cap), cap)
    return best[1], best[0], base


def _refine(xs: tuple, ys: tuple, wts: list, cap: WheelCap) -> WheelCap:
    """Return ``cap`` with limit (and half track) refined between grid points (log scale)."""
    from scipy.optimize import minimize

    def make(x: np.ndarray, ex=math.exp) -> WheelCap:
        return WheelCap(*(float(ex(v)) for v in x)) if x.size > 1 else \
            WheelCap(float(ex(x[0])), None)

    def sse(x: np.ndarray) -> float:
        return _wsse(xs, ys, wts, make(x))

    # the half track within the searched range: past it the limit and the half track grow
    # together without bound, a turn-rate cap dressed as a wheel of an impossible robot
    x0 = np.log([cap.limit] if cap.half is None else [cap.limit, cap.half])
    bounds = [(None, None)] + ([] if cap.half is None else
                               [(math.log(HALVES[0]), math.log(HALVES[-1]))])
    r = minimize(sse, x0, method='Nelder-Mead', options={'xatol': 1e-4, 'fatol': 1e-9},
                 bounds=bounds)
    return make(r.x, np.exp) if r.fun < sse(x0) else cap


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
        s = factor((vh, wh), c)
        return yv - s * vh, yw - s * wh
    ev, ew = sse(cap)
    wv, ww = 1.0 / max(float(ev @ ev) / ev.size, 1e-12), 1.0 / max(float(ew @ ew) / ew.size,
                                                                   1e-12)
    best = wv * float(ev @ ev) + ww * float(ew @ ew)
    for factor_ in (0.7, 1.4):
        half = cap.half * factor_

        def cost(x: float) -> float:
            a, b = sse(WheelCap(math.exp(x), half))
            return wv * float(a @ a) + ww * float(b @ b)
        r = minimize_scalar(cost, bounds=(math.log(cap.limit / 3), math.log(cap.limit * 3)),
                            method='bounded')
        if r.fun - best < HALF_TOLERANCE * best:
            return False
    return True


def _both_wheels(xs: tuple, s: np.ndarray, w: np.ndarray) -> bool:
    """
    Return True when each of two wheels is the faster one in :data:`SIDE` of the capped time.

    A cap met on one wheel alone tells that wheel's limit, not the other's,
    nor that the two are coupled: it is not named.
    """
    capped = w & (s < 0.99)
    if not capped.any():
        return False
    left = np.abs(xs[0][capped]) >= np.abs(xs[1][capped])
    return SIDE <= float(np.mean(left)) <= 1.0 - SIDE


def _each_wheel(er: list, ef: list, binds: np.ndarray) -> bool:
    """Return True when each wheel's held-out residual where the cap binds shrinks with it."""
    return all(float(b[binds] @ b[binds]) < float(a[binds] @ a[binds]) for a, b in zip(er, ef))


def _axes(models: dict, sim_d: dict, wabs, acd, dt: float, gain: bool = True,
          fields: Optional[tuple] = None) -> tuple:
    """Return the channels' chains on the block grid (forward, turn by default; ``gain``)."""
    from robot_calib.mismatch import drive as D

    return tuple(D.predict(D._filled(sim_d[f]), wabs if f == D.V else None, dt, models[f],
                           acmd=acd if f == D.V else None, gain=gain)
                 for f in fields or (D.V, D.W))


def _refit(chosen: dict, sim_d: dict, real_d: dict, s, wabs, acd, w: np.ndarray, dt: float,
           prm, fields: tuple) -> dict:
    """Return the chosen channels' parts fitted again on the samples ``w`` of the real / ``s``."""
    from robot_calib.mismatch import drive as D

    return {f: D.fit_axis(D._filled(sim_d[f]), wabs if f == D.V else None,
                          np.nan_to_num(real_d[f]) / s, w, dt, prm.drive_max_dead_time,
                          chosen[f][0].parts, refine=True, acmd=acd if f == D.V else None)
            for f in fields}


def judge(sim_d: dict, real_d: dict, wabs, acd, held: np.ndarray, piece: int, dt: float,
          prm, late: frozenset, period: float, chosen: dict,
          fields: Optional[tuple] = None) -> Optional[tuple]:
    """
    Return (cap, the channels chosen again on the real motion divided by s, test) or None.

    ``fields``: the forward speed and turn rate (default) or two wheels' rates.
    ``chosen``: per field (model, stats, fitted samples) of :func:`.drive._choose_axis`.
    The cap and the channels' named parts are fitted on the fitted part of the
    time line; the held-out pieces' log ratio of the weighted SSE without /
    with the cap passes Student's t at ``prm.drive_alpha`` on the pieces where
    it binds.
    """
    from robot_calib.mismatch import drive as D

    V = D.V
    fields = tuple(fields or (V, D.W))
    wheels = V not in fields
    if any(f not in chosen for f in fields):
        return None
    ys = tuple(np.nan_to_num(real_d[f]) for f in fields)
    ok = np.logical_and.reduce([chosen[f][2] for f in fields])
    fitw = ok & ~held
    models = {f: chosen[f][0] for f in fields}
    if wheels:
        # a wheel held at its cap half the time shows no lag of its own (it reads as a gain of
        # -0.3): the first cap is fitted on chains with a dead time and a lag free
        models = {f: D.fit_axis(D._filled(sim_d[f]), None, y, fitw, dt, prm.drive_max_dead_time,
                                models[f].parts | {'drive_dead_time', 'drive_lag'}, refine=True)
                  for f, y in zip(fields, ys)}
    # the channels' dynamics without their gains: a gain fitted without the cap has taken part
    # of it (a drive capped half the time reads as one that settles 20-40 % short)
    hats = _axes(models, sim_d, wabs, acd, dt, gain=False, fields=fields)
    cap, with_cap, without = fit(hats, ys, fitw, wheels)
    if cap is None or (without - with_cap) < prm.min_improvement * without or \
            np.mean(factor(tuple(x[ok] for x in hats), cap) < 0.99) < 0.02 or \
            not (wheels or _half_known(*hats, *ys, fitw, cap) or _top_speed(hats, cap, fitw)):
        return None
    # the channels chosen again on the real motion divided by the cap's factor, and the cap
    # fitted again on them; the factor always from channels fitted on the fitted part alone
    # (one from all the time line would carry the held-out noise into the next choice)
    for _ in range(ROUNDS):
        s = factor(hats, cap)
        again = {f: D._choose_axis(f, sim_d[f], real_d[f] / s, wabs if f == V else None,
                                   acd if f == V else None, held, piece, dt, prm, f in late,
                                   period) or chosen[f] for f in fields}
        hats = _axes(_refit(again, sim_d, real_d, s, wabs, acd, fitw, dt, prm, fields), sim_d,
                     wabs, acd, dt, fields=fields)
        cap, _, _ = fit(hats, ys, fitw, wheels)
        if cap is None:
            return None
    # the test: both models fitted on the fitted part only
    reduced = _refit(chosen, sim_d, real_d, 1.0, wabs, acd, fitw, dt, prm, fields)
    full = _refit(again, sim_d, real_d, factor(hats, cap), wabs, acd, fitw, dt, prm, fields)
    rs = _axes(reduced, sim_d, wabs, acd, dt, fields=fields)
    fs = _axes(full, sim_d, wabs, acd, dt, fields=fields)
    cap, _, _ = fit(fs, ys, fitw, wheels)
    if cap is None:
        return None
    s = factor(fs, cap)
    if wheels:
        if not _both_wheels(fs, s, fitw):
            return None
    elif not _half_known(*fs, *ys, fitw, cap):
        if not _top_speed(fs, cap, fitw):
            return None
        cap.half_known = False
    # a top speed met driving straight is judged on the forward speed alone: what it does to
    # the turn rate in the few turns it meets (scaled alike) is no evidence of a top speed
    on = slice(None) if cap.half_known else slice(0, 1)
    test = _heldout(ys[on], rs[on], fs[on], s, ok, fitw, held, piece, prm, wheels)
    return (cap, again, test) if test else None


def _top_speed(hats: tuple, cap: WheelCap, w: np.ndarray) -> bool:
    """
    Return True when a cap whose half track the data cannot tell is a top speed.

    It must be met mostly driving straight (:data:`STRAIGHT` of the capped rim
    speed from the forward speed); one met turning in place gives only limit /
    half. Checked on the first fit too: the rounds of a cap refused at the end
    cost as much as the rest of the drive.
    """
    fv, fw = hats
    capped = w & (factor(hats, cap) < 0.99)
    return bool(capped.any()) and float(np.mean(np.abs(fv[capped]))) >= STRAIGHT * float(
        np.mean(np.abs(fv[capped]) + cap.half * np.abs(fw[capped])))


def _heldout(ys: tuple, reduced: tuple, full: tuple, s: np.ndarray, ok: np.ndarray,
             fitw: np.ndarray, held: np.ndarray, piece: int, prm,
             wheels: bool = False) -> Optional[tuple]:
    """
    Return the cap's held-out test (z, threshold, pieces, fit RMSEs) when it passes, else None.

    ``reduced``, ``full``: the channels' chains without and with the cap (its
    factor ``s``), both fitted on ``fitw``; judged on the held-out pieces where
    the cap binds. Two wheels: each wheel's held-out residual where the cap
    binds must shrink with it (the slower wheel too, which the cap couples).
    The fit RMSEs: the forward speed's, or both wheels' together.
    """
    idx_f = range(len(ys))
    er = [y - r for y, r in zip(ys, reduced)]
    ef = [y - s * f for y, f in zip(ys, full)]
    wts = [1.0 / max(float(np.mean(er[i][fitw] ** 2)), 1e-12) for i in idx_f]
    binds = ok & held & (s < 0.99)
    idx = np.flatnonzero(ok & held)
    sse_r = sum(wts[i] * np.bincount(idx // piece, weights=er[i][idx] ** 2,
                                     minlength=s.size // piece + 1) for i in idx_f)
    sse_f = sum(wts[i] * np.bincount(idx // piece, weights=ef[i][idx] ** 2,
                                     minlength=s.size // piece + 1) for i in idx_f)
    has = np.bincount(np.flatnonzero(binds) // piece, minlength=sse_r.size) >= 3
    if has.sum() < 3:
        return None
    if wheels and not _each_wheel(er, ef, binds):
        return None
    dlt = np.log((sse_r[has] + 1e-300) / (sse_f[has] + 1e-300))
    spread = float(np.std(dlt, ddof=1))
    z = float(np.mean(dlt) / (spread / math.sqrt(dlt.size))) if spread > 0 else 0.0
    thr = L.t_quantile(prm.drive_alpha, dlt.size - 1)
    if not z > thr:
        return None
    # the forward speed's residual (both wheels') where the cap binds, without and with it
    on = list(idx_f) if wheels else [0]
    fit_rmse = {key: float(np.sqrt(np.mean(np.concatenate([e[i][m] ** 2 for i in on]))))
                if m.any() else None
                for key, e, m in (('rmse_before', er, fitw & (s < 0.99)),
                                  ('rmse_after', ef, fitw & (s < 0.99)),
                                  ('heldout_rmse_before', er, binds),
                                  ('heldout_rmse_after', ef, binds))}
    return z, thr, int(dlt.size), fit_rmse


def under_cap(pt, fields: list, sim_d: dict, real_d: dict, wabs, acd, held: np.ndarray,
              piece: int, dt: float, prm, late: frozenset, period: float,
              chosen: dict) -> Optional[tuple]:
    """
    Return (cap, channels, real under the cap, finding, capped fields) of a topic, or None.

    Odometry: its two axes; joint states: exactly two wheels' rates. The real
    channels are returned divided by the cap's factor (the chains' findings
    are made under the cap).
    """
    from robot_calib.mismatch import drive as D

    if not prm.drive_wheel_cap:
        return None
    if pt.msgtype == D.ODOM_TYPE:
        capped = (D.V, D.W)
    elif pt.msgtype == D.JOINT_STATE_TYPE and len(fields) == 2:
        capped = tuple(fields)
    else:
        return None
    judged = judge(sim_d, real_d, wabs, acd, held, piece, dt, prm, late, period, chosen,
                   capped)
    if not judged:
        return None
    cap, models, test = judged
    s_d = factor(_axes({f: m for f, (m, _, _) in models.items()}, sim_d, wabs, acd, dt,
                       fields=capped), cap)
    real_d = {f: real_d[f] / s_d for f in real_d}
    return cap, models, real_d, finding(pt.name, cap, test, float(np.mean(s_d < 0.99)),
                                        capped), capped


def full_scale(pt, fields: tuple, models: dict, cap: WheelCap) -> np.ndarray:
    """Return the cap's factor on the topic's own grid (the chains of ``models``, with gains)."""
    from robot_calib.mismatch import drive as D

    wfull = np.abs(D._filled(pt.sim[D.W])) if D.W in pt.sim else None
    return factor(tuple(D.predict(D._filled(pt.sim[f]), wfull if f == D.V else None, pt.dt,
                                  models[f][0]) for f in fields), cap)


def text(cap: WheelCap) -> str:
    """Return the cap's clause of the drive's description."""
    if cap.half is None:
        return f'; both wheels capped where the faster would pass {cap.limit:.3g} rad/s.'
    return f'; both capped where the faster wheel would pass {cap.limit:.3g} ' \
        f'm/s (|v| + {cap.half:.3g} |omega|).'


def finding(topic: str, cap: WheelCap, test: tuple, bound: float,
            fields: Optional[tuple] = None) -> dict:
    """Return the cap as reported (``wheel_speed_limit``; ``bound``: the share of time capped)."""
    from robot_calib.mismatch import drive as D

    fields = tuple(fields or (D.V, D.W))
    z, thr, pieces, fit_rmse = test
    # it passed the test at drive_alpha; its strength grows from the 5 % bar, as the axes' parts
    strength = 1.0 - (L.t_quantile(0.05, max(pieces - 1, 1)) / max(z, 1e-12)) ** 2
    wheels = cap.half is None
    if wheels:
        what = (f"The faster wheel's rate is capped at {cap.limit:.3g} rad/s (a wheel rate, "
                "as the simulator's drive.max_wheel_speed): where either wheel would turn "
                'faster, both wheels slow together')
    elif cap.half_known:
        what = (f"The faster wheel's rim speed is capped at {cap.limit:.3g} m/s "
                f'(half track {cap.half:.3g} m): where |v| + {cap.half:.3g} |omega| '
                'would exceed it, speed and turn rate shrink together')
    else:
        what = (f'The forward speed is capped at {cap.limit:.3g} m/s (a wheel-speed '
                'cap met only while driving nearly straight: the half track it '
                'acts about cannot be told from these data)')
    return {'channel': f'{topic}.{fields[0]}', 'effect': 'wheel_speed_limit',
            'parameters': {'limit': cap.limit,
                           'half_track': cap.half if cap.half_known else None},
            'units': {'limit': 'rad/s' if wheels else 'm/s', 'half_track': 'm'},
            'window': None, 'channels': [f'{topic}.{f}' for f in fields],
            'explanation': what + f' ({100 * bound:.0f} % of the time). Against '
            f'the same drive without the cap the held-out fit improves (z {z:.1f} > {thr:.1f} '
            f'over {pieces} pieces).',
            'evidence': {'z': z, 'z_threshold': thr, 'blocks': pieces,
                         'test': 'held-out pieces of ' + (
                             'both wheels' if wheels else 'both axes' if cap.half_known else
                             'the forward speed') + ' with and without the cap'},
            'confidence': confidence(max(0.0, min(1.0, strength)), []), 'fit': fit_rmse}
