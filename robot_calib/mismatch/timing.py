# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Stage 1 of the analysis: the time relation of each sensor, and the simulation aligned to it.

One delay per clock group (:mod:`.latency`), kept when its block error makes
it significant; a drive (odometry, joint states) also tries a first-order
lag and names whichever fits clearly better, and an odometry speed is compared
without the wheel slip fitted jointly with the delay (the two look alike). The
simulation is then delayed (or lagged) by it, so the amplitude effects are
judged on aligned signals.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Optional

import numpy as np

from robot_calib.mismatch import effects as E
from robot_calib.mismatch import latency as L
from robot_calib.mismatch.channels import (IMU_TYPE, loo_derivative, ODOM_TYPE, PairedTopic,
                                           regressor_signal)
from robot_calib.mismatch.explain import explain
from robot_calib.mismatch.findings import confidence, evidence, heldout_support, motion_ratio
from robot_calib.mismatch.problem import channel_noise, held_mask, Problem, rmse


MOVING_SPREAD = 1.5
"""A channel takes part in the delay estimate when its simulated motion (standard deviation)
exceeds this many times its residual noise level. A channel of noise alone stays near 0.2-0.7
of it (its regressor averages the noise away, the residual holds both sides' noise); the delay
estimate then integrates the motion over the whole recording and is tested for significance."""


SLIP_FIELD = 'twist.twist.linear.x'


def moving_fields(pt: PairedTopic, prob: Problem, smooth: float) -> list:
    """
    Return the fields whose simulated signal moves well beyond the channel noise.

    The noise level of the problem is measured on the residual at lag 0, where
    a delay of the real recording is left in: on fast motion it passes for
    noise and would hide the very channels that show the delay. A field that
    fails at lag 0 is judged again with the residual at the lag of the
    cross-correlation peak (``pt.tau_xcorr``), noise measured as at lag 0
    (``smooth``: the moving average removed first, s).
    """
    out = []
    lag = float(getattr(pt, 'tau_xcorr', 0.0) or 0.0)
    for f in prob.fields:
        x = pt.sim_reg[f][prob.mask[f]]
        x = x[np.isfinite(x)]
        if x.size <= 20:
            continue
        spread = float(np.std(x))
        if spread <= MOVING_SPREAD * prob.sigma[f] and abs(lag) >= 0.5 * pt.dt:
            a = delayed(pt.sim[f], lag, pt.dt)
            m = prob.mask[f] & np.isfinite(a)
            if m.sum() > 20 and spread > MOVING_SPREAD * channel_noise(
                    a, pt.real[f], m, pt.dt, smooth)[1]:
                out.append(f)
            continue
        if spread > MOVING_SPREAD * prob.sigma[f]:
            out.append(f)
    return out


def group_data(pt: PairedTopic, prob: Problem, fields: list, keep: np.ndarray,
               reals: Optional[dict] = None) -> dict:
    """Return the delay estimate's input per clock group (``reals``: real fields replaced)."""
    reals_of = {**pt.real, **(reals or {})}
    data = {}
    for i, group in enumerate(L.field_groups(pt.msgtype, fields)):
        sims, real_f, oks = [], [], []
        for f in group:
            # the raw simulated channel: independent noise does not bias the cross-spectral
            # phase, while a smoothed copy would bend it
            ok = prob.mask[f] & keep
            sims.append(np.where(ok, pt.sim[f], 0.0))
            real_f.append(np.where(ok, reals_of[f], 0.0))
            oks.append(ok)
        data[f'g{i}'] = (group, sims, real_f, oks)
    return data


def joint_slip(pt: PairedTopic, prob: Problem, acmd: Optional[np.ndarray],
               tau: float = 0.0, with_delay: bool = True) -> Optional[tuple[float, np.ndarray]]:
    """
    Return (coefficient s^2/m, regressor ``v a`` delayed by ``tau``) of a slip fitted with a delay.

    On odometry speed a delay and slip under acceleration look alike (``tau a``
    against ``c v a``: both grow with the acceleration), so a slip fitted alone
    takes the delay's share and a delay estimated alone takes the slip's. The
    speed residual against the simulation delayed by ``tau`` (s) is fitted by
    least squares on an offset, a scale, the slip (delayed alike: the clock
    delays the slipping speed too) and the linearisation ``ds/dt`` of what
    delay is left, together, which separates them where the speed differs
    between accelerations (``with_delay=False``: the slip alone). None when the
    topic is not odometry or has no commanded acceleration (``acmd``, m/s^2 on
    the grid).
    """
    f = SLIP_FIELD
    if pt.msgtype != ODOM_TYPE or acmd is None or f not in prob.fields:
        return None
    noisy = pt.sim_noisy.get(f)
    s, slip = pt.sim[f], np.nan_to_num(pt.sim_reg.get(f, pt.sim[f])) * acmd
    if tau:
        s, slip = delayed(s, tau, pt.dt), delayed(slip, tau, pt.dt)
    level = regressor_signal(s) if noisy else s
    y = pt.real[f] - s
    m = prob.mask[f] & np.isfinite(y) & np.isfinite(slip) & np.isfinite(level)
    if m.sum() < 10 or not np.any(slip[m]):
        return None
    cols = [np.ones(m.sum()), level[m], slip[m]]
    if with_delay:
        cols.append((loo_derivative(s, pt.dt) if noisy else np.gradient(filled(s), pt.dt))[m])
    coef = np.linalg.lstsq(np.column_stack(cols), y[m], rcond=None)[0]
    return float(coef[2]), np.nan_to_num(slip)


