# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pairing and aligning two recordings: which topics belong together, and on which clock.

- Topics pair by name, then by a ``--remap SIM:=REAL`` rule, then (one left on
  each side) by type. Topics of different types pair when they carry the same
  quantity (:data:`BRIDGES`: an IMU's yaw rate and an odometry's; a velocity
  command and an odometry twist); the pair is then judged as the real
  side's message type, with the simulated fields renamed to it.
- Clocks: when the two time lines hardly overlap (a simulation from 0, a
  recording in epoch time) the offset is found from the motion itself: the
  activity of each side (the magnitude of its rates and speeds, 20 Hz) is
  cross-correlated over every possible offset, and the peak must stand out
  from the next-best one, or the pair cannot be aligned. What is left (a
  latency of milliseconds) is judged per sensor later (:mod:`.timing`).
- Each pair is resampled onto the slower side's times; a simulated channel
  that went through a smoothing kernel (:attr:`Topic.kernels`) is compared
  with the real one through the same kernel.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from robot_calib.mismatch.channels import (ChannelError, COMPARED_TYPES, IMU_TYPE,
                                           JOINT_STATE_TYPE, kernel_weights, ODOM_TYPE,
                                           PairedTopic, Recording, smoothed, Topic, TWIST_TYPES)

# Fields of different message types that carry the same quantity: (a type, b type) ->
# {a field: b field}
BRIDGES = {
    (IMU_TYPE, ODOM_TYPE): {'angular_velocity.z': 'twist.twist.angular.z'},
    (TWIST_TYPES[0], ODOM_TYPE): {'linear.x': 'twist.twist.linear.x',
                                  'angular.z': 'twist.twist.angular.z'},
    (TWIST_TYPES[1], ODOM_TYPE): {'linear.x': 'twist.twist.linear.x',
                                  'angular.z': 'twist.twist.angular.z'},
    (IMU_TYPE, TWIST_TYPES[0]): {'angular_velocity.z': 'angular.z'},
    (IMU_TYPE, TWIST_TYPES[1]): {'angular_velocity.z': 'angular.z'},
}
PAIRED_TYPES = COMPARED_TYPES + TWIST_TYPES


def bridge(a_type: str, b_type: str) -> Optional[dict]:
    """Return {field of a: field of b} for two message types carrying the same quantities."""
    if a_type == b_type:
        return None
    if (a_type, b_type) in BRIDGES:
        return dict(BRIDGES[(a_type, b_type)])
    if (b_type, a_type) in BRIDGES:
        return {v: k for k, v in BRIDGES[(b_type, a_type)].items()}
    return None


def _interp(t_src: np.ndarray, x: np.ndarray, t_dst: np.ndarray, max_gap: float) -> np.ndarray:
    """Interpolate linearly; NaN outside the source span or across gaps longer than max_gap (s)."""
    ok = np.isfinite(x)
    ts, xs = t_src[ok], x[ok]
    if ts.size < 2:
        return np.full(t_dst.size, np.nan)
    y = np.interp(t_dst, ts, xs)
    idx = np.clip(np.searchsorted(ts, t_dst), 1, ts.size - 1)
    gap = ts[idx] - ts[idx - 1]
    bad = (t_dst < ts[0]) | (t_dst > ts[-1]) | (gap > max_gap)
    y[bad] = np.nan
    return y


def median_dt(t: np.ndarray) -> float:
    """Return the median sample period (s), NaN for fewer than two samples."""
    if t.size < 2:
        return float('nan')
    return float(np.median(np.diff(t)))


