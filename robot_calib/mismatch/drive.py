# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Drive dynamics: how a real drive follows the velocity its simulation executes.

Per axis (forward speed v, turn rate omega) of an odometry topic, the real
channel is the simulated one (the commanded motion of an ideal robot) through
the chain a real drive has (contract names, architecture.md):

    u1 = u |u| > band ? u : 0                        drive_deadband (band)
    u2 = u1 (1 - k |omega_sim|)       (forward only) turn_speed_loss (k, s/rad)
    u3 = rate limited u2, |du3/dt| <= limit          drive_rate_limit (limit)
    u4 = u3 (t - d)                                  drive_dead_time (d, s)
    y  = (1 + g) lag(u4, tau)                        drive_lag (tau, s), drive_gain (g)

``lag`` is the exact discrete first-order lag ``1 / (1 + s tau)``. All are
fitted together (grids over the nonlinear parameters, linear least squares
for g and k), so a lag is not mistaken for a delay, a turn-coupled speed loss
for a gain, or a deadband for a gain. Each part is named only when leaving it
out (the others re-fitted) makes held-out time worse: the model is fitted on
two thirds of the chunks and the loss of each reduced model is compared on
pieces (>= ``min_block_s``) of the held-out third, where the part changes the
prediction, by Student's t over the pieces (:func:`_eliminate`). A dead time
or lag under one sample period is not named (:func:`_unresolved`). The
steady-state gain is always fitted with the dynamics and judged last, by the
same held-out test (g held at 0 in the reduced model): when it passes it is
the drive's (``drive_gain``) and part of the chain's output, otherwise the
amplitude stage judges scales, offsets and slip on what the named dynamics
leave (:mod:`robot_calib.mismatch.analysis`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math
from typing import Optional

import numpy as np

from robot_calib.mismatch import drive_cap as DC
from robot_calib.mismatch import drive_interval as DI
from robot_calib.mismatch import effects as E
from robot_calib.mismatch import latency as L
from robot_calib.mismatch.channels import JOINT_STATE_TYPE, ODOM_TYPE, PairedTopic
from robot_calib.mismatch.drive_chain import (  # noqa: F401 (the chain, re-exported)
    _filled, AxisModel, deadband, lag, predict, rate_limit, regressors, response, shift)
from robot_calib.mismatch.drive_text import (  # noqa: F401 (the names, re-exported)
    _damping_sentence, _sentence, AXIS, axis_name, describe, driven, UNIT, unit_of, V, W,
    wheel_rates)
from robot_calib.mismatch.findings import confidence, evidence, motion_ratio
from robot_calib.mismatch.problem import held_mask, rmse

PARTS = ('drive_dead_time', 'drive_lag', 'drive_deadband', 'drive_rate_limit',
         'turn_speed_loss', 'drive_damping')  # damping: a second-order lag, drive_lag's
E.SEPARATE.update({
    frozenset(('drive_deadband', 'drive_gain')): 'slow commands near zero beside fast ones '
    'separate a deadband from a gain',
    frozenset(('turn_speed_loss', 'drive_gain')): 'driving straight at the same speeds as in '
    'the turns separates a turn-coupled speed loss from a speed gain',
    frozenset(('drive_rate_limit', 'drive_lag')): 'large steps of the command beside small '
    'ones separate an acceleration limit (binds on large steps only) from a lag',
})
_LIMIT_STEP, _LIMITS = 1.5, 10  # the rate limits' grid: ratio and count
_ZETAS = (0.25, 0.35, 0.45, 0.55, 0.65, 0.75)  # second-order dampings searched (overshoot)
_ZETA_MAX = 0.8  # a damping above overshoots < 1.5 %: a first order with a dead time
_TAUS = np.concatenate(([0.0], np.geomspace(0.02, 2.0, 22)))


def _solve(X: np.ndarray, y: np.ndarray, w: np.ndarray,
           fixed_gain: bool = False) -> tuple[np.ndarray, float]:
    """
    Return (coefficients, SSE) of y ~ X on the samples ``w`` (bool), by normal equations.

    ``fixed_gain``: the first coefficient (1 + g) held at 1.
    """
    if fixed_gain:
        if X.shape[1] == 1:
            r = y - X[:, 0]
            return np.ones(1), float(w.astype(float) @ (r * r))
        c, sse = _solve(X[:, 1:], y - X[:, 0], w)
        return np.concatenate(([1.0], c)), sse
    wf = w.astype(float)
    Xw = X * wf[:, None]
    A = Xw.T @ X + 1e-12 * np.eye(X.shape[1])
    b = Xw.T @ y
    c = np.linalg.solve(A, b)
    yy = float((wf * y) @ y)
    return c, max(yy - float(c @ b), 0.0)


def _chain_fit(u, wabs, y, w, dt, m: AxisModel, coupled: bool,
               acmd=None) -> tuple[np.ndarray, float]:
    """Return (coefficients, SSE) of the chain ``m`` on the samples ``w``, g, k, slip linear."""
    return _solve(regressors(u, wabs, dt, m, coupled, acmd), y, w, m.fixed_gain)


def _linear(m: AxisModel, c: np.ndarray, coupled: bool = False,
            slip: bool = False) -> AxisModel:
    g = float(c[0]) - 1.0
    k = float(-c[1] / c[0]) if coupled and c[0] != 0 else 0.0
    return replace(m, gain=g, k=k, slip=float(c[-1]) if slip else 0.0)


def _grid(u, wabs, y, w, dt, m: AxisModel, coupled: bool, max_d: float,
          free: tuple = ('d', 'tau'), acmd=None, taus=None) -> tuple[AxisModel, float]:
    """Return the best (d, tau) on grids (others fixed) with g, k, slip solved linearly."""
    taus = taus if taus is not None else _TAUS if 'tau' in free else [m.tau]
    step = max(1, int(round(0.04 / dt)))
    ds = [k * dt for k in range(0, int(max_d / dt) + 1, step)] if 'd' in free else [m.d]
    u1 = deadband(u, m.band)
    cols = [u1] + ([u1 * wabs] if coupled and wabs is not None else [])
    rl = np.column_stack([rate_limit(c, dt, m.limit) for c in cols])
    best = (math.inf, m)
    for tau in taus:
        base = response(rl, dt, float(tau), m.zeta)
        if acmd is not None:
            base = np.column_stack((base, base[:, 0] * response(acmd, dt, float(tau), m.zeta)))
        for d in ds:
            c, sse = _solve(shift(base, d, dt), y, w, m.fixed_gain)
            if sse < best[0]:
                best = (sse, _linear(replace(m, tau=float(tau), d=float(d)), c, coupled,
                                     acmd is not None))
    return best[1], best[0]


def _refine(u, wabs, y, w, dt, m: AxisModel, coupled: bool, max_d: float,
            acmd=None) -> AxisModel:
    """Return ``m`` with d and tau refined between grid points (golden search, each in turn)."""
    from scipy.optimize import minimize_scalar

    def sse(mm: AxisModel) -> float:
        return _chain_fit(u, wabs, y, w, dt, mm, coupled, acmd)[1]

    for _ in range(2):
        if 'd' in m.parts or m.d > 0:
            r = minimize_scalar(lambda d: sse(replace(m, d=d)),
                                bounds=(max(0.0, m.d - dt), min(max_d, m.d + dt)),
                                method='bounded', options={'xatol': 1e-4})
            m = replace(m, d=float(r.x))
        if m.tau > 0:
            r = minimize_scalar(lambda t: sse(replace(m, tau=t)),
                                bounds=(0.7 * m.tau, 1.4 * m.tau), method='bounded',
                                options={'xatol': 1e-4})
            m = replace(m, tau=float(r.x))
    c, _ = _chain_fit(u, wabs, y, w, dt, m, coupled, acmd)
    return _linear(m, c, coupled, acmd is not None)


def fit_axis(u: np.ndarray, wabs: Optional[np.ndarray], y: np.ndarray, w: np.ndarray,
             dt: float, max_d: float, parts: set, refine: bool = False,
             acmd: Optional[np.ndarray] = None, fixed_gain: bool = False) -> AxisModel:
    """
    Fit the chain with only ``parts`` free (names of :data:`PARTS`); return the model.

    ``u`` the simulated channel, ``wabs`` |simulated turn rate| (forward axis),
    ``y`` the real channel, ``w`` the samples fitted (bool); ``fixed_gain``: g held at 0.
    """
    coupled = 'turn_speed_loss' in parts and wabs is not None
    free = tuple(p for p, n in (('d', 'drive_dead_time'), ('tau', 'drive_lag')) if n in parts)
    m = AxisModel(parts=set(parts), fixed_gain=fixed_gain)
    slip = acmd is not None
    m, sse = _grid(u, wabs, y, w, dt, m, coupled, max_d, free, acmd) if free else \
        (_linear(m, _chain_fit(u, wabs, y, w, dt, m, coupled, acmd)[0],
                 coupled, slip), 0.0)
    scale = float(np.percentile(np.abs(u[w]), 95)) if w.any() else 0.0
    if 'drive_deadband' in parts and scale > 0:
        best = (math.inf, m)
        for f in (0.0, 0.01, 0.02, 0.04, 0.06, 0.08, 0.1, 0.13, 0.16, 0.2, 0.25, 0.3, 0.4):
            mm = replace(m, band=f * scale)
            c, s = _chain_fit(u, wabs, y, w, dt, mm, coupled, acmd)
            if s < best[0]:
                best = (s, _linear(mm, c, coupled, slip))
        m = best[1]
    if 'drive_rate_limit' in parts and scale > 0:
        # limits from under the command's fastest change down by factors of 1.5, with the
        # dead time and lag searched again (a limit makes its own delay, which a lag fitted
        # without it has taken already); the best searched again half a step either side
        pairs = w[1:] & w[:-1]
        top = float(np.max(np.abs(np.diff(u))[pairs])) / dt if pairs.any() else scale / dt

        def trial(lim: float) -> tuple:
            mm = replace(m, limit=lim)
            if free:
                return _grid(u, wabs, y, w, dt, mm, coupled, max_d, free, acmd)[::-1]
            c, s = _chain_fit(u, wabs, y, w, dt, mm, coupled, acmd)
            return s, _linear(mm, c, coupled, slip)
        tried = [trial(top / _LIMIT_STEP ** i if i else math.inf) for i in range(_LIMITS + 1)]
        best = min(tried, key=lambda sm: sm[0])
        if math.isfinite(best[1].limit):
            best = min([best] + [trial(best[1].limit * _LIMIT_STEP ** h) for h in (-0.5, 0.5)],
                       key=lambda sm: sm[0])
        m = best[1]
    if free and (m.band > 0 or math.isfinite(m.limit)):
        m, _ = _grid(u, wabs, y, w, dt, m, coupled, max_d, free, acmd)
    if 'drive_damping' in parts and 'tau' in free and m.tau > 0:
        m = _damped(u, wabs, y, w, dt, m, coupled, max_d, free, acmd)
    if refine and free:
        m = _refine(u, wabs, y, w, dt, m, coupled, max_d, acmd)
    if refine and (m.band > 0 or math.isfinite(m.limit) or m.zeta > 0):
        m = _refine_nonlinear(u, wabs, y, w, dt, m, coupled, acmd)
    m.parts = set(parts)
    return m


def _damped(u, wabs, y, w, dt, m: AxisModel, coupled: bool, max_d: float, free: tuple,
            acmd=None) -> AxisModel:
    """
    Return the better of ``m`` (first order) and a second-order response of about its delay.

    Both with d and tau refined between grid points first: on the grid alone a
    second order's slow start passes for the part of a dead time between two
    grid points.
    """
    def sse(mm: AxisModel) -> float:
        return _chain_fit(u, wabs, y, w, dt, mm, coupled, acmd)[1]

    near = [t for t in _TAUS if 0.5 * m.tau <= t <= 2.0 * m.tau] or [m.tau]
    second = min((_grid(u, wabs, y, w, dt, replace(m, zeta=z), coupled, max_d, free, acmd,
                        near) for z in _ZETAS), key=lambda ms: ms[1])[0]
    first = _refine(u, wabs, y, w, dt, m, coupled, max_d, acmd)
    second = _refine(u, wabs, y, w, dt, second, coupled, max_d, acmd)
    # the first order as the grid left it, as every model without a damping is in the test
    return second if sse(second) < sse(first) else m


def _refine_nonlinear(u, wabs, y, w, dt, m: AxisModel, coupled: bool, acmd=None) -> AxisModel:
    """Return ``m`` with its band, rate limit and damping refined between grid points (log)."""
    from scipy.optimize import minimize_scalar

    def sse(mm: AxisModel) -> float:
        return _chain_fit(u, wabs, y, w, dt, mm, coupled, acmd)[1]

    for key in ('band', 'limit', 'zeta'):
        v = getattr(m, key)
        if not (v > 0 and math.isfinite(v)):
            continue
        top = v * 1.6 if key != 'zeta' else min(v * 1.6, _ZETA_MAX)
        r = minimize_scalar(lambda x: sse(replace(m, **{key: math.exp(x)})),
                            bounds=(math.log(v / 1.6), math.log(top)), method='bounded',
                            options={'xatol': 1e-3})
        if r.fun < sse(m):
            m = replace(m, **{key: float(math.exp(r.x))})
    c, _ = _chain_fit(u, wabs, y, w, dt, m, coupled, acmd)
    return _linear(m, c, coupled, acmd is not None)


def _chunk_sse(r: np.ndarray, held: np.ndarray, ok: np.ndarray, chunk: int) -> np.ndarray:
    """Return the SSE of ``r`` per held-out chunk."""
    idx = np.flatnonzero(held & ok)
    return np.bincount(idx // chunk, weights=r[idx] ** 2, minlength=r.size // chunk + 1)


def _axis_parts(f: str, u: np.ndarray, wabs: Optional[np.ndarray], ok: np.ndarray) -> set:
    """
    Return the parts the motion can separate on field ``f``.

    The turn speed loss ``-k u |omega|`` is told from a gain ``g u`` only when
    ``|omega|`` varies while the robot drives: when the part of ``u |omega|``
    that ``u`` does not explain is under 5 % of its RMS (a constant turn rate,
    or no turning), the two are the same regressor and the loss is not fitted.
    """
    parts = set(PARTS)
    if f != V or wabs is None:
        parts.discard('turn_speed_loss')
        return parts
    x, c = u[ok], (u * wabs)[ok]
    uu = float(x @ x)
    left = c - x * (float(x @ c) / uu) if uu > 0 else c
    if float(np.sqrt(np.mean(left ** 2))) < 0.05 * float(np.sqrt(np.mean(c ** 2))) + 1e-12:
        parts.discard('turn_speed_loss')
    return parts


@dataclass
class DriveResult:
    """The fitted drive: per field its model, the findings and the simulated channels it makes."""

    models: dict
    findings: list
    sim: dict
    text: str


def analyse_drive(pt: PairedTopic, prm, acmd: Optional[np.ndarray] = None,
                  late: frozenset = frozenset()) -> Optional[DriveResult]:
    """
    Fit the drive chain to a topic; return it when any dynamic part is named.

    Odometry: its forward speed and turn rate; joint states: each wheel's
    rate (a motor of its own: no turn speed loss, slip or acceleration); a
    wheel-speed cap over both axes, or over two wheels (:mod:`.drive_cap`). None
    when the topic has no such channel, when nothing beyond a
    pure delay (which the time stage judges) is named, or when the drive
    model is off (``prm.drive_model``). ``acmd``: the commanded acceleration
    on the topic's grid (m/s^2), for the slip fitted beside the forward axis.
    ``late``: the fields the time stage found late (at full rate, a delay
    rather than a lag): their dead time is kept, the chain judges what the
    dynamics add to it.
    """
    if not getattr(prm, 'drive_model', True) or prm.mode == 'seed' or \
            pt.msgtype not in (ODOM_TYPE, JOINT_STATE_TYPE):
        return None
    # odometry: forward speed and turn rate; joint states: each wheel's rate
    fields = [f for f in ((V, W) if pt.msgtype == ODOM_TYPE else wheel_rates(pt.sim))
              if f in pt.sim and f in pt.real]
    if not fields or pt.t.size < 200:
        return None
    # the parts are chosen and fitted on block averages of at least 10 Hz (cost)
    q = max(1, min(pt.t.size // 4000, int(0.1 / max(pt.dt, 1e-9))))
    dt = pt.dt * q
    n = pt.t.size // q
    held = held_mask(n, prm.heldout_chunks)
    chunk = max(1, n // prm.heldout_chunks)
    # the test's units: each held-out chunk cut into pieces of at least min_block_s
    piece = max(1, chunk // max(1, int(chunk * dt / prm.min_block_s)))
    sim_d, real_d, acd = _block_inputs(pt, fields, acmd, q, n)
    wabs = np.abs(_filled(sim_d[W])) if W in sim_d else None
    out_models, found, sims = {}, [], {}
    period = max(pt.dt_sim, pt.dt_real, pt.dt)
    for f in fields:
        chosen = _choose_axis(f, sim_d[f], real_d[f], wabs if f == V else None,
                              acd if f == V else None, held, piece, dt, prm, f in late, period)
        if chosen is not None:
            out_models[f] = chosen
    # a differential drive's wheel-speed cap, over both axes or two wheels (fitted again under it)
    judged = DC.under_cap(pt, fields, sim_d, real_d, wabs, acd, held, piece, dt, prm, late,
                          period, out_models)
    cap = judged[0] if judged else None
    if judged:
        out_models, real_d = judged[1], judged[2]
        found.append(judged[3])
    dyn = {p for m, _, _ in out_models.values() for p in m.parts} - {
        'drive_dead_time', 'drive_gain'}
    if not dyn and cap is None:
        return None
    wfull = np.abs(_filled(pt.sim[W])) if W in pt.sim else None
    s_full = DC.full_scale(pt, judged[4], out_models, cap) if cap else 1.0
    for f, (model, stats, ok) in out_models.items():
        u = _filled(pt.sim[f])
        # the named gain is the drive's (the amplitude stage judges scales on what it leaves)
        sims[f] = np.where(np.isfinite(pt.sim[f]), predict(
            u, wfull if f == V else None, pt.dt, model, gain=False) * (
                1.0 + model.gain if 'drive_gain' in model.parts else 1.0) * s_full, np.nan)
        ud, wd, ad = _filled(sim_d[f]), wabs if f == V else None, acd if f == V else None
        sd = DI.axis_std(ud, wd, np.nan_to_num(real_d[f]), ok, dt, ad, prm, model)
        found.extend(_findings(pt, f, model, stats, ok, held, ud, real_d[f], wd, dt, ad, sd))
    text = describe({f: m for f, (m, _, _) in out_models.items()})
    if cap:
        text = text[:-1] + DC.text(cap)
    for fd in found:
        fd['explanation'] += ' ' + text
    return DriveResult({f: m for f, (m, _, _) in out_models.items()}, found, sims, text)


def _block_inputs(pt: PairedTopic, fields: list, acmd: Optional[np.ndarray], q: int,
                  n: int) -> tuple:
    """
    Return (sim, real, commanded acceleration): means of ``q`` samples, ``n`` of them.

    A noisy simulation (another recording) puts both sides through one moving
    average of 5 samples, which the dynamics commute with: the sim's own noise,
    absent from the real side, would pass for a lag that filters it. The
    chain's discrete response takes a block's mean as held over the block,
    which makes it about half a block late (a known d + tau of 0.35 s read
    0.386 s on blocks of 5 samples): the block means of the command are read
    that much later to start with.
    """
    dt = pt.dt * q
    noisy = any(pt.sim_noisy.get(f) for f in fields)
    late_by = 0.5 * (q - 1) * pt.dt
    sim_d = {f: shift(_blocks(_smooth(pt.sim[f]) if noisy else pt.sim[f], q, n), late_by, dt)
             for f in fields}
    real_d = {f: _blocks(_smooth(pt.real[f]) if noisy else pt.real[f], q, n) for f in fields}
    acd = np.nan_to_num(shift(_blocks(acmd, q, n), late_by, dt)) \
        if acmd is not None and V in fields else None
    return sim_d, real_d, acd


def _choose_axis(f: str, sim: np.ndarray, real: np.ndarray, wa: Optional[np.ndarray],
                 ac: Optional[np.ndarray], held: np.ndarray, piece: int, dt: float, prm,
                 late: bool, period: float) -> Optional[tuple]:
    """
    Return (model, stats, fitted samples) of one axis, or None when it cannot be judged.

    The parts by backward elimination (:func:`_eliminate`; a dead time the
    time stage showed kept when ``late``), fitted again on all the samples,
    without a dead time or lag under one sample ``period`` (:func:`_unresolved`).
    """
    u = _filled(sim)
    ok = np.isfinite(sim) & np.isfinite(real)
    if ok.sum() < 100 or np.std(u[ok]) <= 0:
        return None
    yf = np.nan_to_num(real)
    named, stats = _eliminate(u, wa, yf, ok, held, piece, dt, prm, _axis_parts(f, u, wa, ok),
                              ac, frozenset({'drive_dead_time'} if late else ()))
    model = fit_axis(u, wa, yf, ok, dt, prm.drive_max_dead_time, named, refine=True, acmd=ac)
    small = _unresolved(model, period)
    if small:
        model = fit_axis(u, wa, yf, ok, dt, prm.drive_max_dead_time, named - small,
                         refine=True, acmd=ac)
    return model, stats, ok


def _unresolved(m: AxisModel, period: float) -> set:
    """
    Return the named dead time or lag shorter than one sample ``period`` (s) of the coarser side.

    Read at the other side's stamps, a series sampled every T is interpolated;
    at the midpoints that filters as cos(pi f T) ~ 1 - (pi f T)^2 / 2, the
    magnitude of a first-order lag of T / 2, and a speed differenced over one
    period trails its stamp by T / 2: sampling alone makes a lag or a delay of
    up to half a period, so only one longer than a whole period is the drive's.
    """
    return {p for p, v in (('drive_lag', m.tau), ('drive_dead_time', m.d))
            if p in m.parts and v < period}


def _eliminate(u, wa, yf, ok, held, chunk, dt, prm, parts: set, acmd=None,
               keep: frozenset = frozenset()) -> tuple:
    """
    Backward elimination of the drive's parts by the held-out chunk test; return (named, stats).

    Parts that stand in for each other (a dead time, a lag and a rate limit all
    delay a step) each look dispensable while the others are there; dropping
    the weakest one at a time and testing again keeps the ones the data need.
    Each part is judged on the held-out samples where leaving it out changes
    the prediction by over 1 % of the command's scale (a deadband acts on slow
    commands only), in chunks with at least 5 such samples. Parts in ``keep``
    are not dropped (a dead time the time stage has shown). A dead time and a
    lag that both help on held-out time (mean log ratio > 0 over at least 10
    pieces where each acts) stay together
    when dropping both fails the test, even if one alone passes: a response
    with both, modelled by one, biases it (a dead time alone takes part of the
    lag, and the gain fitted with it shrinks). The gain is judged last.
    """
    fitw = ok & ~held
    cur = set(parts)
    scale = float(np.percentile(np.abs(u[ok]), 95)) if ok.any() else 0.0

    def test(drop: set, full: AxisModel, r_full: np.ndarray) -> tuple:
        # a second order's d and tau are refined between grid points: so is the first order
        # it is tested against
        red = fit_axis(u, wa, yf, fitw, dt, prm.drive_max_dead_time, cur - drop, acmd=acmd,
                       fixed_gain='drive_gain' in drop, refine='drive_damping' in drop)
        r_red = yf - predict(u, wa, dt, red, acmd=acmd)
        # judged where the part changes the prediction (a deadband acts on slow commands
        # only): chosen by the fitted models, not by the held-out data
        acts = ok & (np.abs(r_red - r_full) > 0.01 * scale)
        s_full = _chunk_sse(r_full, held, acts, chunk)
        # log ratio per chunk: scale-free, so a few chunks of fast motion do not make the
        # spread that hides a part every other chunk needs
        s_red = _chunk_sse(r_red, held, acts, chunk)
        has = np.bincount(np.flatnonzero(held & acts) // chunk, minlength=s_full.size) >= 5
        dlt = np.log((s_red[has] + 1e-300) / (s_full[has] + 1e-300))
        se = float(np.std(dlt, ddof=1) / math.sqrt(dlt.size)) if dlt.size > 2 else math.inf
        z = float(np.mean(dlt) / se) if dlt.size > 2 and se > 0 else 0.0
        thr = L.t_quantile(prm.drive_alpha, max(dlt.size - 1, 1))
        hb, ha = rmse(r_red, acts & held), rmse(r_full, acts & held)
        good = z > thr and hb is not None and ha is not None and \
            ha < (1.0 - prm.min_improvement) * hb
        return (z, thr, int(dlt.size), red, hb, ha, good, full, len(drop) > 1)

    while True:
        full = fit_axis(u, wa, yf, fitw, dt, prm.drive_max_dead_time, cur, acmd=acmd)
        if full.zeta <= 0:  # the first order fits better: no second order to test
            cur.discard('drive_damping')
        r_full = yf - predict(u, wa, dt, full, acmd=acmd)
        stats = {p: test({p}, full, r_full) for p in sorted(cur)}
        # a dead time and a lag that stand in for each other: kept together when the
        # response needs them together (their sum is resolved, the split is not)
        pair = {'drive_dead_time', 'drive_lag'}
        if pair <= cur and not all(stats[p][6] for p in pair) and full.d > 0 and \
                full.tau > 0 and all(stats[p][0] > 0 and stats[p][2] >= 10 for p in pair):
            joint = test(pair, full, r_full)
            if joint[6]:
                stats.update({p: joint for p in pair if not stats[p][6]})
        bad = [p for p in cur if not stats[p][6] and p not in keep]
        if not bad:
            # the steady-state gain, judged last on the parts the data need (always fitted)
            stats['drive_gain'] = test({'drive_gain'}, full, r_full)
            if stats['drive_gain'][6]:
                cur.add('drive_gain')
            return cur, stats
        cur.discard(min(bad, key=lambda p: stats[p][0]))
        if 'drive_lag' not in cur:
            cur.discard('drive_damping')
        if not cur:
            return cur, stats


_VALUE = {'drive_dead_time': ('tau', 's', lambda m: m.d),
          'drive_lag': ('tau', 's', lambda m: m.tau),
          'drive_deadband': ('band', None, lambda m: m.band),
          'drive_rate_limit': ('limit', None, lambda m: m.limit),
          'turn_speed_loss': ('coefficient', 's/rad', lambda m: m.k),
          'drive_gain': ('gain', '', lambda m: m.gain)}


def _smooth(x: np.ndarray, width: int = 5) -> np.ndarray:
    """Return the centred moving average of ``width`` samples (NaN kept, ignored in means)."""
    ok = np.isfinite(x)
    k = np.ones(width)
    num = np.convolve(np.where(ok, x, 0.0), k, mode='same')
    den = np.convolve(ok.astype(float), k, mode='same')
    return np.where(ok & (den > 0), num / np.maximum(den, 1.0), np.nan)


def _blocks(x: np.ndarray, q: int, n: int) -> np.ndarray:
    """Return the means of ``q`` consecutive samples (NaN where one is missing)."""
    return x[:n * q].reshape(n, q).mean(axis=1) if q > 1 else x[:n].copy()


def _findings(pt: PairedTopic, f: str, m: AxisModel, stats: dict, ok: np.ndarray,
              held: np.ndarray, u: np.ndarray, yr: np.ndarray, wa: Optional[np.ndarray],
              dt: float, acmd: Optional[np.ndarray] = None, sd: Optional[dict] = None) -> list:
    """Return one finding per named part of the axis (contract keys, held-out fit, ``sd``)."""
    out = []
    y = np.nan_to_num(yr)
    scale = float(np.percentile(np.abs(u[ok]), 95)) if ok.any() else 0.0
    second = _second_order(m, stats)
    for p in sorted(m.parts - {'drive_damping'}):
        z, thr, nb, red, hb, ha, _, full, together = stats[p]
        # the models of the test (fitted on the fitted part), on the samples where the part
        # changes the prediction, as it was tested
        r_red = y - predict(u, wa, dt, red, acmd=acmd)
        r_fit = y - predict(u, wa, dt, full, acmd=acmd)
        acts = ok & (np.abs(r_red - r_fit) > 0.01 * scale)
        motion = motion_ratio(r_red - r_fit, acts & ~held, acts & held)
        fitd = {'rmse_before': rmse(r_red, acts & ~held),
                'rmse_after': rmse(r_fit, acts & ~held),
                'heldout_rmse_before': hb, 'heldout_rmse_after': ha}
        key, unit, get = _VALUE[p]
        if unit is None:
            unit = unit_of(f) if p == 'drive_deadband' else unit_of(f) + '/s'
        val, std = float(get(m)), float(get(replace(m, **sd))) if sd else math.nan
        # the part passed the test at drive_alpha; its strength grows from the 5 % bar
        strength = 1.0 - (L.t_quantile(0.05, max(nb - 1, 1)) / max(z, 1e-12)) ** 2
        alts = [0.0] if together else []  # the other split fits as well
        if p in ('drive_lag', 'drive_dead_time'):
            other = 'drive_dead_time' if p == 'drive_lag' else 'drive_lag'
            alts_sep = E.separating_motion(p, other)
        else:
            alts_sep = E.separating_motion(p, {'drive_rate_limit': 'drive_lag',
                                               'drive_gain': 'wheel_radius_scale'}.get(
                                                   p, 'drive_gain'))
        fd = {'channel': f'{pt.name}.{f}', 'effect': p, 'parameters': {key: val},
              'window': None, 'fit': fitd, 'units': {key: unit},
              'std': {key: std}, 'channels': [f'{pt.name}.{f}'],
              'explanation': _sentence(p, f, val, std) + (
                  f' Modelling it cuts the held-out residual where it acts from {hb:.3g} to '
                  f'{ha:.3g}.' + (f' The dead time and the lag are resolved together (d + tau '
                                  f'= {m.d + m.tau:.3g} s), not apart: either alone fits about '
                                  'as well.' if together else '')
                  if hb is not None and ha is not None else ''),
              'evidence': {'z': z, 'z_threshold': thr, 'blocks': nb, 'test': 'held-out chunks '
                           'of the drive model with and without it'},
              'evidence_strength': evidence(strength, fitd, motion),
              'separating_motion': alts_sep}
        fd['confidence'] = confidence(fd['evidence_strength'], alts)
        if math.isfinite(std):  # as the other findings give it (findings.make_finding)
            fd['ci95'] = {key: [val - 1.96 * std, val + 1.96 * std]}
        if p == 'drive_lag' and second:
            zsd = float(sd['zeta']) if sd and 'zeta' in sd else math.nan
            fd['parameters']['damping'] = m.zeta
            fd['units']['damping'] = ''
            fd['std']['damping'] = zsd
            fd['explanation'] += ' ' + _damping_sentence(m.zeta, zsd, second)
            fd['evidence']['damping_z'] = second[0]
        out.append(fd)
    return out


def _second_order(m: AxisModel, stats: dict) -> Optional[tuple]:
    """Return the damping's test (z, threshold, pieces) when the lag is named second order."""
    if m.zeta > 0 and {'drive_lag', 'drive_damping'} <= m.parts and 'drive_damping' in stats:
        return stats['drive_damping'][:3]
    return None