def deslipped(pt: PairedTopic, slip: Optional[tuple]) -> dict:
    """
    Return {speed field: the real odometry speed less ``slip`` (:func:`joint_slip`)}, or {}.

    The delay is estimated on it; the amplitude stage finds the slip again on
    the aligned signals.
    """
    return {} if slip is None else {SLIP_FIELD: pt.real[SLIP_FIELD] - slip[0] * slip[1]}


def filled(x: np.ndarray) -> np.ndarray:
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
    y = L.shift_frac(filled(x), k)
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


def time_stage(pt: PairedTopic, prob: Problem, prm: Any, edges: np.ndarray,
               acmd: Optional[np.ndarray] = None) -> list:
    """
    Return the significant time effects of a topic: [(kind, TimeEffect, lag info)].

    ``acmd``: the commanded acceleration on the topic's grid (m/s^2); with it an
    odometry speed is compared without the wheel slip fitted jointly with a
    delay (:func:`joint_slip`).
    """
    fields = moving_fields(pt, prob, prm.noise_smooth)
    if not fields:
        return []
    keep = np.ones(prob.n, bool)
    reals = deslipped(pt, joint_slip(pt, prob, acmd))
    effects = L.delays_of(group_data(pt, prob, fields, keep, reals), pt.dt, edges, prm.alpha,
                          prm.max_lag)
    for _ in range(4 if reals else 0):
        # the slip again, delayed by the delay found, and the delay with it, until they settle
        # (alternating least squares)
        if not effects:
            break
        last = effects[0].delay
        reals = deslipped(pt, joint_slip(pt, prob, acmd, last.tau))
        effects = L.delays_of(group_data(pt, prob, fields, keep, reals), pt.dt, edges,
                              prm.alpha, prm.max_lag)
        if effects and abs(effects[0].delay.tau - last.tau) < 0.1 * last.std:
            break
    out = []
    for te in effects:
        kind, info = 'time_offset', {}
        if te.drift:
            kind = 'timing_drift'
        elif pt.msgtype != IMU_TYPE and te.delay.tau > 0:
            kind, info = _lag_or_delay(pt, prob, te, prm, reals)
        out.append((kind, te, info))
    return out


def _whitened_chi2(prob: Problem, fields: list, pred: dict,
                   reals: Optional[dict] = None) -> float:
    """Return the chi2 of ``real - pred`` after a per-field offset and scale are fitted."""
    total = 0.0
    for f in fields:
        m = prob.mask[f] & np.isfinite(pred[f])
        y = (reals or {}).get(f, prob.pt.real[f])[m] - pred[f][m]
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


def _lag_or_delay(pt: PairedTopic, prob: Problem, te: L.TimeEffect, prm: Any,
                  reals: dict) -> tuple[str, dict]:
    """
    Compare a pure delay with a first-order lag of the drive; return (effect name, info).

    Both are fitted by least squares in time (each with its own time
    constant, after a per-field offset and scale), so neither is favoured by
    the estimator; the lag must fit better by ``alt_margin`` to be named.
    ``reals``: real fields compared in place of the recorded ones (the speed
    less its slip, :func:`deslipped`).
    """
    sims = {f: filled(pt.sim[f]) for f in te.fields}
    tau0 = te.delay.tau

    def chi_delay(tau: float) -> float:
        return _whitened_chi2(prob, te.fields,
                              {f: delayed(pt.sim[f], tau, pt.dt) for f in te.fields}, reals)

    def chi_lag(log_tau: float) -> float:
        return _whitened_chi2(prob, te.fields, {f: L.lag_response(sims[f], pt.dt,
                                                                  np.exp(log_tau))
                                                for f in te.fields}, reals)
    tau_d = _golden(chi_delay, tau0 - 0.5 * abs(tau0) - pt.dt, tau0 + 0.5 * abs(tau0) + pt.dt)
    log_l = _golden(chi_lag, np.log(max(pt.dt, 0.2 * tau0)), np.log(max(5.0 * tau0, 3 * pt.dt)))
    info = {'delay_chi2': chi_delay(tau_d), 'lag_chi2': chi_lag(log_l),
            'lag_tau': float(np.exp(log_l)), 'delay_tau_ls': float(tau_d)}
    better = info['lag_chi2'] < info['delay_chi2'] - prm.alt_margin
    return ('drive_lag' if better else 'time_offset'), info