def xcorr_lag(sim: dict, real: dict, dt: float, max_lag: float) -> tuple[float, float]:
    """
    Return (lag s, correlation gain) of the peak of the summed normalised cross-correlation.

    Each channel is mean-removed and divided by its standard deviation; the
    correlations of all channels are summed; the peak is refined by a parabola
    through its neighbours. Positive lag: ``real`` lags ``sim``.
    """
    num = None
    n_used = 0
    for k in sim:
        a, b = sim[k], real.get(k)
        if b is None:
            continue
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < 20:
            continue
        a0 = np.where(ok, a - np.nanmean(a[ok]), 0.0)
        b0 = np.where(ok, b - np.nanmean(b[ok]), 0.0)
        sa, sb = np.std(a0[ok]), np.std(b0[ok])
        if sa <= 0 or sb <= 0:
            continue
        a0, b0 = a0 / sa, b0 / sb
        n = a0.size
        nfft = 1 << int(math.ceil(math.log2(2 * n)))
        c = np.fft.irfft(np.fft.rfft(b0, nfft) * np.conj(np.fft.rfft(a0, nfft)), nfft)
        c = c / ok.sum()
        num = c if num is None else num + c
        n_used += 1
    if num is None or not np.isfinite(dt) or dt <= 0:
        return 0.0, 0.0
    num = num / n_used
    nfft = num.size
    m = int(min(max_lag / dt, nfft // 4))
    if m < 1:
        return 0.0, 0.0
    lags = np.concatenate((np.arange(0, m + 1), np.arange(-m, 0)))
    vals = np.concatenate((num[:m + 1], num[nfft - m:]))
    i = int(np.argmax(vals))
    best = lags[i]
    frac = 0.0
    if -m < best < m:
        y0, y1, y2 = num[(best - 1) % nfft], num[best % nfft], num[(best + 1) % nfft]
        den = y0 - 2 * y1 + y2
        if den < 0:
            frac = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5))
    return float((best + frac) * dt), float(vals[i] - num[0])


@dataclass
class Clock:
    """
    How the real clock maps onto the simulated one: ``t_sim = t_real + offset``.

    ``method`` is ``'stamps'`` (the recordings share a clock) or ``'motion'``
    (found from the motion); ``confidence`` is the correlation peak over the
    next-best one (1 for stamps); ``correspondence`` how well the real motion
    follows the simulated one once aligned (:func:`correspondence`, NaN when
    nothing moves).
    """

    offset: float = 0.0
    method: str = 'stamps'
    confidence: float = 1.0
    correlation: float = float('nan')
    correspondence: float = float('nan')

    def as_dict(self) -> dict:
        """Return the findings.json form."""
        return {'offset': self.offset, 'method': self.method, 'confidence': self.confidence,
                'correlation': self.correlation, 'correspondence': self.correspondence}


def _span(rec: Recording) -> tuple[float, float]:
    tps = [tp for tp in rec.values() if len(tp)]
    if not tps:
        return float('nan'), float('nan')
    return float(min(tp.t[0] for tp in tps)), float(max(tp.t[-1] for tp in tps))


def _activity_of(tp: Topic) -> Optional[np.ndarray]:
    """Return a topic's motion magnitude per sample, or None when it has none."""
    f = tp.fields
    if tp.msgtype == IMU_TYPE:
        keys = [k for k in f if k.startswith('angular_velocity.')]
    elif tp.msgtype == ODOM_TYPE:
        keys = [k for k in ('twist.twist.linear.x', 'twist.twist.angular.z') if k in f]
    elif tp.msgtype in TWIST_TYPES:
        keys = [k for k in ('linear.x', 'angular.z') if k in f]
    elif tp.msgtype == JOINT_STATE_TYPE:
        keys = [k for k in f if k.startswith('velocity.')]
    else:
        return None
    if not keys:
        return None
    cols = [np.abs(np.nan_to_num(f[k])) for k in keys]
    cols = [c / s for c in cols if (s := float(np.std(c))) > 0]
    return np.sum(cols, axis=0) if cols else None


def activity(rec: Recording, names: list, rate: float = 20.0) -> tuple[float, np.ndarray]:
    """Return (start s, activity on a grid of ``rate`` Hz) of the named topics, summed."""
    t0, t1 = _span({k: rec[k] for k in names})
    if not np.isfinite(t0) or t1 - t0 < 2.0 / rate:
        return t0, np.zeros(0)
    grid = np.arange(t0, t1, 1.0 / rate)
    out = np.zeros(grid.size)
    for k in names:
        a = _activity_of(rec[k])
        if a is not None and a.size > 1:
            y = np.interp(grid, rec[k].t, a, left=0.0, right=0.0)
            out += y / max(float(np.std(y)), 1e-12)
    return t0, out


