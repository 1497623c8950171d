# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The mismatch analysis: align, locate, name, model and show, or abstain.

:func:`analyse_recordings` takes two :class:`~robot_calib.mismatch.channels.Recording`
objects (the simulated and the real run) and returns the findings dict of
the contract (architecture.md, "Mismatch findings") plus additive keys:
``time_alignment`` (per topic, the cross-correlation lag), ``channels``
(per channel the residual RMS, the noise level and the windows where the
residual is beyond noise), ``not_judged`` (what cannot be judged and why)
and ``notes``.

Held-out evaluation: the common time line is cut into ``heldout_chunks``
equal chunks; every third chunk is held out. The selected effects (with
their windows and nonlinear parameters from the whole recording) are
re-fitted on the other chunks only and the RMSE of ``real - sim`` before and
after applying them is reported on both parts, inside the finding's window.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from robot_calib.core.params import param
from robot_calib.mismatch import effects as E
from robot_calib.mismatch import select as S
from robot_calib.mismatch.channels import (ChannelError, IMU_TYPE, ODOM_TYPE, pair_topics,
                                           PairedTopic, Recording, TWIST_TYPES)
from robot_calib.mismatch.locate import active_windows, moving_average, noise_level


@dataclass
class MismatchParams:
    """Parameters of the mismatch analyser."""

    mode: str = param('improved', '', "'improved' (windows, alternatives, exact refinement) "
                      "or 'seed' (global effects only, no windows)",
                      choices=('improved', 'seed'))
    margin: float = param(12.0, '', 'BIC gain an effect must bring to be reported', minimum=0.0)
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


def _problem(pt: PairedTopic, smooth: float, not_judged: list) -> Optional[S.Problem]:
    fields, r, mask, sigma, phi = [], {}, {}, {}, {}
    for f in pt.sim:
        a, b = pt.sim[f], pt.real[f]
        m = np.isfinite(a) & np.isfinite(b)
        ch = f'{pt.name}.{f}'
        if m.sum() < 20:
            not_judged.append({'channel': ch, 'reason': 'empty: no overlapping samples'})
            continue
        if np.ptp(b[m]) == 0 and np.ptp(a[m]) > 0:
            not_judged.append({'channel': ch, 'reason': 'the real channel is constant while the '
                               'simulated one varies (a stuck or unfilled field)'})
            continue
        res = np.where(m, b - a, 0.0)
        s, ph = noise_level(res, m, pt.dt, smooth)
        s = max(s, _floor(res, m, a, b))
        fields.append(f)
        r[f], mask[f], sigma[f], phi[f] = res, m, s, ph
    if not fields:
        return None
    return S.Problem(pt, fields, r, mask, sigma, phi, pt.t.size)


def _implausible(prob: S.Problem, sel: list, not_judged: list) -> list:
    """
    Move effects fitted far beyond their plausible range into ``not_judged``.

    A parameter beyond twice the plausible magnitude (e.g. a gyro scale of
    -1: the real channel does not follow the simulation at all) is not a
    physical effect of that name; it is reported as a stretch the tool
    cannot explain.
    """
    if not sel:
        return sel
    f = S.fit(prob, sel)
    keep = []
    for i, t in enumerate(sel):
        params, _ = E.to_params(t, f.betas[i], f.covs[i])
        spec = E.SPECS[t.effect]
        bad = [k for k, lim in zip(spec.params, spec.plausible) if abs(params[k]) > 2 * lim]
        if not bad:
            keep.append(t)
            continue
        pt = prob.pt
        where = 'the whole recording' if t.window is None else \
            f'{pt.t[t.window[0]]:.1f}-{pt.t[min(t.window[1], prob.n) - 1]:.1f} s'
        desc = ', '.join(f'{k} = {params[k]:.3g}' for k in bad)
        not_judged.append({'channel': t.channel, 'reason': f'in {where} the real channel does '
                           f'not follow the simulation (the best {t.effect} fit, {desc}, is far '
                           'beyond a physical value; is the simulated signal noise there?)'})
    if len(keep) < len(sel):
        keep = S.refine_nonlinear(prob, keep)
    return keep


def _predict(prob: S.Problem, terms: list, betas: list, f: str) -> np.ndarray:
    out = np.zeros(prob.n)
    for t, b in zip(terms, betas):
        if f not in t.cols:
            continue
        X = t.cols[f]
        c = S.mdot(X, b)
        off = t.meta.get('offset')
        if off is not None and f in off:
            c = c + off[f]
        if t.window is not None:
            m = np.zeros(prob.n, bool)
            m[t.window[0]:t.window[1]] = True
            c = np.where(m, c, 0.0)
        out += c
    return out


def _rmse(x: np.ndarray, m: np.ndarray) -> Optional[float]:
    return float(np.sqrt(np.mean(x[m] ** 2))) if m.any() else None