def slip_alternative(pt: PairedTopic, prob: Problem, te: L.TimeEffect,
                     acmd: Optional[np.ndarray], joint: Optional[tuple]) -> Optional[tuple]:
    """
    Return (delta chi2, coefficient s^2/m) of wheel slip instead of an odometry delay, or None.

    On odometry speed a delay and slip under acceleration look alike (``tau a``
    against ``c v a``): the delay stage, run first, could take a slip for a
    delay and hide it. The slip is fitted alone to the unaligned residual and
    both models are scored alike (:func:`_whitened_chi2` over the delay's
    fields: slip leaves the turn rate as it is, a clock delays it too), the
    delay together with ``joint``, the slip fitted jointly with it
    (:func:`joint_slip` at the delay), so a delay beside a slip is weighed by
    what it adds; a positive delta means the delay fits better. ``acmd`` is the
    commanded acceleration on the topic's grid (m/s^2).
    """
    if SLIP_FIELD not in te.fields:
        return None
    alone = joint_slip(pt, prob, acmd, with_delay=False)
    if alone is None:
        return None
    with_slip = {f: pt.sim[f] for f in te.fields}
    with_slip[SLIP_FIELD] = pt.sim[SLIP_FIELD] + alone[0] * alone[1]
    delay = {f: delayed(pt.sim[f], te.delay.tau, pt.dt) for f in te.fields}
    if joint is not None:
        delay[SLIP_FIELD] = delay[SLIP_FIELD] + joint[0] * joint[1]
    return (_whitened_chi2(prob, te.fields, with_slip) -
            _whitened_chi2(prob, te.fields, delay), alone[0])


def field_taus(te: L.TimeEffect, fields: Optional[list] = None) -> dict:
    """
    Return the delay applied to each field: the pooled one, or its group's when they differ.

    Given the topic's ``fields``, every field of a clock group gets the group's
    delay, not only those that moved enough to take part in its estimate: a
    sensor's clock delays all its channels (a still gyro axis left unaligned
    would show the delay as a gain on its fast motion). A clock group with no
    estimate of its own gets the pooled delay.
    """
    out = {}
    for group, d in te.groups.items():
        out.update({f: (te.delay.tau if te.consistent else d.tau) for f in group})
    for clock in L.field_groups('', list(fields or [])):
        own = [d for g, d in te.groups.items() if set(g) & set(clock)]
        tau = own[0].tau if own and not te.consistent else te.delay.tau
        out.update({f: tau for f in clock if f not in out})
    return out


def _time_fit(pt: PairedTopic, prob: Problem, te: L.TimeEffect, prm: Any,
              edges: np.ndarray, reals: dict) -> tuple[str, dict, float, tuple]:
    """
    Return (best channel, fit dict, motion, support): the delay re-estimated without held-out time.

    The channel reported is the one whose held-out mean square falls most, in
    units of its noise variance; ``motion`` how much more the delay changes it
    on fitted than on held-out time (``findings.motion_ratio``), ``support`` the
    held-out gain it predicts and that gain's error (``findings.heldout_support``).
    """
    held = held_mask(prob.n, prm.heldout_chunks)
    refit = L.delays_of(group_data(pt, prob, te.fields, ~held, reals), pt.dt, edges, 1.0,
                        prm.max_lag)
    moved = aligned(pt, field_taus(refit[0] if refit else te))
    best, fitd, channel, motion, support = None, {}, f'{pt.name}.{te.fields[0]}', 1.0, None
    for f in te.fields:
        r0 = prob.r[f]
        r1 = np.where(prob.mask[f], pt.real[f] - moved.sim[f], np.nan)
        m = prob.mask[f] & np.isfinite(r1)
        fd = {'rmse_before': rmse(r0, m & ~held), 'rmse_after': rmse(r1, m & ~held),
              'heldout_rmse_before': rmse(r0, m & held),
              'heldout_rmse_after': rmse(r1, m & held)}
        # the channel where the delay shows most against its own noise (channels differ in
        # units: an accelerometer's m/s^2 are no more than a gyro's rad/s)
        gain = ((fd['heldout_rmse_before'] or 0.0) ** 2 -
                (fd['heldout_rmse_after'] or 0.0) ** 2) / max(prob.sigma[f], 1e-300) ** 2
        if best is None or gain > best:
            best, fitd, channel = gain, fd, f'{pt.name}.{f}'
            change = np.nan_to_num(r0 - r1)
            motion = motion_ratio(change, m & ~held, m & held)
            support = heldout_support(change, m & held, r1, prob.phi[f])
    return channel, fitd, motion, support


