# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The mismatch analysis: align, locate, name, model and show, or abstain.

:func:`analyse_recordings` takes two :class:`~robot_calib.mismatch.channels.Recording`
objects (the simulated and the real run) and returns the findings dict of
the contract (docs/contract.md, "Mismatch findings") plus additive keys:
``time_alignment`` (per topic, the cross-correlation lag and the delay
judged per sensor), ``channels`` (per channel the residual RMS, the noise
level and the windows where the residual is beyond noise), ``not_judged``
(what cannot be judged and why) and ``notes``.

Per sensor (topic), :func:`_analyse_topic` runs named steps: align time,
build candidates, select, check on held-out time, write findings, describe
the channels, name what is left; across topics the findings are reconciled,
a latency common to the run folded into the clock offset, and the minor and
weak ones sorted out (:func:`_sort_minor_and_weak`). In three stages:

1. time: one delay per clock group (an IMU's gyro and accelerometer may
   differ), by least squares with exact shifts, kept when its block error
   makes it significant; a drive (odometry, joint states) also tries a
   first-order lag (:mod:`.timing`, :mod:`.latency`). A delay must hold on
   each third of the run too, else it is a ``timing_drift`` (time lines that
   drift apart), not a latency. The simulation is then delayed by it.
2. amplitude: forward selection of the library's effects on the aligned
   residual (:mod:`.select`), kept only when they pass a block-robust test
   (:mod:`.robust`) and improve held-out time; a window only when the effect's
   change at its edges passes that test too, else the effect is global.
3. what is left: structure beyond noise that no effect explains becomes one
   ``unexplained`` finding (where, how large, what it follows), never a
   forced wrong name (:mod:`.residual`).

Across sensors, one change of how the robot moved is one finding: the same
scale on a speed and a yaw rate, or on a gyro and another topic's yaw rate,
is named once (:mod:`.reconcile`).

