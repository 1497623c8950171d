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
two thirds of the chunks and the loss of each reduced model is compared chunk
by chunk on the held-out third, by Student's t over the chunks. The gain is
not named here: the amplitude stage judges scales, offsets and slip on what
the named dynamics leave (:mod:`robot_calib.mismatch.analysis`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from typing import Optional

import numpy as np
from scipy.signal import lfilter

from robot_calib.mismatch import latency as L
from robot_calib.mismatch.channels import ODOM_TYPE, PairedTopic
from robot_calib.mismatch.findings import confidence, evidence
from robot_calib.mismatch.problem import held_mask, rmse

V, W = 'twist.twist.linear.x', 'twist.twist.angular.z'
AXIS = {V: 'forward speed', W: 'turn rate'}
UNIT = {V: 'm/s', W: 'rad/s'}
PARTS = ('drive_dead_time', 'drive_lag', 'drive_deadband', 'drive_rate_limit',
         'turn_speed_loss')
_TAUS = np.concatenate(([0.0], np.geomspace(0.02, 2.0, 22)))


@dataclass
class AxisModel:
    """One axis of the drive: dead time d (s), lag tau (s), band, rate limit, gain g, k (s/rad)."""

    d: float = 0.0
    tau: float = 0.0
    band: float = 0.0
    limit: float = math.inf
    gain: float = 0.0
    k: float = 0.0
    parts: set = field(default_factory=set)


def deadband(u: np.ndarray, band: float) -> np.ndarray:
    """Return ``u`` with values of magnitude <= ``band`` set to zero (contract drive_deadband)."""
    return np.where(np.abs(u) > band, u, 0.0) if band > 0 else u


def rate_limit(u: np.ndarray, dt: float, limit: float) -> np.ndarray:
    """Return ``u`` changing by at most ``limit`` per second (units of u per s)."""
    if not math.isfinite(limit) or limit <= 0:
        return u
    step = limit * dt
    out = np.empty(u.size)
    y = float(u[0])
    for i, x in enumerate(u.tolist()):
        y += min(max(x - y, -step), step)
        out[i] = y
    return out


def lag(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """Return ``x`` through ``1 / (1 + s tau)``, exact discretisation, at rest on ``x[0]``."""
    if tau <= 0:
        return x
    a = math.exp(-dt / tau)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, axis=0, zi=np.atleast_1d(a * x[0])
                   if x.ndim == 1 else a * x[:1])
    return y


def shift(x: np.ndarray, d: float, dt: float) -> np.ndarray:
    """Return ``x`` delayed by ``d`` s (linear interpolation, held at the start)."""
    if d <= 0:
        return x
    s = d / dt
    i = int(math.floor(s))
    f = s - i
    idx = np.arange(x.shape[0])
    a = x[np.clip(idx - i, 0, None)]
    b = x[np.clip(idx - i - 1, 0, None)]
    return (1.0 - f) * a + f * b


def _filled(x: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x)
    if ok.all() or ok.sum() < 2:
        return np.nan_to_num(x)
    return np.interp(np.arange(x.size), np.flatnonzero(ok), x[ok])


def regressors(u: np.ndarray, wabs: Optional[np.ndarray], dt: float, m: AxisModel,
               coupled: bool) -> np.ndarray:
    """Return the response columns: [chain(u)] and, forward, [chain(u |omega|)]."""
    u1 = deadband(u, m.band)
    cols = [u1] + ([u1 * wabs] if coupled and wabs is not None else [])
    out = [shift(lag(rate_limit(c, dt, m.limit), dt, m.tau), m.d, dt) for c in cols]
    return np.column_stack(out)


def predict(u: np.ndarray, wabs: Optional[np.ndarray], dt: float, m: AxisModel,
            gain: bool = True) -> np.ndarray:
    """Return the modelled real channel (exact chain, k applied before the rate limit)."""
    u1 = deadband(u, m.band)
    if wabs is not None and m.k:
        u1 = u1 * (1.0 - m.k * wabs)
    y = shift(lag(rate_limit(u1, dt, m.limit), dt, m.tau), m.d, dt)
    return (1.0 + m.gain) * y if gain else y


def _solve(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Return (coefficients, SSE) of y ~ X on the samples ``w`` (bool), by normal equations."""
    wf = w.astype(float)
    Xw = X * wf[:, None]
    A = Xw.T @ X + 1e-12 * np.eye(X.shape[1])
    b = Xw.T @ y
    c = np.linalg.solve(A, b)
    yy = float((wf * y) @ y)
    return c, max(yy - float(c @ b), 0.0)


def _linear(m: AxisModel, c: np.ndarray) -> AxisModel:
    g = float(c[0]) - 1.0
    k = float(-c[1] / c[0]) if c.size > 1 and c[0] != 0 else 0.0
    return replace(m, gain=g, k=k)


def _grid(u, wabs, y, w, dt, m: AxisModel, coupled: bool, max_d: float,
          free: tuple = ('d', 'tau')) -> tuple[AxisModel, float]:
    """Return the best (d, tau) on grids (others fixed) with g, k solved linearly."""
    taus = _TAUS if 'tau' in free else [m.tau]
    step = max(1, int(round(0.04 / dt)))
    ds = [k * dt for k in range(0, int(max_d / dt) + 1, step)] if 'd' in free else [m.d]
    rl = regressors(u, wabs, dt, replace(m, tau=0.0, d=0.0), coupled)
    best = (math.inf, m)
    for tau in taus:
        base = lag(rl, dt, float(tau))
        for d in ds:
            c, sse = _solve(shift(base, d, dt), y, w)
            if sse < best[0]:
                best = (sse, _linear(replace(m, tau=float(tau), d=float(d)), c))
    return best[1], best[0]


def _refine(u, wabs, y, w, dt, m: AxisModel, coupled: bool, max_d: float) -> AxisModel:
    """Return ``m`` with d and tau refined between grid points (golden search, each in turn)."""
    from scipy.optimize import minimize_scalar

    def sse(mm: AxisModel) -> float:
        return _solve(regressors(u, wabs, dt, mm, coupled), y, w)[1]

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
    c, _ = _solve(regressors(u, wabs, dt, m, coupled), y, w)
    return _linear(m, c)


def fit_axis(u: np.ndarray, wabs: Optional[np.ndarray], y: np.ndarray, w: np.ndarray,
             dt: float, max_d: float, parts: set, refine: bool = False) -> AxisModel:
    """
    Fit the chain with only ``parts`` free (names of :data:`PARTS`); return the model.

    ``u`` the simulated channel, ``wabs`` |simulated turn rate| (forward axis),
    ``y`` the real channel, ``w`` the samples fitted (bool).
    """
    coupled = 'turn_speed_loss' in parts and wabs is not None
    free = tuple(p for p, n in (('d', 'drive_dead_time'), ('tau', 'drive_lag')) if n in parts)
    m = AxisModel(parts=set(parts))
    m, sse = _grid(u, wabs, y, w, dt, m, coupled, max_d, free) if free else \
        (_linear(m, _solve(regressors(u, wabs, dt, m, coupled), y, w)[0]), 0.0)
    scale = float(np.percentile(np.abs(u[w]), 95)) if w.any() else 0.0
    if 'drive_deadband' in parts and scale > 0:
        best = (math.inf, m)
        for f in (0.0, 0.01, 0.02, 0.04, 0.06, 0.08, 0.1, 0.13, 0.16, 0.2):
            mm = replace(m, band=f * scale)
            c, s = _solve(regressors(u, wabs, dt, mm, coupled), y, w)
            if s < best[0]:
                best = (s, _linear(mm, c))
        m = best[1]
    if 'drive_rate_limit' in parts and scale > 0:
        jumps = np.abs(np.diff(u))
        step = float(np.percentile(jumps[jumps > 1e-3 * scale], 90)) \
            if (jumps > 1e-3 * scale).sum() > 5 else scale
        best = (math.inf, m)
        for ramp in (0.0, 0.05, 0.1, 0.2, 0.3, 0.45, 0.65, 0.9, 1.3, 2.0):
            mm = replace(m, limit=step / ramp if ramp > 0 else math.inf)
            c, s = _solve(regressors(u, wabs, dt, mm, coupled), y, w)
            if s < best[0]:
                best = (s, _linear(mm, c))
        m = best[1]
    if free and (m.band > 0 or math.isfinite(m.limit)):
        m, _ = _grid(u, wabs, y, w, dt, m, coupled, max_d, free)
    if refine and free:
        m = _refine(u, wabs, y, w, dt, m, coupled, max_d)
    m.parts = set(parts)
    return m


def _chunk_sse(r: np.ndarray, held: np.ndarray, ok: np.ndarray, chunk: int) -> np.ndarray:
    """Return the SSE of ``r`` per held-out chunk."""
    idx = np.flatnonzero(held & ok)
    return np.bincount(idx // chunk, weights=r[idx] ** 2, minlength=r.size // chunk + 1)


def _axis_parts(f: str, has_w: bool) -> set:
    parts = set(PARTS)
    if f != V or not has_w:
        parts.discard('turn_speed_loss')
    return parts


@dataclass
class DriveResult:
    """The fitted drive: per field its model, the findings and the simulated channels it makes."""

    models: dict
    findings: list
    sim: dict
    text: str


def analyse_drive(pt: PairedTopic, prm) -> Optional[DriveResult]:
    """
    Fit the drive chain to an odometry topic; return it when any dynamic part is named.

    None when the topic has no forward or turn channel, when nothing beyond a
    pure delay (which the time stage judges) is named, or when the drive
    model is off (``prm.drive_model``).
    """
    if not getattr(prm, 'drive_model', True) or pt.msgtype != ODOM_TYPE or prm.mode == 'seed':
        return None
    fields = [f for f in (V, W) if f in pt.sim and f in pt.real]
    if not fields or pt.t.size < 200:
        return None
    dt = pt.dt
    n = pt.t.size
    held = held_mask(n, prm.heldout_chunks)
    chunk = max(1, n // prm.heldout_chunks)
    wabs = np.abs(_filled(pt.sim[W])) if W in pt.sim else None
    out_models, found, sims = {}, [], {}
    for f in fields:
        u, y = _filled(pt.sim[f]), pt.real[f]
        ok = np.isfinite(pt.sim[f]) & np.isfinite(y)
        if ok.sum() < 100 or np.std(u[ok]) <= 0:
            continue
        yf = np.nan_to_num(y)
        wa = wabs if f == V else None
        parts = _axis_parts(f, wa is not None)
        nchunks = int(np.count_nonzero(np.bincount(np.flatnonzero(held & ok) // chunk)))
        thr = L.t_quantile(prm.drive_alpha, max(nchunks - 1, 1))
        named, stats = _eliminate(u, wa, yf, ok, held, chunk, dt, prm, parts, thr)
        model = fit_axis(u, wa, yf, ok, dt, prm.drive_max_dead_time, named, refine=True)
        out_models[f] = (model, stats, ok)
    dyn = {p for m, _, _ in out_models.values() for p in m.parts} - {'drive_dead_time'}
    if not dyn:
        return None
    for f, (model, stats, ok) in out_models.items():
        wa = wabs if f == V else None
        u = _filled(pt.sim[f])
        sims[f] = np.where(np.isfinite(pt.sim[f]), predict(u, wa, dt, model, gain=False), np.nan)
        found.extend(_findings(pt, f, model, stats, ok, held, u, wa))
    text = describe({f: m for f, (m, _, _) in out_models.items()})
    for fd in found:
        fd['explanation'] += ' ' + text
    return DriveResult({f: m for f, (m, _, _) in out_models.items()}, found, sims, text)


def _eliminate(u, wa, yf, ok, held, chunk, dt, prm, parts: set, thr: float) -> tuple:
    """
    Backward elimination of the drive's parts by the held-out chunk test; return (named, stats).

    Parts that stand in for each other (a dead time, a lag and a rate limit all
    delay a step) each look dispensable while the others are there; dropping
    the weakest one at a time and testing again keeps the ones the data need.
    """
    fitw = ok & ~held
    cur = set(parts)
    while True:
        full = fit_axis(u, wa, yf, fitw, dt, prm.drive_max_dead_time, cur)
        r_full = yf - predict(u, wa, dt, full)
        s_full = _chunk_sse(r_full, held, ok, chunk)
        has = np.bincount(np.flatnonzero(held & ok) // chunk, minlength=s_full.size) > 0
        stats = {}
        for p in sorted(cur):
            red = fit_axis(u, wa, yf, fitw, dt, prm.drive_max_dead_time, cur - {p})
            r_red = yf - predict(u, wa, dt, red)
            dlt = (_chunk_sse(r_red, held, ok, chunk) - s_full)[has]
            se = float(np.std(dlt, ddof=1) / math.sqrt(dlt.size)) if dlt.size > 1 else math.inf
            z = float(np.mean(dlt) / se) if se > 0 else 0.0
            hb, ha = rmse(r_red, ok & held), rmse(r_full, ok & held)
            good = z > thr and hb is not None and ha is not None and \
                ha < (1.0 - prm.min_improvement) * hb
            stats[p] = (z, thr, int(dlt.size), red, hb, ha, good)
        bad = [p for p in cur if not stats[p][6]]
        if not bad:
            return cur, stats
        cur.discard(min(bad, key=lambda p: stats[p][0]))
        if not cur:
            return cur, stats


_VALUE = {'drive_dead_time': ('tau', 's', lambda m: m.d),
          'drive_lag': ('tau', 's', lambda m: m.tau),
          'drive_deadband': ('band', None, lambda m: m.band),
          'drive_rate_limit': ('limit', None, lambda m: m.limit),
          'turn_speed_loss': ('coefficient', 's/rad', lambda m: m.k)}


def _findings(pt: PairedTopic, f: str, m: AxisModel, stats: dict, ok: np.ndarray,
              held: np.ndarray, u: np.ndarray, wa: Optional[np.ndarray]) -> list:
    """Return one finding per named part of the axis (contract keys, held-out fit)."""
    from robot_calib.mismatch.effects import separating_motion
    out = []
    y = np.nan_to_num(pt.real[f])
    r_full = y - predict(u, wa, pt.dt, m)
    for p in sorted(m.parts):
        z, thr, nb, red, hb, ha, _ = stats[p]
        r_red = y - predict(u, wa, pt.dt, red)
        fitd = {'rmse_before': rmse(r_red, ok & ~held), 'rmse_after': rmse(r_full, ok & ~held),
                'heldout_rmse_before': hb, 'heldout_rmse_after': ha}
        key, unit, get = _VALUE[p]
        unit = unit or (UNIT[f] if p == 'drive_deadband' else UNIT[f] + '/s')
        val = float(get(m))
        strength = 1.0 - (thr / max(z, 1e-12)) ** 2
        alts = []
        if p in ('drive_lag', 'drive_dead_time'):
            other = 'drive_dead_time' if p == 'drive_lag' else 'drive_lag'
            alts_sep = separating_motion(p, other)
        else:
            alts_sep = separating_motion(p, 'drive_gain')
        fd = {'channel': f'{pt.name}.{f}', 'effect': p, 'parameters': {key: val},
              'window': None, 'fit': fitd, 'units': {key: unit},
              'std': {key: float('nan')}, 'channels': [f'{pt.name}.{f}'],
              'explanation': _sentence(p, f, val) + (
                  f' Modelling it cuts the held-out residual from {hb:.3g} to {ha:.3g}.'
                  if hb is not None and ha is not None else ''),
              'evidence': {'z': z, 'z_threshold': thr, 'blocks': nb, 'test': 'held-out chunks '
                           'of the drive model with and without it'},
              'evidence_strength': evidence(strength, fitd),
              'separating_motion': alts_sep}
        fd['confidence'] = confidence(fd['evidence_strength'], alts)
        out.append(fd)
    return out


def _sentence(p: str, f: str, val: float) -> str:
    ax = AXIS[f]
    if p == 'drive_lag':
        return f'The real {ax} follows the command with a first-order lag of {val:.3g} s.'
    if p == 'drive_dead_time':
        return f'The real {ax} starts to follow the command {val * 1000:.0f} ms late ' \
            '(dead time, before the lag).'
    if p == 'drive_deadband':
        return f'{ax.capitalize()} commands smaller than {val:.3g} {UNIT[f]} move nothing ' \
            '(deadband).'
    if p == 'drive_rate_limit':
        return f'The real {ax} changes no faster than {val:.3g} {UNIT[f]}/s (acceleration limit).'
    return f'The real forward speed drops while turning: speed = command x (1 - {val:.3g} ' \
        '|omega|), omega in rad/s.'


def describe(models: dict) -> str:
    """Return the drive in its own terms, one clause per axis."""
    parts = []
    for f, m in models.items():
        s = f'{AXIS[f]}: '
        bits = []
        if m.d > 0 and 'drive_dead_time' in m.parts:
            bits.append(f'{m.d:.2f} s dead time')
        if 'drive_lag' in m.parts:
            bits.append(f'{m.tau:.2f} s time constant')
        if not bits:
            bits.append('no lag')
        s += ' + '.join(bits) + f', settles at {100 * (1 + m.gain):.1f} % of the command'
        if 'turn_speed_loss' in m.parts:
            s += f', slows by {m.k:.2f} x |omega| in turns'
        if 'drive_deadband' in m.parts:
            s += f', deadband {m.band:.3g} {UNIT[f]}'
        if 'drive_rate_limit' in m.parts:
            s += f', rate limit {m.limit:.3g} {UNIT[f]}/s'
        parts.append(s)
    return 'Drive model (fitted together): ' + '; '.join(parts) + '.'