def _heldout(prob: S.Problem, sel: list, chunks: int) -> dict:
    """Re-fit the selected terms on the fitting chunks; RMSE before/after per selected term."""
    n = prob.n
    chunk = max(1, n // chunks)
    held = ((np.arange(n) // chunk) % 3) == 2
    fit_mask = {f: prob.mask[f] & ~held for f in prob.fields}
    pf = S.Problem(prob.pt, prob.fields, prob.r, fit_mask, prob.sigma, prob.phi, n)
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


def _fmt(v: float, unit: str) -> str:
    return f'{v:.4g} {unit}'.strip()


def explain(term: E.Term, params: dict, window: Optional[list], fitd: dict) -> str:
    """Return one or two plain sentences on a finding."""
    e = term.effect
    spec = E.SPECS[e]
    where = f' between {window[0]:.1f} s and {window[1]:.1f} s' if window else ''
    if e == 'gyro_bias':
        s = f'The real gyro reads {_fmt(params["bias"], "rad/s")} more than the simulation{where}.'
    elif e == 'gyro_bias_drift':
        s = (f'The real gyro has an offset of {_fmt(params["bias"], "rad/s")} at the start that '
             f'changes by {_fmt(params["drift"], "rad/s^2")} (a warm-up drift){where}.')
    elif e in ('gyro_scale', 'accel_scale', 'wheel_radius_scale', 'track_width_scale'):
        k = params['scale']
        what = {'gyro_scale': 'the real gyro rate', 'accel_scale': 'the real acceleration',
                'wheel_radius_scale': 'the real odometry speed (wheel radius)',
                'track_width_scale': 'the effective track width (odometry yaw rate / (1+k))'}[e]
        s = f'{what[0].upper() + what[1:]} is {abs(k) * 100:.2f}% ' \
            f'{"larger" if k > 0 else "smaller"} than simulated{where}.'
    elif e == 'time_offset':
        tau = params['tau']
        s = f'The real recording {"lags" if tau > 0 else "leads"} the simulation by ' \
            f'{abs(tau) * 1000:.1f} ms (a latency).'
    elif e == 'accel_bias':
        s = f'The real accelerometer reads {_fmt(params["bias"], "m/s^2")} more than the ' \
            f'simulation{where}.'
    elif e == 'centripetal_acceleration':
        s = f'The real lateral acceleration contains v*omega with gain {params["gain"]:.3f}: ' \
            'the simulation leaves out the centripetal acceleration in turns.'
    elif e == 'imu_mounting_tilt':
        s = f'The IMU is mounted tilted by roll {np.degrees(params["roll"]):.2f} deg and pitch ' \
            f'{np.degrees(params["pitch"]):.2f} deg, so gravity leaks into a_x and a_y.'
    elif e == 'wheel_slip':
        s = f'The real odometry speed changes with the commanded acceleration (coefficient ' \
            f'{_fmt(params["coefficient"], "s^2/m")}): the wheels slip{where}.'
    elif e == 'gyro_cross_axis':
        src = term.meta.get('source', 'another axis')
        s = f'Rotation about {src} leaks into this axis with ' \
            f'coefficient {params["coefficient"]:.4f} (an axis misalignment of ' \
            f'{np.degrees(np.arcsin(np.clip(params["coefficient"], -1, 1))):.2f} deg).'
    else:
        s = f'{spec.what}.'
    hb, ha = fitd.get('heldout_rmse_before'), fitd.get('heldout_rmse_after')
    if hb and ha is not None and hb > 0:
        s += f' Modelling it cuts the held-out residual from {hb:.3g} to {ha:.3g}.'
    for name, lim in zip(spec.params, spec.plausible):
        if abs(params.get(name, 0.0)) > lim:
            s += f' The {name} is beyond the plausible {lim:g}: check units and the pairing.'
    return s


def _analyse_topic(pt: PairedTopic, sim: Recording, real: Recording, t0: float,
                   prm: MismatchParams, notes: list, not_judged: list,
                   channel_info: dict) -> tuple[list, Optional[S.Problem], list]:
    prob = _problem(pt, prm.noise_smooth, not_judged)
    if prob is None:
        return [], None, []
    aux = _aux(sim, real, pt, t0, notes)
    cands, cannot = E.candidates(pt, prob.sigma, aux)
    for c in cannot:
        if c not in notes:
            notes.append(c)
    min_len = max(20, int(prm.min_window * prob.n),
                  int(prm.min_window_s / max(pt.dt, 1e-9)))
    if prm.mode == 'seed':  # global effects only: no window can be as long as this
        min_len = prob.n + 1
    sel, _ = S.forward_select(prob, cands, prm.margin, min_len, prm.max_terms)
    if sel:
        # second pass with the noise level measured on the model's residual
        cur = S.fit(prob, sel, contributions=True)
        sig2, phi2 = {}, {}
        changed = False
        for f in prob.fields:
            s, ph = noise_level(prob.r[f] - cur.contrib.get(f, 0.0), prob.mask[f], pt.dt,
                                prm.noise_smooth)
            s = max(s, _floor(prob.r[f], prob.mask[f], pt.sim[f], pt.real[f]))
            sig2[f], phi2[f] = s, ph
            changed |= s < 0.9 * prob.sigma[f]
        if changed:
            prob = S.Problem(pt, prob.fields, prob.r, prob.mask, sig2, phi2, prob.n)
            sel, _ = S.forward_select(prob, cands, prm.margin, min_len, prm.max_terms)
    if sel and prm.mode != 'seed':
        sel = S.refine_windows(prob, sel, min_len)
        sel = S.unexcited_windows(prob, sel)
    sel = S.refine_nonlinear(prob, sel)
    sel = S.backward_eliminate(prob, sel, prm.margin)
    sel = _implausible(prob, sel, not_judged)
    held = _heldout(prob, sel, prm.heldout_chunks) if sel else {}
    # cross-validation guard: an effect that makes the held-out part worse is dropped
    bad = {i for i, h in held.items() if h['heldout_rmse_before'] is not None and
           h['heldout_rmse_after'] is not None and
           h['heldout_rmse_after'] > h['heldout_rmse_before']}
    if bad:
        for i in sorted(bad):
            notes.append(f'{sel[i].channel}: a candidate {sel[i].effect} did not improve the '
                         'held-out part and is not reported')
        sel = [t for i, t in enumerate(sel) if i not in bad]
        held = _heldout(prob, sel, prm.heldout_chunks) if sel else {}
    final = S.fit(prob, sel, contributions=True)
    for f in prob.fields:
        ch = f'{pt.name}.{f}'
        r = prob.r[f]
        m = prob.mask[f]
        channel_info[ch] = {
            'rmse': _rmse(r, m), 'noise': prob.sigma[f], 'noise_inflation': prob.phi[f],
            'rmse_after': _rmse(r - final.contrib.get(f, 0.0), m),
            'beyond_noise': active_windows(pt.t, r, m, prob.sigma[f], prob.phi[f])}
    for f in prob.fields:
        ci = channel_info[f'{pt.name}.{f}']
        left = ci['rmse_after'] or 0.0
        if left > 3.0 * prob.sigma[f] * np.sqrt(prob.phi[f]) and left > 0:
            not_judged.append({'channel': f'{pt.name}.{f}', 'reason': (
                f'after the effects found the residual is still {left / prob.sigma[f]:.1f} '
                'times the noise: the runs may not follow the same motion, or an effect '
                'outside the library acts; findings on this channel are uncertain')})
    alts = S.alternatives(prob, sel, cands, min_len, prm.alt_margin) \
        if sel and prm.mode != 'seed' else {}
    base = S.score(prob, final)
    findings = []
    for i, t in enumerate(sel):
        params, sds = E.to_params(t, final.betas[i], final.covs[i])
        window = None
        if t.window is not None:
            i0, i1 = t.window
            window = [round(float(pt.t[i0]), 4), round(float(pt.t[min(i1, prob.n) - 1]), 4)]
        fitd = held.get(i, {})
        without = S.score(prob, S.fit(prob, sel[:i] + sel[i + 1:]))
        fd = {'channel': t.channel, 'effect': t.effect,
              'parameters': {k: float(v) for k, v in params.items()},
              'window': window, 'fit': fitd,
              'explanation': explain(t, params, window, fitd),
              'std': sds,
              'ci95': {k: [params[k] - 1.96 * sds[k], params[k] + 1.96 * sds[k]] for k in params},
              'units': dict(zip(E.SPECS[t.effect].params, E.SPECS[t.effect].units)),
              'evidence': {'delta_bic': float(without - base)}}
        if 'source' in t.meta:
            fd['source_channel'] = t.meta['source']
        if i in alts:
            fd['alternatives'] = []
            for c, cf, d in alts[i]:
                j = len(cf.terms) - 1
                cp, _ = E.to_params(c, cf.betas[j], cf.covs[j])
                fd['alternatives'].append({
                    'effect': c.effect, 'channel': c.channel,
                    'parameters': {k: float(v) for k, v in cp.items()},
                    'delta_bic': d,
                    'separating_motion': E.separating_motion(t.effect, c.effect)})
            names = ', '.join(sorted({a['effect'] for a in fd['alternatives']}))
            fd['explanation'] += f' This recording cannot clearly tell it from {names}; ' \
                f'{fd["alternatives"][0]["separating_motion"]}.'
        findings.append(fd)
    return findings, prob, sel


def analyse_recordings(sim: Recording, real: Recording,
                       params: Optional[MismatchParams] = None) -> tuple[dict, list]:
    """
    Compare two recordings; return (findings dict, per-topic details for the report).

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
        timing[pt.name] = {'xcorr_lag': pt.tau_xcorr, 'xcorr_gain': pt.xcorr_gain}
        fs, prob, sel = _analyse_topic(pt, sim, real, t0, prm, notes, not_judged, channel_info)
        findings.extend(fs)
        if prob is not None:
            details.append((pt, prob, sel, fs))
    if not channel_info:
        raise ChannelError('no channel can be compared (' + '; '.join(
            f'{d["channel"]}: {d["reason"]}' for d in not_judged) + ')')
    findings.sort(key=lambda f: -f['evidence']['delta_bic'])
    out = {'verdict': 'mismatch' if findings else 'consistent', 'findings': findings,
           'time_alignment': timing, 'channels': channel_info, 'not_judged': not_judged,
           'notes': notes, 'bag_start': t0}
    return out, details