def motion_offset(sim: Recording, real: Recording, pairs: list, rate: float = 20.0,
                  min_overlap: float = 0.5) -> Clock:
    """
    Return the clock offset found by cross-correlating the two recordings' activity.

    Every offset at which the recordings overlap by at least ``min_overlap``
    of the shorter one is tried (a normalised correlation over the overlap);
    the peak must reach 0.3 and stand 1.2 times above the best peak more than
    2 s away, or the motion is not distinctive enough.

    :raises ChannelError: when the recordings cannot be aligned
    """
    s0, a = activity(sim, [p[0] for p in pairs], rate)
    r0, b = activity(real, [p[1] for p in pairs], rate)
    if a.size < 20 or b.size < 20 or np.std(a) <= 0 or np.std(b) <= 0:
        raise ChannelError('cannot align the recordings: one of them has no motion to align on '
                           '(give both the same clock, or record some turns and stops)')
    a, b = a - a.mean(), b - b.mean()
    n = 1 << int(math.ceil(math.log2(a.size + b.size)))
    fa, fb = np.fft.rfft(a, n), np.fft.rfft(b, n)
    cross = np.fft.irfft(fb * np.conj(fa), n)      # sum_i a[i] b[i + k]
    oa, ob = np.fft.rfft(np.ones(a.size), n), np.fft.rfft(np.ones(b.size), n)
    count = np.rint(np.fft.irfft(ob * np.conj(oa), n))            # overlap in samples
    ea = np.fft.irfft(ob * np.conj(np.fft.rfft(a * a, n)), n)      # energy of a there
    eb = np.fft.irfft(np.fft.rfft(b * b, n) * np.conj(oa), n)      # energy of b there
    with np.errstate(invalid='ignore', divide='ignore'):
        corr = cross / np.sqrt(np.maximum(ea * eb, 1e-300))
    lags = np.where(np.arange(n) < n // 2, np.arange(n), np.arange(n) - n)
    ok = count >= min_overlap * min(a.size, b.size)
    corr = np.where(ok & np.isfinite(corr), corr, -np.inf)
    k = int(np.argmax(corr))
    peak = float(corr[k])
    far = np.abs(lags - lags[k]) > 2.0 * rate
    second = float(np.max(corr[far])) if np.any(far & ok) else -np.inf
    conf = peak / second if second > 0 else math.inf
    if not np.isfinite(peak) or peak < 0.3 or conf < 1.2:
        raise ChannelError(f'cannot align the recordings from their motion (best correlation '
                           f'{peak:.2f}, next best {second:.2f}): the runs do not show the same '
                           'motion, or it repeats; give both the same clock')
    frac = 0.0
    y0, y2 = corr[(k - 1) % n], corr[(k + 1) % n]
    if np.isfinite(y0) and np.isfinite(y2) and y0 - 2 * peak + y2 < 0:
        frac = float(np.clip(0.5 * (y0 - y2) / (y0 - 2 * peak + y2), -0.5, 0.5))
    lag = (lags[k] + frac) / rate            # b lags a by this much on their own grids
    return Clock(offset=float(s0 - r0 - lag), method='motion', confidence=float(conf),
                 correlation=peak)


def _resolve(sim_c: dict, real_c: dict, remaps: list, notes: list,
             not_judged: list) -> list:
    """Return the (sim topic, real topic) pairs: remaps, same names, the only one of a type."""
    pairs = []
    for a, b in remaps:
        if a not in sim_c:
            raise ChannelError(f'--remap {a}:={b}: {a} is not in the simulated recording '
                               f'(topics: {", ".join(sorted(sim_c)) or "none"})')
        if b not in real_c:
            raise ChannelError(f'--remap {a}:={b}: {b} is not in the real recording '
                               f'(topics: {", ".join(sorted(real_c)) or "none"})')
        pairs.append((a, b))
    used_s, used_r = {p[0] for p in pairs}, {p[1] for p in pairs}
    for name in sorted(set(sim_c) & set(real_c)):
        if name not in used_s and name not in used_r and sim_c[name].msgtype in COMPARED_TYPES:
            pairs.append((name, name))
            used_s.add(name)
            used_r.add(name)
    for mt in COMPARED_TYPES:
        us = [k for k, v in sim_c.items() if v.msgtype == mt and k not in used_s]
        ur = [k for k, v in real_c.items() if v.msgtype == mt and k not in used_r]
        if len(us) == 1 and len(ur) == 1:
            notes.append(f'sim topic {us[0]} compared with real topic {ur[0]} (same type, '
                         'different names)')
            pairs.append((us[0], ur[0]))
            used_s.add(us[0])
            used_r.add(ur[0])
        elif us and len(ur) > 1:
            for k in us:
                not_judged.append({'channel': k, 'reason': (
                    f'the real recording has several {mt.rsplit("/", 1)[-1]} topics '
                    f'({", ".join(ur)}) and none named {k}: say which with --remap '
                    f'{k}:={ur[0]}')})
                used_s.add(k)
    for k, v in sim_c.items():
        if k not in used_s and v.msgtype in COMPARED_TYPES:
            not_judged.append({'channel': k, 'reason': 'topic missing in the real recording'})
    for k, v in real_c.items():
        if k not in used_r and v.msgtype in COMPARED_TYPES:
            not_judged.append({'channel': k, 'reason': 'topic missing in the simulated '
                               'recording'})
    return pairs


def _bridged(a: Topic, b: Topic, asked: bool,
             not_judged: list) -> Optional[tuple[Topic, Topic]]:
    """
    Return the pair on one message type (the real one's), or None (reason noted).

    Topics of different types are compared on their common quantities only
    when the user paired them (``asked``): a name shared by chance is no reason.
    """
    if a.msgtype == b.msgtype:
        return a, b
    fmap = bridge(a.msgtype, b.msgtype)
    if not fmap or not asked:
        hint = f'; pair them with --remap {a.name}:={b.name} to compare ' \
            f'{", ".join(fmap)}' if fmap else ' and no common quantity'
        not_judged.append({'channel': a.name, 'reason': f'different message types: sim '
                           f'{a.msgtype}, real {b.msgtype}{hint}'})
        return None
    fields = {fmap[k]: v for k, v in a.fields.items() if k in fmap}
    kernels = {fmap[k]: v for k, v in a.kernels.items() if k in fmap}
    return Topic(b.name, b.msgtype, a.t, fields, kernels), b


def pair_topics(sim: Recording, real: Recording, max_lag: float = 0.5,
                remaps: Optional[list] = None,
                min_correspondence: float = 0.4) -> tuple[list, list, float, list, Clock]:
    """
    Pair, align and resample the compared topics of two recordings.

    :param sim: the simulated recording
    :param real: the real recording
    :param max_lag: largest time offset (s) the cross-correlation searches
    :param remaps: ``[(sim topic, real topic)]`` pairs given by the user
    :param min_correspondence: least :func:`correspondence` (0..1) of a pair
        that moves; below it the recordings are not the same run
    :returns: (paired topics, not-judged entries ``{'channel', 'reason'}``,
        the sim start (s) used as time zero, notes, the clock mapping)
    :raises ChannelError: when nothing at all can be compared, a remap names a
        missing topic, the clocks differ and the motion cannot align them, or
        the real motion does not follow the simulated one
    """
    notes: list = []
    not_judged: list = []
    sim_c = {k: v for k, v in sim.items() if v.msgtype in PAIRED_TYPES}
    real_c = {k: v for k, v in real.items() if v.msgtype in PAIRED_TYPES}
    if not any(v.msgtype in COMPARED_TYPES for v in sim_c.values()) and not remaps:
        raise ChannelError('the simulated recording has no IMU, odometry or joint-state topic '
                           f'(topics: {", ".join(sorted(sim)) or "none"})')
    if not any(v.msgtype in COMPARED_TYPES for v in real_c.values()) and not remaps:
        raise ChannelError('the real recording has no IMU, odometry or joint-state topic '
                           f'(topics: {", ".join(sorted(real)) or "none"})')
    pairs = _resolve(sim_c, real_c, list(remaps or []), notes, not_judged)
    s0, s1 = _span({p[0]: sim_c[p[0]] for p in pairs}) if pairs else (np.nan, np.nan)
    r0, r1 = _span({p[1]: real_c[p[1]] for p in pairs}) if pairs else (np.nan, np.nan)
    if not pairs or not (np.isfinite(s0) and np.isfinite(r0)):
        return [], not_judged, float(s0) if np.isfinite(s0) else 0.0, notes, Clock()
    clock = Clock()
    if min(s1, r1) - max(s0, r0) < 0.5 * min(s1 - s0, r1 - r0):
        clock = motion_offset(sim_c, real_c, pairs)
        notes.append(f'the recordings use different clocks (sim from {s0:.3f} s, real from '
                     f'{r0:.3f} s); aligned on their motion: real + {clock.offset:.3f} s '
                     f'(correlation {clock.correlation:.2f}, {clock.confidence:.1f} times the '
                     'next best)')
    paired = []
    asked = set(remaps or [])
    for a_name, b_name in pairs:
        both = _bridged(sim_c[a_name], real_c[b_name], (a_name, b_name) in asked, not_judged)
        if both is None:
            continue
        a, b = both
        if len(a) < 20 or len(b) < 20:
            not_judged.append({'channel': a.name, 'reason': f'too few samples (sim {len(a)}, '
                               f'real {len(b)})'})
            continue
        if a_name != b_name and a.name == b.name and sim_c[a_name].msgtype != a.msgtype:
            notes.append(f'sim {a_name} ({sim_c[a_name].msgtype}) compared with real {b_name} '
                         f'({b.msgtype}) on {", ".join(a.fields)}')
        pt = _pair_one(a, b, s0, clock.offset, max_lag, not_judged)
        if pt is not None:
            paired.append(pt)
    score, per = correspondence(paired)
    clock.correspondence = round(score, 3) if np.isfinite(score) else float('nan')
    if np.isfinite(score) and score < min_correspondence:
        worst = ', '.join(f'{k} {v:.2f}' for k, v in sorted(per.items(), key=lambda kv: kv[1])[:3])
        raise ChannelError(f'the real motion does not follow the simulated one (correspondence '
                           f'{score:.2f} < {min_correspondence:.2f} over {len(per)} moving '
                           f'channels; lowest {worst}): these are not recordings of the same '
                           'run, so no effect can explain their difference')
    return paired, not_judged, s0, notes, clock


def _pair_one(a: Topic, b: Topic, t0: float, shift: float, max_lag: float,
              not_judged: list) -> Optional[PairedTopic]:
    tb = b.t + shift
    dta, dtb = median_dt(a.t), median_dt(tb)
    notes = []
    if not (dta > 0 and dtb > 0):
        not_judged.append({'channel': a.name, 'reason': 'time stamps do not increase'})
        return None
    if abs(dta - dtb) > 0.05 * min(dta, dtb):
        notes.append(f'different rates: sim {1 / dta:.1f} Hz, real {1 / dtb:.1f} Hz; '
                     'compared at the slower rate')
    lo, hi = max(a.t[0], tb[0]), min(a.t[-1], tb[-1])
    if hi - lo < 20 * max(dta, dtb):
        not_judged.append({'channel': a.name, 'reason': 'the two recordings of this topic do '
                           'not overlap in time'})
        return None
    dur_a, dur_b = a.t[-1] - a.t[0], tb[-1] - tb[0]
    if abs(dur_a - dur_b) > 0.02 * max(dur_a, dur_b) + 2 * max(dta, dtb):
        notes.append(f'different lengths: sim {dur_a:.1f} s, real {dur_b:.1f} s; compared '
                     f'on the common {hi - lo:.1f} s')
    if dta >= dtb:
        grid = a.t[(a.t >= lo) & (a.t <= hi)]
        dt = dta
    else:
        grid = tb[(tb >= lo) & (tb <= hi)]
        dt = dtb
    sim_f, real_f, kernels = {}, {}, {}
    for k in a.fields:
        if k not in b.fields:
            continue
        sim_f[k] = _interp(a.t, a.fields[k], grid, 5 * dta + 1e-9)
        real_k = b.fields[k]
        if k in a.kernels:  # compare the real channel through the simulation's own smoothing
            real_k = smoothed(real_k, kernel_weights(a.kernels[k], dtb))
            kernels[k] = kernel_weights(a.kernels[k], dt)
        real_f[k] = _interp(tb, real_k, grid, 5 * dtb + 1e-9)
    if kernels:
        used = ', '.join(f'{k} {s[0]} +-{s[1] * 1000:.0f} ms' for k, s in a.kernels.items())
        notes.append(f'{a.name}: the real channels are compared through the smoothing of the '
                     f'simulated ones ({used})')
    tau, gain = xcorr_lag(sim_f, real_f, dt, max_lag)
    return PairedTopic(a.name, a.msgtype, grid - t0, sim_f, real_f, dt, tau, gain, notes,
                       sim_src=(a.t - t0, a.fields), kernels=kernels, dt_sim=float(dta),
                       dt_real=float(dtb))


def _blocks(x: np.ndarray, step: int) -> np.ndarray:
    """Return the means of consecutive blocks of ``step`` samples (NaN where none is finite)."""
    n = x.size // step
    if n == 0:
        return np.zeros(0)
    b = x[:n * step].reshape(n, step)
    ok = np.isfinite(b)
    with np.errstate(invalid='ignore'):
        return np.where(ok.any(axis=1), np.where(ok, b, 0.0).sum(axis=1) /
                        np.maximum(ok.sum(axis=1), 1), np.nan)


def slow_share(x: np.ndarray, width: int) -> float:
    """
    Return the share (0..1) of a signal's variance left after a ``width``-sample moving average.

    Motion varies over seconds and keeps most of its variance; white noise
    keeps about ``1 / width`` of it. NaN samples are left out; 0 for a constant.
    """
    ok = np.isfinite(x)
    if ok.sum() < 2 * width:
        return 0.0
    y = x[ok] - float(np.mean(x[ok]))
    v = float(np.mean(y * y))
    if not v > 0.0:
        return 0.0
    s = np.convolve(y, np.ones(width) / width, mode='valid')
    return float(np.clip(np.mean(s * s) / v, 0.0, 1.0))


def _multiple_correlation(y: np.ndarray, X: np.ndarray) -> float:
    """Return the multiple correlation (0..1) of ``y`` on the columns of ``X`` with a constant."""
    ok = np.isfinite(y) & np.all(np.isfinite(X), axis=1)
    if ok.sum() < max(20, 4 * (X.shape[1] + 1)):
        return float('nan')
    yy, XX = y[ok] - y[ok].mean(), X[ok] - X[ok].mean(axis=0)
    vy = float(yy @ yy)
    if not vy > 0.0:
        return float('nan')
    beta, *_ = np.linalg.lstsq(XX, yy, rcond=None)
    e = yy - XX @ beta
    return float(np.sqrt(np.clip(1.0 - float(e @ e) / vy, 0.0, 1.0)))


def correspondence(paired: list, max_shift: float = 1.0, rate: float = 20.0,
                   min_slow: float = 0.3) -> tuple[float, dict]:
    """
    Return how well the real motion follows the simulated one (0..1), and per channel.

    Both sides are averaged onto ``rate`` Hz. A channel takes part when both
    its simulated and its real values move (keep at least ``min_slow`` of
    their variance through a 1 s moving average: motion, not noise). Its
    score is the multiple correlation of the real values on all the simulated
    fields of the topic (a scale, an offset, a mounting rotation or a cross-axis
    term keep it high), at the best shift within ``max_shift`` s (a latency).
    The recordings' score is the mean over the channels that take part; NaN
    when none does (nothing moves: nothing to tell).
    """
    per: dict = {}
    for pt in paired:
        step = max(1, int(round(1.0 / (rate * pt.dt)))) if pt.dt > 0 else 1
        sim = {f: _blocks(x, step) for f, x in pt.sim.items()}
        real = {f: _blocks(x, step) for f, x in pt.real.items()}
        width = max(2, int(round(1.0 / (step * pt.dt)))) if pt.dt > 0 else 20
        moving = [f for f in sim if slow_share(sim[f], width) >= min_slow]
        if not moving:
            continue
        X = np.column_stack([sim[f] for f in moving])
        m = int(max_shift / (step * pt.dt)) if pt.dt > 0 else 0
        n = X.shape[0]
        for f in real:
            if f not in moving or slow_share(real[f], width) < min_slow:
                continue

            def at(k: int) -> float:  # real lags the simulation by k samples
                lo, hi = max(0, -k), min(n, n - k)
                if hi - lo < 20:
                    return float('nan')
                return _multiple_correlation(real[f][lo + k:hi + k], X[lo:hi])
            # every other shift, then the neighbours of the best (motion is smooth at 20 Hz)
            tried = {k: at(k) for k in range(-m, m + 1, 2)}
            ok = [k for k, r in tried.items() if np.isfinite(r)]
            if not ok:
                continue
            k0 = max(ok, key=tried.get)
            tried.update({k: at(k) for k in (k0 - 1, k0 + 1) if -m <= k <= m})
            best = max(r for r in tried.values() if np.isfinite(r))
            per[f'{pt.name}.{f}'] = round(best, 3)
    score = float(np.mean(list(per.values()))) if per else float('nan')
    return score, per