def time_findings(pt: PairedTopic, prob: Problem, found: list, prm: Any,
                  edges: np.ndarray, acmd: Optional[np.ndarray] = None) -> list:
    """
    Return the findings of the time stage, with held-out fit (delay re-estimated without).

    ``acmd``: the commanded acceleration on the topic's grid (m/s^2), with which
    an odometry delay is weighed against wheel slip (:func:`slip_alternative`).
    """
    out = []
    for kind, te, info in found:
        d = te.delay
        joint = joint_slip(pt, prob, acmd, d.tau)
        channel, fitd, motion, support = _time_fit(pt, prob, te, prm, edges,
                                                   deslipped(pt, joint))
        tau = info['lag_tau'] if kind == 'drive_lag' else d.tau
        params, sds = {'tau': float(tau)}, {'tau': float(d.std)}
        if kind == 'timing_drift':
            params, sds = drift_parameters(te)
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
        slip = slip_alternative(pt, prob, te, acmd, joint) if kind == 'time_offset' else None
        if slip is not None and slip[0] < prm.alt_margin:
            alt.append({'effect': 'wheel_slip', 'channel': f'{pt.name}.{SLIP_FIELD}',
                        'delta_bic': float(max(slip[0], 0.0)),
                        'parameters': {'coefficient': slip[1]},
                        'separating_motion': E.separating_motion(kind, 'wheel_slip')})
        text = explain(kind, params, None, fitd, {'parts': te.drift, 'tau': d.tau,
                                                  'max_lag': prm.max_lag})
        if kind == 'time_offset':
            text += rate_note(pt, d)
        per_group = {g[0].rsplit('.', 1)[0]: gd.tau for g, gd in te.groups.items()}
        if not te.consistent:
            text += ' Its channels do not share one delay: ' + ', '.join(
                f'{k} {v * 1000:.1f} ms' for k, v in per_group.items()) + \
                ' (filters of different delay inside the sensor, or in the reference).'
        fd = {'channel': channel, 'effect': kind, 'parameters': params, 'window': None,
              'fit': fitd, 'explanation': text,
              'std': sds, 'ci95': {k: [v - 1.96 * sds[k], v + 1.96 * sds[k]]
                                   for k, v in params.items()},
              'units': {k: 's' for k in params},
              'channels': [f'{pt.name}.{f}' for f in te.fields],
              'per_group': per_group,
              'evidence': {'z': float(d.z), 'z_threshold': z_thr, 'blocks': d.blocks,
                           'band_hz': list(d.band_hz), 'coherence': d.coherence},
              'evidence_strength': evidence(1.0 - (z_thr / max(d.z, 1e-12)) ** 2, fitd,
                                            motion, support)}
        fd['confidence'] = confidence(fd['evidence_strength'], [a['delta_bic'] for a in alt])
        if alt:
            fd['alternatives'] = alt
        out.append(fd)
    return out


def drift_parameters(te: L.TimeEffect) -> tuple[dict, dict]:
    """Return the parameters of a ``timing_drift`` (delays of the first and last parts, s)."""
    known = [d for _, _, d in te.drift if d is not None] or [te.delay]
    first, last = known[0], known[-1]
    return ({'tau_start': float(first.tau), 'tau_end': float(last.tau)},
            {'tau_start': float(first.std), 'tau_end': float(last.std)})


def rate_note(pt: PairedTopic, d: L.Delay) -> str:
    """
    Return a sentence when a delay is what a different sample rate alone makes, else ''.

    A speed or rate differenced over one sample period (odometry, joint
    velocities) stands for the middle of that period, so it trails its stamp
    by half a period: sampled at different rates, the two recordings differ by
    half the difference of their periods with no latency at all.
    """
    if pt.msgtype == IMU_TYPE or not (pt.dt_sim > 0 and pt.dt_real > 0):
        return ''
    half = 0.5 * (pt.dt_real - pt.dt_sim)
    if abs(pt.dt_real - pt.dt_sim) <= 0.05 * min(pt.dt_real, pt.dt_sim) or \
            abs(d.tau - half) > max(3.0 * d.std, 0.25 * abs(half)):
        return ''
    return f' It equals half the difference of the two sample periods ({half * 1000:.1f} ms; ' \
        f'sim {1 / pt.dt_sim:.0f} Hz, real {1 / pt.dt_real:.0f} Hz): a speed differenced over ' \
        'one period trails its stamp by half of it, so the rate alone may make this delay; ' \
        'simulate at the real rate to tell.'


def lagged(pt: PairedTopic, f: str, tau: float) -> np.ndarray:
    x = pt.sim[f]
    return np.where(np.isfinite(x), L.lag_response(filled(x), pt.dt, tau), np.nan)
