# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The mismatch analysis: align, locate, name, model and show, or abstain.

:func:`analyse_recordings` takes two :class:`~robot_calib.mismatch.channels.Recording`
objects (the simulated and the real run) and returns the findings dict of
the contract (architecture.md, "Mismatch findings") plus additive keys:
``time_alignment`` (per topic, the cross-correlation lag and the delay
judged per sensor), ``channels`` (per channel the residual RMS, the noise
level and the windows where the residual is beyond noise), ``not_judged``
(what cannot be judged and why) and ``notes``.

Per sensor (topic) the analysis runs in three stages:

1. time: one delay per clock (the IMU's gyro and accelerometer may differ),
   from the phase of the cross-spectrum, kept when its jackknife error makes
   it significant; a drive (odometry, joint states) also tries a first-order
   lag (:mod:`.latency`). The simulation is then shifted by it.
2. amplitude: forward selection of the library's effects on the aligned
   residual (:mod:`.select`), kept only when they pass a block-robust test
   (:mod:`.robust`) and improve held-out time.
3. what is left: structure beyond noise that no effect explains becomes one
   ``unexplained`` finding (where, how large, what it follows), never a
   forced wrong name (:mod:`.residual`).

Held-out evaluation: the common time line is cut into ``heldout_chunks``
equal chunks; every third chunk is held out. The selected effects are
re-fitted on the other chunks only and the RMSE of ``real - sim`` before and
after applying them is reported on both parts, inside the finding's window.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from robot_calib.core.params import param
from robot_calib.mismatch import effects as E
from robot_calib.mismatch import latency as L
from robot_calib.mismatch import residual as U
from robot_calib.mismatch import robust as R
from robot_calib.mismatch import select as S
from robot_calib.mismatch.channels import (ChannelError, IMU_TYPE, ODOM_TYPE, pair_topics,
                                           PairedTopic, Recording, TWIST_TYPES)
from robot_calib.mismatch.explain import explain
from robot_calib.mismatch.locate import (active_windows, local_weights, moving_average,
                                         noise_level)


@dataclass
class MismatchParams:
    """Parameters of the mismatch analyser."""

    mode: str = param('improved', '', "'improved' (windows, alternatives, exact refinement) "
                      "or 'seed' (global effects only, no windows)",
                      choices=('improved', 'seed'))
    margin: float = param(12.0, '', 'BIC gain an effect must bring to be considered',
                          minimum=0.0)
    alt_margin: float = param(10.0, '', 'BIC distance within which another effect is listed '
                              'as an alternative', minimum=0.0)
    max_lag: float = param(0.5, 's', 'largest time offset searched by cross-correlation',
                           minimum=0.0)
    min_window: float = param(0.03, '', 'shortest effect window as a fraction of the recording',
                              minimum=0.0, maximum=1.0)
    min_window_s: float = param(2.0, 's', 'shortest effect window', minimum=0.0)
    noise_smooth: float = param(2.0, 's', 'moving average removed before measuring the noise',
                                minimum=0.0)
    heldout_chunks: int = param(60, '', 'chunks of the time line; every third is held out',
                                minimum=3)
    max_terms: int = param(14, '', 'most effects selected per topic', minimum=1)
    alpha: float = param(1e-6, '', 'false-alarm probability of the block-robust test an '
                         'effect must pass', minimum=1e-15, maximum=0.5)
    blocks: int = param(40, '', 'contiguous blocks of the time line for the block-robust '
                        'tests', minimum=4)
    min_block_s: float = param(1.0, 's', 'shortest block of the block-robust tests',
                               minimum=0.0)
    min_confidence: float = param(0.5, '', 'least evidence (0..1) of a reported finding; '
                                  'weaker ones are listed apart as weak_findings',
                                  minimum=0.0, maximum=1.0)
    floor_scale: float = param(1.0, '', 'multiplies each effect\'s reporting floor (the '
                               'smallest size worth naming); smaller effects are listed as '
                               'minor_findings; 0 reports every significant effect',
                               minimum=0.0)


@dataclass
class TopicDetail:
    """
    What the report needs of one analysed topic.

    ``pt`` is the paired topic as recorded, ``prob0`` its residual before any
    effect, ``prob`` the residual after the time stage (the simulation
    delayed), ``sel`` and ``final`` the amplitude effects and their fit,
    ``held`` the held-out samples.
    """

    pt: PairedTopic
    prob0: S.Problem
    prob: S.Problem
    sel: list
    final: S.Fit
    term_findings: list
    time_findings: list
    unexplained: Optional[dict]
    held: np.ndarray


def _t_abs_interp(t_src: np.ndarray, x: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x)
    if ok.sum() < 2:
        return np.full(t_dst.size, np.nan)
    y = np.interp(t_dst, t_src[ok], x[ok])
    y[(t_dst < t_src[ok][0] - 0.5) | (t_dst > t_src[ok][-1] + 0.5)] = np.nan
    return y


def _aux(sim: Recording, real: Recording, pt: PairedTopic, t0: float, notes: list) -> dict:
    """Return sim regressors on the topic's times: v (m/s), omega (rad/s), acmd (m/s^2)."""
    aux: dict = {}
    ta = pt.t + t0
    odoms = [tp for tp in sim.values() if tp.msgtype == ODOM_TYPE and len(tp) > 2]
    odoms.sort(key=lambda tp: ('truth' not in tp.name, tp.name))
    if odoms:
        o = odoms[0]
        aux['v'] = _t_abs_interp(o.t, o.fields['twist.twist.linear.x'], ta)
        aux['omega'] = _t_abs_interp(o.t, o.fields['twist.twist.angular.z'], ta)
    if pt.msgtype == IMU_TYPE and 'angular_velocity.z' in pt.sim:
        aux['omega'] = np.nan_to_num(pt.sim_reg['angular_velocity.z'])
    cmds = [tp for rec in (sim, real) for tp in rec.values()
            if tp.msgtype in TWIST_TYPES and len(tp) > 2]
    if cmds:
        c = cmds[0]
        a = np.gradient(c.fields['linear.x'], c.t)
        aux['acmd'] = _t_abs_interp(c.t, a, ta)
    elif pt.msgtype == ODOM_TYPE and 'twist.twist.linear.x' in pt.sim:
        v = np.nan_to_num(pt.sim['twist.twist.linear.x'])
        w = max(1, int(round(0.2 / max(pt.dt, 1e-9))))
        aux['acmd'] = np.gradient(moving_average(v, w), pt.t)
        notes.append(f'{pt.name}: no velocity-command topic; the commanded acceleration for '
                     'wheel slip is taken from the simulated speed')
    return {k: np.nan_to_num(v) for k, v in aux.items()}


def _floor(res: np.ndarray, m: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Return the smallest noise level used (noiseless data): keeps chi2 well conditioned."""
    scale = max(float(np.sqrt(np.mean(b[m] ** 2))), float(np.sqrt(np.mean(a[m] ** 2))))
    return max(1e-3 * float(np.sqrt(np.mean(res[m] ** 2))), 1e-9 * scale, 1e-12)


def _problem(pt: PairedTopic, smooth: float, not_judged: Optional[list]) -> Optional[S.Problem]:
    fields, r, mask, sigma, phi = [], {}, {}, {}, {}
    for f in pt.sim:
        a, b = pt.sim[f], pt.real[f]
        m = np.isfinite(a) & np.isfinite(b)
        ch = f'{pt.name}.{f}'
        if m.sum() < 20:
            if not_judged is not None:
                not_judged.append({'channel': ch, 'reason': 'empty: no overlapping samples'})
            continue
        if np.ptp(b[m]) == 0 and np.ptp(a[m]) > 0:
            if not_judged is not None:
                not_judged.append({'channel': ch, 'reason': 'the real channel is constant while '
                                   'the simulated one varies (a stuck or unfilled field)'})
            continue
        res = np.where(m, b - a, 0.0)
        s, ph = noise_level(res, m, pt.dt, smooth)
        s = max(s, _floor(res, m, a, b))
        fields.append(f)
        r[f], mask[f], sigma[f], phi[f] = res, m, s, ph
    if not fields:
        return None
    return S.Problem(pt, fields, r, mask, sigma, phi, pt.t.size)


def _rmse(x: np.ndarray, m: np.ndarray) -> Optional[float]:
    return float(np.sqrt(np.mean(x[m] ** 2))) if m.any() else None


def _held_mask(n: int, chunks: int) -> np.ndarray:
    chunk = max(1, n // chunks)
    return ((np.arange(n) // chunk) % 3) == 2


# -- stage 1: time ------------------------------------------------------------------------
def _moving_fields(pt: PairedTopic, prob: S.Problem) -> list:
    """Return the fields whose simulated signal moves well beyond the channel noise."""
    out = []
    for f in prob.fields:
        x = pt.sim_reg[f][prob.mask[f]]
        x = x[np.isfinite(x)]
        if x.size > 20 and float(np.std(x)) > 3.0 * prob.sigma[f]:
            out.append(f)
    return out


def _group_data(pt: PairedTopic, prob: S.Problem, fields: list, keep: np.ndarray) -> dict:
    data = {}
    for i, group in enumerate(L.field_groups(pt.msgtype, fields)):
        sims, reals, oks = [], [], []
        for f in group:
            # the raw simulated channel: independent noise does not bias the cross-spectral
            # phase, while a smoothed copy would bend it
            ok = prob.mask[f] & keep
            sims.append(np.where(ok, pt.sim[f], 0.0))
            reals.append(np.where(ok, pt.real[f], 0.0))
            oks.append(ok)
        data[f'g{i}'] = (group, sims, reals, oks)
    return data


def _filled(x: np.ndarray) -> np.ndarray:
    """Return ``x`` with NaN replaced by linear interpolation (held at the ends)."""
    ok = np.isfinite(x)
    if ok.all() or ok.sum() < 2:
        return np.nan_to_num(x)
    return np.interp(np.arange(x.size), np.flatnonzero(ok), x[ok])


def delayed(x: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """
    Return ``x`` (on a grid of period ``dt``) delayed by ``tau`` s, NaN where unknown.

    An exact fractional delay (FFT phase ramp): linear interpolation would damp
    fast motion and noise and so pass for a scale error.
    """
    k = tau / dt
    y = L.shift_frac(_filled(x), k)
    bad = ~np.isfinite(x)
    lo, hi = int(np.floor(k)), int(np.ceil(k))
    unknown = np.zeros(x.size, bool)
    for s in {lo, hi}:
        sh = np.ones(x.size, bool)
        if 0 <= s < x.size:
            sh[s:] = bad[:x.size - s]
        elif -x.size < s < 0:
            sh[:s] = bad[-s:]
        unknown |= sh
    return np.where(unknown, np.nan, y)


def aligned(pt: PairedTopic, taus: dict) -> PairedTopic:
    """Return ``pt`` with the simulated fields delayed by ``taus[field]`` s (others unchanged)."""
    if not taus:
        return pt
    sim = {f: (delayed(x, taus[f], pt.dt) if f in taus else x) for f, x in pt.sim.items()}
    return replace(pt, sim=sim, sim_reg={}, sim_noisy={})


def _time_stage(pt: PairedTopic, prob: S.Problem, prm: MismatchParams,
                edges: np.ndarray) -> list:
    """Return the significant time effects of a topic: [(kind, TimeEffect, lag info)]."""
    fields = _moving_fields(pt, prob)
    if not fields:
        return []
    keep = np.ones(prob.n, bool)
    effects = L.delays_of(_group_data(pt, prob, fields, keep), pt.dt, edges, prm.alpha,
                          prm.max_lag)
    out = []
    for te in effects:
        kind, info = 'time_offset', {}
        if pt.msgtype != IMU_TYPE and te.delay.tau > 0:
            kind, info = _lag_or_delay(pt, prob, te, prm)
        out.append((kind, te, info))
    return out


def _whitened_chi2(prob: S.Problem, fields: list, pred: dict) -> float:
    """Return the chi2 of ``real - pred`` after a per-field offset and scale are fitted."""
    total = 0.0
    for f in fields:
        m = prob.mask[f] & np.isfinite(pred[f])
        y = prob.pt.real[f][m] - pred[f][m]
        X = np.column_stack((np.ones(m.sum()), pred[f][m]))
        beta, *_ = np.linalg.lstsq(X, y, rcond=None)
        e = y - X @ beta
        total += float(e @ e) * prob.w[f]
    return total


def _golden(fun, lo: float, hi: float, iters: int = 30) -> float:
    """Return the minimiser of a unimodal ``fun`` on [lo, hi] by golden-section search."""
    g = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    for _ in range(iters):
        c, d = b - g * (b - a), a + g * (b - a)
        if fun(c) < fun(d):
            b = d
        else:
            a = c
    return 0.5 * (a + b)


def _lag_or_delay(pt: PairedTopic, prob: S.Problem, te: L.TimeEffect,
                  prm: MismatchParams) -> tuple[str, dict]:
    """
    Compare a pure delay with a first-order lag of the drive; return (effect name, info).

    Both are fitted by least squares in time (each with its own time
    constant, after a per-field offset and scale), so neither is favoured by
    the estimator; the lag must fit better by ``alt_margin`` to be named.
    """
    sims = {f: _filled(pt.sim[f]) for f in te.fields}
    tau0 = te.delay.tau

    def chi_delay(tau: float) -> float:
        return _whitened_chi2(prob, te.fields,
                              {f: delayed(pt.sim[f], tau, pt.dt) for f in te.fields})

    def chi_lag(log_tau: float) -> float:
        return _whitened_chi2(prob, te.fields, {f: L.lag_response(sims[f], pt.dt,
                                                                  np.exp(log_tau))
                                                for f in te.fields})
    tau_d = _golden(chi_delay, tau0 - 0.5 * abs(tau0) - pt.dt, tau0 + 0.5 * abs(tau0) + pt.dt)
    log_l = _golden(chi_lag, np.log(max(pt.dt, 0.2 * tau0)), np.log(max(5.0 * tau0, 3 * pt.dt)))
    info = {'delay_chi2': chi_delay(tau_d), 'lag_chi2': chi_lag(log_l),
            'lag_tau': float(np.exp(log_l)), 'delay_tau_ls': float(tau_d)}
    better = info['lag_chi2'] < info['delay_chi2'] - prm.alt_margin
    return ('drive_lag' if better else 'time_offset'), info


# -- stage 2: amplitude effects -------------------------------------------------------------
def _implausible(prob: S.Problem, sel: list, not_judged: list) -> tuple[list, list]:
    """
    Move effects fitted far beyond their plausible range out of the findings.

    A parameter beyond the plausible magnitude of a working sensor (e.g. a
    gyro scale of -1: the real channel does not follow the simulation at all)
    is not a physical effect of that name; it is reported as a stretch the tool
    cannot explain. Returns (kept terms, [(term, parameters)] dropped).
    """
    if not sel:
        return sel, []
    f = S.fit(prob, sel)
    keep, dropped = [], []
    for i, t in enumerate(sel):
        params, _ = E.to_params(t, f.betas[i], f.covs[i])
        spec = E.SPECS[t.effect]
        bad = [k for k, lim in zip(spec.params, spec.plausible)
               if np.isfinite(params[k]) and abs(params[k]) > lim]
        if not bad:
            keep.append(t)
            continue
        dropped.append((t, params))
        pt = prob.pt
        where = 'the whole recording' if t.window is None else \
            f'{pt.t[t.window[0]]:.1f}-{pt.t[min(t.window[1], prob.n) - 1]:.1f} s'
        desc = ', '.join(f'{k} = {params[k]:.3g}' for k in bad)
        not_judged.append({'channel': t.channel, 'reason': f'in {where} the real channel does '
                           f'not follow the simulation (the best {t.effect} fit, {desc}, is far '
                           'beyond a physical value; is the simulated signal noise there?)'})
    if len(keep) < len(sel):
        keep = S.refine_nonlinear(prob, keep)
    return keep, dropped


def _plain_offsets(prob: S.Problem, sel: list, prm: MismatchParams) -> list:
    """
    Return ``sel`` with drifting offsets whose drift is immaterial replaced by plain offsets.

    A drift that moves the offset by less than the offset's reporting floor
    over the recording is not worth naming; the plain offset is the simpler
    claim (its terms are made from the drift term's first column).
    """
    out = list(sel)
    f = S.fit(prob, out)
    span = float(prob.pt.t[-1] - prob.pt.t[0]) if prob.n else 0.0
    floor = prm.floor_scale * E.SPECS['gyro_bias'].floor
    for i, t in enumerate(out):
        if t.effect != 'gyro_bias_drift' or abs(f.betas[i][1]) * span >= floor:
            continue
        out[i] = E.Term('gyro_bias', t.topic, {k: c[:, :1] for k, c in t.cols.items()}, t.group,
                        t.channel, t.windowable, t.window, dict(t.meta))
    return out


def _min_len(prob: S.Problem, prm: MismatchParams) -> int:
    """Return the shortest effect window (samples); longer than the recording in seed mode."""
    if prm.mode == 'seed':  # global effects only
        return prob.n + 1
    return max(20, int(prm.min_window * prob.n), int(prm.min_window_s / max(prob.pt.dt, 1e-9)))


def _select(prob: S.Problem, cands: list, prm: MismatchParams, edges: np.ndarray,
            notes: list, not_judged: list) -> tuple[list, S.Problem, list]:
    pt = prob.pt
    min_len = _min_len(prob, prm)
    sel, _ = S.forward_select(prob, cands, prm.margin, min_len, prm.max_terms)
    # second pass with the noise level, and its changes along the recording, measured on
    # the first model's residual
    cur = S.fit(prob, sel, contributions=True)
    sig2, phi2, sw2 = {}, {}, {}
    for f in prob.fields:
        e = prob.r[f] - cur.contrib.get(f, 0.0)
        s, ph = noise_level(e, prob.mask[f], pt.dt, prm.noise_smooth)
        sig2[f] = max(s, _floor(prob.r[f], prob.mask[f], pt.sim[f], pt.real[f]))
        phi2[f] = ph
        sw2[f] = np.sqrt(local_weights(e, prob.mask[f], pt.dt, prm.noise_smooth,
                                       prm.noise_smooth))
    prob = S.Problem(pt, prob.fields, prob.r, prob.mask, sig2, phi2, prob.n, sw=sw2)
    sel, _ = S.forward_select(prob, cands, prm.margin, min_len, prm.max_terms)
    if sel and prm.mode != 'seed':
        sel = S.refine_windows(prob, sel, min_len)
        sel = S.unexcited_windows(prob, sel)
    sel = S.refine_nonlinear(prob, sel)
    sel = S.backward_eliminate(prob, sel, prm.margin)
    sel, dropped = R.robust_prune(prob, sel, edges, prm.alpha,
                                  refine=lambda ts: S.refine_nonlinear(prob, ts),
                                  min_block_s=prm.min_block_s)
    for t, (w, thr, kb) in dropped:
        notes.append(f'{t.channel}: a candidate {t.effect} fits, but not consistently across '
                     f'the recording (robust test {w:.3g} < {thr:.3g} over {kb} blocks); '
                     'not reported')
    sel = _plain_offsets(prob, sel, prm)
    sel, implausible = _implausible(prob, sel, not_judged)
    held = _heldout(prob, sel, prm.heldout_chunks) if sel else {}
    bad = {i for i, h in held.items() if h['heldout_rmse_before'] is not None and
           h['heldout_rmse_after'] is not None and
           h['heldout_rmse_after'] > h['heldout_rmse_before']}
    for i in sorted(bad):
        notes.append(f'{sel[i].channel}: a candidate {sel[i].effect} did not improve the '
                     'held-out part and is not reported')
    sel = [t for i, t in enumerate(sel) if i not in bad]
    return sel, prob, implausible


def _predict(prob: S.Problem, terms: list, betas: list, f: str) -> np.ndarray:
    out = np.zeros(prob.n)
    for t, b in zip(terms, betas):
        if f not in t.cols:
            continue
        c = S.mdot(t.cols[f], b)
        off = t.meta.get('offset')
        if off is not None and f in off:
            c = c + off[f]
        if t.window is not None:
            m = np.zeros(prob.n, bool)
            m[t.window[0]:t.window[1]] = True
            c = np.where(m, c, 0.0)
        out += c
    return out


def _heldout(prob: S.Problem, sel: list, chunks: int) -> dict:
    """Re-fit the selected terms on the fitting chunks; RMSE before/after per selected term."""
    n = prob.n
    held = _held_mask(n, chunks)
    fit_mask = {f: prob.mask[f] & ~held for f in prob.fields}
    pf = S.Problem(prob.pt, prob.fields, prob.r, fit_mask, prob.sigma, prob.phi, n,
                   sw=dict(prob.sw))
    fr = S.fit(pf, sel)
    out = {}
    for i, t in enumerate(sel):
        f = t.channel[len(t.topic) + 1:]
        if f not in prob.fields:
            f = next(iter(t.cols))
        pred = _predict(prob, sel, fr.betas, f)
        m = prob.mask[f].copy()
        if t.window is not None:
            w = np.zeros(n, bool)
            w[t.window[0]:t.window[1]] = True
            m &= w
        r = prob.r[f]
        out[i] = {'rmse_before': _rmse(r, m & ~held), 'rmse_after': _rmse(r - pred, m & ~held),
                  'heldout_rmse_before': _rmse(r, m & held),
                  'heldout_rmse_after': _rmse(r - pred, m & held)}
    return out


# -- findings -------------------------------------------------------------------------------
def _evidence(strength: float, fitd: dict) -> float:
    """
    Return the evidence (0..1) that a finding is real, whatever its name.

    The product of how far the robust statistic clears its bar
    (``1 - bar / statistic``) and whether held-out time confirms at least half
    of the in-sample improvement (full credit), less (partial) or none.
    """
    s = float(np.clip(strength, 0.0, 1.0))
    hb, ha = fitd.get('heldout_rmse_before'), fitd.get('heldout_rmse_after')
    ib, ia = fitd.get('rmse_before'), fitd.get('rmse_after')
    gen = 1.0
    if None not in (hb, ha, ib, ia) and ib ** 2 - ia ** 2 > 0:
        gen = float(np.clip(2.0 * (hb ** 2 - ha ** 2) / (ib ** 2 - ia ** 2), 0.0, 1.0))
    return round(s * gen, 3)


def _confidence(evidence: float, alt_deltas: list) -> float:
    """
    Return the confidence (0..1) in the finding's name: its evidence times its share.

    The share among the explanations that fit about as well is a BIC weight,
    ``1 / (1 + sum exp(-delta / 2))`` over the alternatives (Schwarz 1978).
    """
    alt = 1.0 / (1.0 + sum(float(np.exp(-max(d, 0.0) / 2.0)) for d in alt_deltas))
    return round(evidence * alt, 3)


def _field_taus(te: L.TimeEffect) -> dict:
    """Return the delay applied to each field: the pooled one, or its group's when they differ."""
    out = {}
    for group, d in te.groups.items():
        out.update({f: (te.delay.tau if te.consistent else d.tau) for f in group})
    return out


def _time_fit(pt: PairedTopic, prob: S.Problem, te: L.TimeEffect, prm: MismatchParams,
              edges: np.ndarray) -> tuple[str, dict]:
    """Return (best channel, fit dict): the delay re-estimated without the held-out chunks."""
    held = _held_mask(prob.n, prm.heldout_chunks)
    refit = L.delays_of(_group_data(pt, prob, te.fields, ~held), pt.dt, edges, 1.0, prm.max_lag)
    moved = aligned(pt, _field_taus(refit[0] if refit else te))
    best, fitd, channel = None, {}, f'{pt.name}.{te.fields[0]}'
    for f in te.fields:
        r0 = prob.r[f]
        r1 = np.where(prob.mask[f], pt.real[f] - moved.sim[f], np.nan)
        m = prob.mask[f] & np.isfinite(r1)
        fd = {'rmse_before': _rmse(r0, m & ~held), 'rmse_after': _rmse(r1, m & ~held),
              'heldout_rmse_before': _rmse(r0, m & held),
              'heldout_rmse_after': _rmse(r1, m & held)}
        gain = (fd['heldout_rmse_before'] or 0.0) - (fd['heldout_rmse_after'] or 0.0)
        if best is None or gain > best:
            best, fitd, channel = gain, fd, f'{pt.name}.{f}'
    return channel, fitd


def _time_findings(pt: PairedTopic, prob: S.Problem, found: list, prm: MismatchParams,
                   edges: np.ndarray) -> list:
    """Return the findings of the time stage, with held-out fit (delay re-estimated without)."""
    out = []
    for kind, te, info in found:
        d = te.delay
        channel, fitd = _time_fit(pt, prob, te, prm, edges)
        tau = d.tau if kind == 'time_offset' else info['lag_tau']
        params, sds = {'tau': float(tau)}, {'tau': float(d.std)}
        z_thr = L.t_quantile(prm.alpha, d.blocks - 1)
        alt = []
        if info:
            other = 'drive_lag' if kind == 'time_offset' else 'time_offset'
            gap = abs(info['lag_chi2'] - info['delay_chi2'])
            if gap < prm.alt_margin:
                alt.append({'effect': other, 'channel': channel, 'delta_bic': float(gap),
                            'parameters': {'tau': float(d.tau if other == 'time_offset'
                                                        else info['lag_tau'])},
                            'separating_motion': E.separating_motion(kind, other)})
        text = explain(kind, params, None, fitd)
        per_group = {g[0].rsplit('.', 1)[0]: gd.tau for g, gd in te.groups.items()}
        if not te.consistent:
            text += ' Its channels do not share one delay: ' + ', '.join(
                f'{k} {v * 1000:.1f} ms' for k, v in per_group.items()) + \
                ' (filters of different delay inside the sensor, or in the reference).'
        fd = {'channel': channel, 'effect': kind, 'parameters': params, 'window': None,
              'fit': fitd, 'explanation': text,
              'std': sds, 'ci95': {'tau': [tau - 1.96 * d.std, tau + 1.96 * d.std]},
              'units': {'tau': 's'}, 'channels': [f'{pt.name}.{f}' for f in te.fields],
              'per_group': per_group,
              'evidence': {'z': float(d.z), 'z_threshold': z_thr, 'blocks': d.blocks,
                           'band_hz': list(d.band_hz), 'coherence': d.coherence},
              'evidence_strength': _evidence(1.0 - (z_thr / max(d.z, 1e-12)) ** 2, fitd)}
        fd['confidence'] = _confidence(fd['evidence_strength'], [a['delta_bic'] for a in alt])
        if alt:
            fd['alternatives'] = alt
        out.append(fd)
    return out


def _term_finding(prob: S.Problem, final: S.Fit, sel: list, i: int, fitd: dict,
                  test: tuple, alts: list) -> dict:
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
    fd['evidence_strength'] = _evidence(1.0 - thr / max(w, 1e-12), fitd)
    fd['confidence'] = _confidence(fd['evidence_strength'], deltas)
    return fd


def _analyse_topic(pt: PairedTopic, sim: Recording, real: Recording, t0: float,
                   prm: MismatchParams, notes: list, not_judged: list,
                   channel_info: dict) -> tuple[list, Optional[S.Problem], list, dict]:
    prob0 = _problem(pt, prm.noise_smooth, not_judged)
    if prob0 is None:
        return [], None, [], {}
    edges = R.block_edges(prob0.n, pt.dt, prm.blocks, prm.min_block_s)
    timing = _time_stage(pt, prob0, prm, edges)
    findings = _time_findings(pt, prob0, timing, prm, edges)
    taus = {}
    for kind, te, _ in timing:
        if kind == 'time_offset':
            taus.update(_field_taus(te))
    pta = aligned(pt, taus)
    lags = [(te, info) for kind, te, info in timing if kind == 'drive_lag']
    if lags:
        sim_l = dict(pta.sim)
        for te, info in lags:
            sim_l.update({f: _lagged(pt, f, info['lag_tau']) for f in te.fields})
        pta = replace(pta, sim=sim_l, sim_reg={}, sim_noisy={})
    prob = _problem(pta, prm.noise_smooth, None) if (taus or lags) else prob0
    if prob is None:
        return findings, None, [], {}
    aux = _aux(sim, real, pta, t0, notes)
    cands, cannot = E.candidates(pta, prob.sigma, aux)
    notes.extend(c for c in cannot if c not in notes)
    sel, prob, implausible = _select(prob, cands, prm, edges, notes, not_judged)
    held = _heldout(prob, sel, prm.heldout_chunks) if sel else {}
    final = S.fit(prob, sel, contributions=True)
    tests = R.wald(prob, sel, final, edges, prm.alpha, prm.min_block_s) if sel else []
    alts = S.alternatives(prob, sel, cands, _min_len(prob, prm), prm.alt_margin) \
        if sel and prm.mode != 'seed' else {}
    term_findings = [_term_finding(prob, final, sel, i, held.get(i, {}), tests[i],
                                   alts.get(i, [])) for i in range(len(sel))]
    time_findings = list(findings)
    findings.extend(term_findings)
    for f in prob.fields:
        r, m = prob0.r[f], prob0.mask[f]
        left = prob.r[f] - final.contrib.get(f, 0.0)
        channel_info[f'{pt.name}.{f}'] = {
            'rmse': _rmse(r, m), 'noise': prob.sigma[f], 'noise_inflation': prob.phi[f],
            'rmse_after': _rmse(left, prob.mask[f]),
            'beyond_noise': active_windows(pt.t, r, m, prob0.sigma[f], prob0.phi[f])}
    extra = U.unexplained(prob, final, aux, edges, implausible)
    if extra is not None:
        findings.append(extra)
    detail = TopicDetail(pt, prob0, prob, sel, final, term_findings, time_findings, extra,
                         _held_mask(prob.n, prm.heldout_chunks))
    return findings, prob, sel, {'delays': timing, 'detail': detail}


def _lagged(pt: PairedTopic, f: str, tau: float) -> np.ndarray:
    x = pt.sim[f]
    return np.where(np.isfinite(x), L.lag_response(_filled(x), pt.dt, tau), np.nan)


def analyse_recordings(sim: Recording, real: Recording,
                       params: Optional[MismatchParams] = None) -> tuple[dict, list]:
    """
    Compare two recordings; return (findings dict, per-topic :class:`TopicDetail` list).

    :raises ChannelError: when nothing can be compared
    """
    prm = params or MismatchParams()
    paired, not_judged, t0, notes = pair_topics(sim, real, prm.max_lag)
    if not paired:
        reasons = '; '.join(f'{d["channel"]}: {d["reason"]}' for d in not_judged) or \
            'no common topic'
        raise ChannelError(f'no channel can be compared ({reasons})')
    findings: list = []
    details: list = []
    channel_info: dict = {}
    timing: dict = {}
    for pt in paired:
        notes.extend(pt.notes)
        fs, prob, sel, info = _analyse_topic(pt, sim, real, t0, prm, notes, not_judged,
                                             channel_info)
        timing[pt.name] = {'xcorr_lag': pt.tau_xcorr, 'xcorr_gain': pt.xcorr_gain,
                           'delays': [{'fields': te.fields, 'effect': kind,
                                       'tau': te.delay.tau, 'std': te.delay.std}
                                      for kind, te, _ in info.get('delays', [])]}
        findings.extend(fs)
        if 'detail' in info:
            details.append(info['detail'])
    if not channel_info:
        raise ChannelError('no channel can be compared (' + '; '.join(
            f'{d["channel"]}: {d["reason"]}' for d in not_judged) + ')')
    findings.sort(key=lambda f: (f['effect'] == 'unexplained', -f.get('confidence', 0.0)))
    duration = max((float(pt.t[-1] - pt.t[0]) for pt in paired if pt.t.size), default=0.0)
    weak = [f for f in findings if f.get('evidence_strength', f['confidence']) <
            prm.min_confidence]
    minor = [f for f in findings if f not in weak and f['effect'] != 'unexplained' and
             E.effect_size(f['effect'], f['parameters'], duration) <
             prm.floor_scale * E.SPECS[f['effect']].floor]
    findings = [f for f in findings if f not in weak and f not in minor]
    for f in minor:
        f['explanation'] += ' It is smaller than the ' \
            f'{E.SPECS[f["effect"]].floor:g} worth naming for a ground robot, so it is listed ' \
            'as minor.'
    out = {'verdict': 'mismatch' if findings else 'consistent',
           'findings': findings, 'minor_findings': minor, 'weak_findings': weak,
           'time_alignment': timing,
           'channels': channel_info,
           'not_judged': not_judged, 'notes': notes, 'bag_start': t0}
    return out, details