Held-out evaluation: the common time line is cut into ``heldout_chunks``
equal chunks; every third chunk is held out. The selected effects are
re-fitted on the other chunks only and the RMSE of ``real - sim`` before and
after applying them is reported on both parts, inside the finding's window.
An effect is dropped when it makes the held-out residual worse, and its
evidence counts how much of its in-sample gain held-out time confirms, both
weighted as the fit weighs each sample (by its local noise level), the
confirmation scaled by how much the effect changes each part (it shows in
proportion to the motion exciting it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from robot_calib.mismatch import drive as D
from robot_calib.mismatch import effects as E
from robot_calib.mismatch import residual as U
from robot_calib.mismatch import robust as R
from robot_calib.mismatch import select as S
from robot_calib.mismatch import timing
from robot_calib.mismatch.align import pair_topics
from robot_calib.mismatch.channels import (ChannelError, JOINT_STATE_TYPE, ODOM_TYPE,
                                           PairedTopic, Recording)
from robot_calib.mismatch.drive_stage import drive_stage
from robot_calib.mismatch.findings import (heldout_support, motion_ratio, term_finding,
                                           unsupported)
from robot_calib.mismatch.locate import active_windows, local_weights
from robot_calib.mismatch.locate import noise_level
from robot_calib.mismatch.params import MismatchParams
from robot_calib.mismatch.problem import held_mask, make_problem, noise_floor, Problem, rmse
from robot_calib.mismatch.reconcile import reconcile
from robot_calib.mismatch.regressors import motion_regressors

__all__ = ['MismatchParams', 'TopicDetail', 'analyse_recordings']


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
    prob0: Problem
    prob: Problem
    sel: list
    final: S.Fit
    term_findings: list
    time_findings: list
    unexplained: Optional[dict]
    held: np.ndarray


# -- stage 2: amplitude effects -------------------------------------------------------------
def _beyond_plausible(term: E.Term, beta: np.ndarray, cov: np.ndarray) -> tuple[dict, list]:
    """Return a term's parameters and the names of those beyond a working sensor's range."""
    params, _ = E.to_params(term, beta, cov)
    spec = E.SPECS[term.effect]
    return params, [k for k, lim in zip(spec.params, spec.plausible)
                    if np.isfinite(params[k]) and abs(params[k]) > lim]


def _implausible(prob: Problem, sel: list, not_judged: list, notes: list, cands: list,
                 min_len: int, alt_margin: float) -> tuple[list, list]:
    """
    Move effects fitted far beyond their plausible range out of the findings.

    A parameter beyond the plausible magnitude of a working sensor (e.g. a
    gyro scale of -1: the real channel does not follow the simulation at all)
    is not a physical effect of that name. When another effect of the library
    explains the same residual about as well (within ``alt_margin``) with
    physical values, it takes the place of the first (a note says so; e.g. on
    a steady circle the centripetal acceleration v omega and an accelerometer
    scale are the same regressor); otherwise the stretch is reported as one the
    tool cannot explain. Returns (kept terms, [(term, parameters)] dropped).
    """
    if not sel:
        return sel, []
    f = S.fit(prob, sel)
    keep, dropped = [], []
    for i, t in enumerate(sel):
        params, bad = _beyond_plausible(t, f.betas[i], f.covs[i])
        if not bad:
            keep.append(t)
            continue
        desc = ', '.join(f'{k} = {params[k]:.3g}' for k in bad)
        alt = next((c for c, cf, _ in S.alternatives(prob, sel, cands, min_len, alt_margin,
                                                     only=i).get(i, [])
                    if not _beyond_plausible(c, cf.betas[-1], cf.covs[-1])[1]), None)
        if alt is not None:
            keep.append(alt)
            notes.append(f'{t.channel}: the best {t.effect} fit ({desc}) is far beyond a '
                         f'physical value; {alt.effect} explains the residual about as well '
                         'with a physical value and is reported instead')
            continue
        dropped.append((t, params))
        not_judged.append({'channel': t.channel, 'reason': f'in {_where(t, prob)} the real '
                           f'channel does not follow the simulation (the best {t.effect} fit, '
                           f'{desc}, is far beyond a physical value; is the simulated signal '
                           'noise there?)'})
    # a channel that does not follow the simulation over the whole recording carries no
    # other finding either (an offset fitted to unrelated motion is no gyro bias)
    lost = {f for t, _ in dropped if t.window is None and len(t.cols) == 1 for f in t.cols}
    for t in [t for t in keep if lost & set(t.cols)]:
        keep.remove(t)
        notes.append(f'{t.channel}: {t.effect} not reported: the channel does not follow the '
                     'simulation over the whole recording')
    if len(keep) < len(sel):
        keep = S.refine_nonlinear(prob, keep)
    return keep, dropped


def _plain_offsets(prob: Problem, sel: list, prm: MismatchParams) -> list:
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


def _where(t: E.Term, prob: Problem) -> str:
    """Return where a term acts: 'the whole recording' or its window in seconds."""
    if t.window is None:
        return 'the whole recording'
    return f'{prob.pt.t[t.window[0]]:.1f}-{prob.pt.t[min(t.window[1], prob.n) - 1]:.1f} s'


def _min_len(prob: Problem, prm: MismatchParams) -> int:
    """Return the shortest effect window (samples); longer than the recording in seed mode."""
    if prm.mode == 'seed':  # global effects only
        return prob.n + 1
    return max(20, int(prm.min_window * prob.n), int(prm.min_window_s / max(prob.pt.dt, 1e-9)))


def _select(prob: Problem, cands: list, prm: MismatchParams, edges: np.ndarray,
            notes: list, not_judged: list) -> tuple[list, Problem, list]:
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
        sig2[f] = max(s, noise_floor(prob.r[f], prob.mask[f], pt.sim[f], pt.real[f]))
        phi2[f] = ph
        sw2[f] = np.sqrt(local_weights(e, prob.mask[f], pt.dt, prm.noise_smooth,
                                       prm.noise_smooth))
    prob = Problem(pt, prob.fields, prob.r, prob.mask, sig2, phi2, prob.n, sw=sw2)
    sel, _ = S.forward_select(prob, cands, prm.margin, min_len, prm.max_terms)
    if sel and prm.mode != 'seed':
        sel = S.refine_windows(prob, sel, min_len)
        sel = S.unexcited_windows(prob, sel)
        sel, wide = R.window_prune(prob, sel, edges, prm.window_alpha, prm.min_block_s)
        notes.extend(f'{t.channel}: a candidate {t.effect} fits in {_where(t, prob)}, but its '
                     f'change at the edges is not consistent across the recording (robust test '
                     f'{w[2]:.3g} < {w[3]:.3g} over {w[4]:.1f} blocks); reported over the whole '
                     'recording' for t, w in wide)
    sel = S.refine_nonlinear(prob, sel)
    sel = S.backward_eliminate(prob, sel, prm.margin)
    sel, dropped = R.robust_prune(prob, sel, edges, prm.alpha,
                                  refine=lambda ts: S.refine_nonlinear(prob, ts),
                                  min_block_s=prm.min_block_s)
    notes.extend(R.dropped_note(t, test) for t, test in dropped)
    if prm.gain_band_s > 0 and prm.mode != 'seed':
        sel, unequal = R.band_prune(prob, sel, edges, prm.alpha, prm.gain_band_s)
        for t, (slow, fast, w, thr, _) in unequal:
            notes.append(f'{t.channel}: a candidate {t.effect} fits, but not as one gain: '
                         f'{fast:+.3g} on fast motion, {slow:+.3g} on slow, which alone is not '
                         f'significant (split at a {prm.gain_band_s:g} s average; robust test of '
                         f'the difference {w:.3g} > {thr:.3g}); the simulation may carry less '
                         'fast motion than the real sensor (a bandwidth or filter difference); '
                         'not reported')
        if unequal and sel:
            sel = S.refine_nonlinear(prob, sel)
    sel = _plain_offsets(prob, sel, prm)
    sel, implausible = _implausible(prob, sel, not_judged, notes, cands, min_len,
                                    prm.alt_margin)
    bad = _heldout_worse(_heldout(prob, sel, prm.heldout_chunks)[1]) if sel else set()
    for i in sorted(bad):
        notes.append(f'{sel[i].channel}: a candidate {sel[i].effect} did not improve the '
                     'held-out part and is not reported')
    sel = [t for i, t in enumerate(sel) if i not in bad]
    return sel, prob, implausible


def _predict(prob: Problem, terms: list, betas: list, f: str) -> np.ndarray:
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


def _heldout(prob: Problem, sel: list, chunks: int) -> tuple[dict, dict, dict, dict]:
    """
    Re-fit the selected terms on the fitting chunks; RMSE before/after per selected term.

    Returns four dicts per term: the plain RMSE (reported); the RMSE weighted
    as the fit weighs each sample (``Problem.sw``, lower where the residual is
    locally noisier), by which a term is judged; how much more the re-fitted
    terms change the fitted than the held-out time (``findings.motion_ratio``,
    weighted alike); and the held-out gain they predict with its standard
    error (``findings.heldout_support``). A plain RMSE lets a noisy stretch
    that no effect explains outvote the quiet time where an effect shows (a
    drifting gyro bias measured at rest, under fast turns the simulation does
    not reproduce).
    """
    n = prob.n
    held = held_mask(n, chunks)
    fit_mask = {f: prob.mask[f] & ~held for f in prob.fields}
    pf = Problem(prob.pt, prob.fields, prob.r, fit_mask, prob.sigma, prob.phi, n,
                 sw=dict(prob.sw))
    fr = S.fit(pf, sel)
    plain, weighted, motion, support = {}, {}, {}, {}
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
        r, sw = prob.r[f], prob.sw[f]
        for out, x, y in ((plain, r, r - pred), (weighted, sw * r, sw * (r - pred))):
            out[i] = {'rmse_before': rmse(x, m & ~held), 'rmse_after': rmse(y, m & ~held),
                      'heldout_rmse_before': rmse(x, m & held),
                      'heldout_rmse_after': rmse(y, m & held)}
        motion[i] = motion_ratio(sw * pred, m & ~held, m & held)
        support[i] = heldout_support(sw * pred, m & held, sw * (r - pred), prob.phi[f])
    return plain, weighted, motion, support


def _heldout_worse(weighted: dict) -> set:
    """Return the terms (indices) whose re-fit makes held-out time worse (weighted RMSE)."""
    return {i for i, h in weighted.items() if h['heldout_rmse_before'] is not None and
            h['heldout_rmse_after'] is not None and
            h['heldout_rmse_after'] > h['heldout_rmse_before']}


# -- one topic, step by step ---------------------------------------------------------------
@dataclass
class TimeStage:
    """
    What the time stage found on one topic (step 1).

    ``delays``: ``[(effect, estimate, info)]`` (time offset, drift, drive lag);
    ``findings``: their findings; ``aligned``: the topic with the simulation
    delayed by them and, where the drive chain names dynamics, the speed and turn
    rate replaced by its output (:mod:`.drive`); ``problem``: its residual
    problem (None: nothing left to judge); ``taus``: the delay per field (s);
    ``lag_tau``: the drive lag of the wheel-slip channel (s, 0 without one);
    ``drive``: the drive chain (None when it names nothing).
    """

    delays: list
    findings: list
    aligned: PairedTopic
    problem: Optional[Problem]
    taus: dict
    lag_tau: float
    drive: Optional[D.DriveResult] = None


@dataclass
class HeldOutCheck:
    """
    The selected effects checked on held-out time (step 4).

    Per selected term (by index): ``plain``/``weighted`` RMSE before and after,
    ``motion`` ratio and held-out ``support`` (see :func:`_heldout`); the
    ``final`` fit on all of the recording with contributions, the block-robust
    ``tests`` and the ``alternatives`` that explain about as well.
    """

    plain: dict
    weighted: dict
    motion: dict
    support: dict
    final: S.Fit
    tests: list
    alternatives: dict


@dataclass
class TopicResult:
    """A topic's findings, its delays (for ``time_alignment``) and the report's detail."""

    findings: list
    delays: list
    detail: Optional[TopicDetail]
    drive_text: str = ''


def _drive_tau(drive: Optional[D.DriveResult]) -> float:
    """Return the forward axis' dead time plus lag (s) of a drive model, 0 without one."""
    m = drive.models.get(D.V) if drive is not None else None
    return float(m.d + m.tau) if m is not None else 0.0


def _align_time(pt: PairedTopic, prob0: Problem, sim: Recording, real: Recording, t0: float,
                prm: MismatchParams, edges: np.ndarray) -> TimeStage:
    """Step 1: judge delays and the drive's dynamics; return the topic with the sim delayed."""
    acmd = (motion_regressors(sim, real, pt, t0, []).get('acmd')
            if pt.msgtype == ODOM_TYPE else None)
    delays = timing.time_stage(pt, prob0, prm, edges, acmd)
    findings = timing.time_findings(pt, prob0, delays, prm, edges, acmd)
    taus = {}
    for kind, te, _ in delays:
        if kind in ('time_offset', 'timing_drift'):
            # a drifting delay too: its run-wide value is the best single alignment
            taus.update(timing.field_taus(te, list(pt.sim)))
    drive = None
    if pt.msgtype in (ODOM_TYPE, JOINT_STATE_TYPE):
        # the drive chain; a late speed, turn or wheel rate is first its response
        drive, delays, findings, taus = drive_stage(
            pt, prm, taus, delays, findings,
            lambda p, tau: motion_regressors(sim, real, p, t0, [], tau).get('acmd')
            if pt.msgtype == ODOM_TYPE else None)
    aligned = timing.aligned(pt, taus)
    lags = [(te, info) for kind, te, info in delays if kind == 'drive_lag']
    if drive is not None:
        mine = {f'{pt.name}.{f}' for f in drive.sim}
        findings = drive.findings + [f for f in findings if not (
            f['effect'] == 'drive_lag' and mine & set(f.get('channels', [f['channel']])))]
        lags = [(te, info) for te, info in lags if not set(te.fields) & set(drive.sim)]
    if lags:
        sim_l = dict(aligned.sim)
        for te, info in lags:
            sim_l.update({f: timing.lagged(pt, f, info['lag_tau']) for f in te.fields})
        aligned = replace(aligned, sim=sim_l, sim_reg={}, sim_noisy={})
    if drive is not None:  # the drive's dynamics replace the simulated speed and turn rate
        aligned = replace(aligned, sim={**aligned.sim, **drive.sim}, sim_reg={}, sim_noisy={})
    prob = make_problem(aligned, prm.noise_smooth, None) if (taus or lags or drive) else prob0
    lag_tau = next((info['lag_tau'] for te, info in lags if timing.SLIP_FIELD in te.fields),
                   _drive_tau(drive))
    return TimeStage(delays, findings, aligned, prob, taus, lag_tau, drive)


def _build_candidates(stage: TimeStage, sim: Recording, real: Recording, t0: float,
                      notes: list) -> tuple[list, dict]:
    """
    Step 2: the library's candidate effects on the aligned residual, and their regressors.

    The regressors from other topics are read at the delay of the channel each
    serves: the odometry speed (wheel slip), the accelerometer's lateral axis
    (centripetal acceleration).
    """
    taus = stage.taus
    aux = motion_regressors(sim, real, stage.aligned, t0, notes,
                            taus.get(timing.SLIP_FIELD, taus.get('linear_acceleration.y', 0.0)),
                            stage.lag_tau)
    cands, cannot = E.candidates(stage.aligned, stage.problem.sigma, aux)
    notes.extend(c for c in cannot if c not in notes)
    # one owner of a scale: where the drive chain's held-out test names its gain, the chain's
    # output carries it and no second scale is fitted on that field
    owned = {f for f, m in stage.drive.models.items() if 'drive_gain' in m.parts} \
        if stage.drive is not None else set()
    if owned:
        cands = [c for c in cands if c.group.partition(':')[::2] not in
                 {('scale', f) for f in owned}]
    return cands, aux


def _check_held_out(prob: Problem, sel: list, cands: list, prm: MismatchParams,
                    edges: np.ndarray) -> HeldOutCheck:
    """Step 4: re-fit on part of the time, test across blocks, and list alternatives."""
    plain, weighted, motion, support = _heldout(prob, sel, prm.heldout_chunks) if sel else \
        ({}, {}, {}, {})
    final = S.fit(prob, sel, contributions=True)
    tests = R.wald(prob, sel, final, edges, prm.alpha, prm.min_block_s) if sel else []
    alts = S.alternatives(prob, sel, cands, _min_len(prob, prm), prm.alt_margin) \
        if sel and prm.mode != 'seed' else {}
    # an explanation that needs a parameter no working sensor has is no alternative
    alts = {i: [a for a in lst if not _beyond_plausible(a[0], a[1].betas[-1], a[1].covs[-1])[1]]
            for i, lst in alts.items()}
    return HeldOutCheck(plain, weighted, motion, support, final, tests, alts)


def _write_findings(prob: Problem, sel: list, check: HeldOutCheck) -> list:
    """Step 5: one finding per selected effect, with its held-out evidence."""
    return [term_finding(prob, check.final, sel, i, check.plain.get(i, {}), check.tests[i],
                         check.alternatives.get(i, []), check.weighted.get(i),
                         check.motion.get(i, 1.0), check.support.get(i))
            for i in range(len(sel))]


def _describe_channels(prob0: Problem, prob: Problem, final: S.Fit, channel_info: dict) -> None:
    """Step 6: per channel the residual RMS before and after, the noise and where it exceeds."""
    pt = prob0.pt
    for f in prob.fields:
        r, m = prob0.r[f], prob0.mask[f]
        left = prob.r[f] - final.contrib.get(f, 0.0)
        channel_info[f'{pt.name}.{f}'] = {
            'rmse': rmse(r, m), 'noise': prob.sigma[f], 'noise_inflation': prob.phi[f],
            'rmse_after': rmse(left, prob.mask[f]),
            'beyond_noise': active_windows(pt.t, r, m, prob0.sigma[f], prob0.phi[f])}


def _analyse_topic(pt: PairedTopic, sim: Recording, real: Recording, t0: float,
                   prm: MismatchParams, notes: list, not_judged: list,
                   channel_info: dict) -> TopicResult:
    """
    Analyse one paired topic in named steps; fill ``notes``, ``not_judged``, ``channel_info``.

    Align time (delays, drive lag), build the candidate effects, select the
    fewest that explain the residual, check them on held-out time, write their
    findings, describe each channel, and name what is left as ``unexplained``.
    """
    prob0 = make_problem(pt, prm.noise_smooth, not_judged)
    if prob0 is None:
        return TopicResult([], [], None)
    edges = R.block_edges(prob0.n, pt.dt, prm.blocks, prm.min_block_s)
    stage = _align_time(pt, prob0, sim, real, t0, prm, edges)
    text = stage.drive.text if stage.drive is not None else ''
    if stage.problem is None:
        return TopicResult(list(stage.findings), [], None, text)  # no topic detail: no delays
    cands, aux = _build_candidates(stage, sim, real, t0, notes)
    sel, prob, implausible = _select(stage.problem, cands, prm, edges, notes, not_judged)
    check = _check_held_out(prob, sel, cands, prm, edges)
    term_findings = _write_findings(prob, sel, check)
    _describe_channels(prob0, prob, check.final, channel_info)
    extra = U.unexplained(prob, check.final, aux, edges, implausible)
    findings = list(stage.findings) + term_findings + ([extra] if extra is not None else [])
    detail = TopicDetail(pt, prob0, prob, sel, check.final, term_findings,
                         list(stage.findings), extra, held_mask(prob.n, prm.heldout_chunks))
    return TopicResult(findings, stage.delays, detail, text)


# -- across topics ------------------------------------------------------------------------
def _fold_common_latency(findings: list, clock, notes: list) -> list:
    """
    Return ``findings`` without time offsets when the clocks were aligned on the motion.

    A latency common to the run is then part of the clock offset: the
    strongest one is folded into ``clock.offset`` and a note says so.
    """
    if clock.method != 'motion':
        return findings
    delays = [f for f in findings if f['effect'] == 'time_offset']
    findings = [f for f in findings if f['effect'] != 'time_offset']
    if delays:
        best = max(delays, key=lambda f: f['evidence']['z'])
        clock.offset -= best['parameters']['tau']
        notes.append('the clocks differ, so a latency common to a whole sensor cannot be '
                     'told from the clock offset; the offset includes '
                     f'{best["parameters"]["tau"] * 1000:.1f} ms measured on '
                     f'{best["channel"]}; per-sensor delays are in time_alignment')
    return findings


def _sort_minor_and_weak(findings: list, prm: MismatchParams, duration: float,
                         notes: list) -> tuple[list, list, list]:
    """
    Split findings into (reported, minor, weak).

    Weak: below ``min_confidence``, or not improving what it claims to.
    Minor: smaller than the effect's floor worth naming for a ground robot.
    """
    weak = [f for f in findings if f.get('evidence_strength', f['confidence']) <
            prm.min_confidence]
    for f in [f for f in findings if f not in weak]:
        why = unsupported(f, prm.min_improvement)  # a finding must improve what it claims to
        if why:
            weak.append(f)
            f['explanation'] += f' Not reported: {why}.'
            notes.append(f'{f["channel"]}: a candidate {f["effect"]} is not reported: {why}')
    minor = [f for f in findings if f not in weak and f['effect'] != 'unexplained' and
             E.effect_size(f['effect'], f['parameters'], duration) <
             prm.floor_scale * E.SPECS[f['effect']].floor]
    for f in minor:
        f['explanation'] += ' It is smaller than the ' \
            f'{E.SPECS[f["effect"]].floor:g} worth naming for a ground robot, so it is listed ' \
            'as minor.'
    return [f for f in findings if f not in weak and f not in minor], minor, weak


def analyse_recordings(sim: Recording, real: Recording,
                       params: Optional[MismatchParams] = None,
                       remaps: Optional[list] = None) -> tuple[dict, list]:
    """
    Compare two recordings; return (findings dict, per-topic :class:`TopicDetail` list).

    :param remaps: ``[(sim topic, real topic)]`` pairs the user gave (``--remap``)
    :raises ChannelError: when nothing can be compared, or the clocks cannot be aligned
    """
    prm = params or MismatchParams()
    paired, not_judged, t0, notes, clock = pair_topics(sim, real, prm.max_lag, remaps,
                                                       prm.min_correspondence)
    if not paired:
        reasons = '; '.join(f'{d["channel"]}: {d["reason"]}' for d in not_judged) or \
            'no common topic'
        raise ChannelError(f'no channel can be compared ({reasons})')
    findings: list = []
    details: list = []
    channel_info: dict = {}
    alignment: dict = {}
    drive_text: dict = {}
    for pt in paired:
        notes.extend(pt.notes)
        res = _analyse_topic(pt, sim, real, t0, prm, notes, not_judged, channel_info)
        alignment[pt.name] = {'xcorr_lag': pt.tau_xcorr, 'xcorr_gain': pt.xcorr_gain,
                              'delays': [{'fields': te.fields, 'effect': kind,
                                          'tau': te.delay.tau, 'std': te.delay.std}
                                         for kind, te, _ in res.delays]}
        findings.extend(res.findings)
        if res.drive_text:
            drive_text[pt.name] = res.drive_text
        if res.detail is not None:
            details.append(res.detail)
    findings = reconcile(findings, notes)
    if not channel_info:
        raise ChannelError('no channel can be compared (' + '; '.join(
            f'{d["channel"]}: {d["reason"]}' for d in not_judged) + ')')
    findings = _fold_common_latency(findings, clock, notes)
    findings.sort(key=lambda f: (f['effect'] == 'unexplained', -f.get('confidence', 0.0)))
    duration = max((float(pt.t[-1] - pt.t[0]) for pt in paired if pt.t.size), default=0.0)
    findings, minor, weak = _sort_minor_and_weak(findings, prm, duration, notes)
    out = {'verdict': 'mismatch' if findings else 'consistent',
           'findings': findings, 'minor_findings': minor, 'weak_findings': weak,
           'time_alignment': {'clock': clock.as_dict(), **alignment},
           'drive': drive_text,
           'channels': channel_info,
           'not_judged': not_judged, 'notes': notes, 'bag_start': t0}
    return out, details
