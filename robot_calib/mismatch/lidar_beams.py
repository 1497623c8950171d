# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Beam-by-beam comparison of two recordings that see the same geometry.

When the simulated scans are taken at the real poses (an ideal scan
ray-cast into a map at the true pose, or a simulation of the same building
replayed along the real path), beam ``i`` of the real scan and beam ``i`` of
the simulated scan at the same stamp see the same surface. Then, with
``d = r_real - r_sim`` and ``g = dr_sim / dangle`` (central difference along
the beams; first-order Taylor expansion of a turned scanner)::

    d = b + s r_sim + delta g - d.u + g (d.n) / r   (range_bias, range_scale, mounting
                                                    yaw delta and offset d)

(``u``, ``n``: the beam's direction and its normal; the angle ``delta`` is
iterated, the simulated beams re-sampled by the angle found, Gauss-Newton)

fitted by Huber-weighted least squares. The noise left after it is binned by
range: ``sigma_real(r)^2 = sigma_d(r)^2 - sigma_sim^2`` (the simulation's own
noise from its adjacent-beam second differences, ``var = 1.5 sigma^2``), and
``sigma_real = s0 + s1 r`` fitted to the bins (``range_noise_growth``).
Beams the simulation returns and the real scanner does not are dropouts,
modelled as a rate that steps up beyond a range or beyond an incidence angle
(``dropout_rate``), against the simulation's own loss rate
(:mod:`robot_calib.mismatch.lidar_dropout`).

An uncorrected sweep (``scan_distortion``): beam ``i`` of ``n`` is measured
``i / n`` of the sweep time after the stamp, so while the real robot turns at
``w`` and drives at ``v`` (its odometry at the stamp) a sweep ``dT`` longer
than the simulated one adds the column ``(i / n) dT (w g + v a_x)`` (``a_x``:
the offset column of x above); ``dT`` is the finding (s). Without turning it
is not judged (the listed reason names the turning seen).

Whether both see the same geometry is tested first (the share of beams that
agree within 0.1 m + 5 %); otherwise nothing here is judged and the reason is
listed. Standard errors by a block jackknife over time blocks; each effect
must improve the held-out chunks (every third of ``heldout_chunks``).
"""

from __future__ import annotations

import math
from typing import Optional, TYPE_CHECKING

import numpy as np

from robot_calib.mismatch.lidar_dropout import dropout_findings

if TYPE_CHECKING:  # pragma: no cover
    from robot_calib.mismatch.lidar import LidarMismatchParams

__all__ = ['beam_findings', 'pair_scans', 'sweep_vs_delay']

BLOCKS = 6
CHUNKS = 12
Z_MIN = 5.0
FLOORS = {'bias': 0.005, 'scale': 0.002, 'yaw': 0.0035, 'x': 0.015, 's1': 0.0015,
          'sweep_time': 0.005, 'tau': 0.008}


def pair_scans(sim: list, real: list, tol: float = 0.02) -> tuple:
    """
    Return (sim ranges, real ranges, angles, times, stamp differences) of paired scans.

    Scans are paired when their beams are equal and their stamps within ``tol``
    (s); the stamp difference is the real minus the simulated stamp (s).
    """
    ts = np.array([s.t for s in sim])
    rs, rr, tt, dp = [], [], [], []
    ang = None
    for r in real:
        i = int(np.clip(np.searchsorted(ts, r.t), 1, ts.size - 1))
        i = i - 1 if abs(ts[i - 1] - r.t) < abs(ts[i] - r.t) else i
        s = sim[i]
        if abs(s.t - r.t) > tol or s.ranges.size != r.ranges.size or \
                abs(s.angle_min - r.angle_min) > 1e-6 or \
                abs(s.angle_increment - r.angle_increment) > 1e-9:
            continue
        if ang is None:
            ang = r.angles()
        rs.append(np.where((s.ranges >= s.range_min) & (s.ranges < s.range_max), s.ranges,
                           np.nan))
        rr.append(np.where((r.ranges >= r.range_min) & (r.ranges < r.range_max), r.ranges,
                           np.nan))
        tt.append(r.t)
        dp.append(r.t - s.t)
    if not rs:
        return None
    return np.array(rs), np.array(rr), ang, np.array(tt), np.array(dp)


def huber_lstsq(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Return the robust least-squares solution of ``a x = y`` (Huber weights, 6 IRLS steps)."""
    w = np.ones(y.size)
    x = np.zeros(a.shape[1])
    for _ in range(6):
        x = np.linalg.lstsq(a * w[:, None], y * w, rcond=None)[0]
        r = y - a @ x
        sc = 1.4826 * np.median(np.abs(r)) + 1e-9
        u = np.abs(r) / (1.5 * sc)
        w = np.sqrt(np.where(u <= 1, 1.0, 1.0 / np.maximum(u, 1e-9)))
    return x


def _jack(fun, blk: np.ndarray, nb: int) -> np.ndarray:
    """Return the block-jackknife standard error of ``fun(mask)`` (vector)."""
    loo = np.array([fun(blk != b) for b in range(nb)])
    return np.sqrt((nb - 1) / nb * ((loo - loo.mean(axis=0)) ** 2).sum(axis=0))


def _conf(z: float) -> float:
    return float(1.0 - 0.5 ** ((max(z, 0.0) / Z_MIN) ** 2.1))


def beam_findings(sim: list, real: list, topic: str, notes: list, not_judged: list,
                  motion: Optional[tuple] = None, min_turn: float = 0.5) -> list:
    """
    Return the beam findings of one scan topic (empty with a reason when not judged).

    ``motion``: the real recording's odometry ``(t, vx, wz)`` (s, m/s, rad/s) for the
    sweep distortion; ``min_turn`` (rad): the summed turning over the compared scans
    below which the distortion is not judged.
    """
    p = _comparable(sim, real, topic, not_judged)
    if p is None:
        return []
    rs, rr, ang, tt, dp, agree = p
    inc = float(ang[1] - ang[0]) if ang.size > 1 else 1.0
    ns, nbm = rs.shape
    blk_s = np.minimum((np.arange(ns) * BLOCKS) // ns, BLOCKS - 1)
    held_s = ((np.minimum((np.arange(ns) * CHUNKS) // ns, CHUNKS - 1)) % 3) == 2
    window = [float(tt[0]), float(tt[-1])]
    sweep = _sweep_rows(motion, tt, nbm, min_turn, topic, not_judged)
    turn = 0.0
    for _ in range(4):  # Gauss-Newton on the angle: re-sample the sim beams, fit again
        rsh = _turned(rs, turn / inc)
        g = np.full_like(rsh, np.nan)
        g[:, 1:-1] = (rsh[:, 2:] - rsh[:, :-2]) / (2 * inc)
        smooth = np.abs(g * inc) < 0.05 + 0.02 * np.nan_to_num(rsh)  # no depth edge
        agree2 = agree & (np.abs(rr - rsh) < 0.1 + 0.05 * np.nan_to_num(rsh))
        use = agree2 & np.isfinite(g) & smooth
        ii = np.nonzero(use)
        r0, d0, g0 = rsh[use], (rr - rsh)[use], g[use]
        bk, hd = blk_s[ii[0]], held_s[ii[0]]
        b = np.broadcast_to(ang, rs.shape)[use]
        cb, sb = np.cos(b), np.sin(b)
        # a scanner moved by (dx, dy): dr = -d.u + g (d.n) / r, u = (cos, sin), n = (-sin, cos)
        a = np.c_[np.ones(r0.size), r0, g0, -cb - g0 * sb / r0, -sb + g0 * cb / r0]
        if sweep is not None:
            # the real scanner's view moved by the motion over a time: c = w g + v a_x;
            # beam i seen i/n of the sweep late (f c dT); the scan seen tau before the
            # simulated one beyond their stamps' difference (-c tau, the difference known)
            c = sweep[0][ii[0]] * g0 + sweep[1][ii[0]] * a[:, 3]
            a = np.c_[a, c * (ii[1] / nbm), -c]
            d0 = d0 - dp[ii[0]] * c
        if r0.size < 200:
            not_judged.append({'channel': f'{topic}.ranges', 'reason': 'too few beams on '
                               'smooth surfaces in both recordings'})
            return []
        x = huber_lstsq(a, d0)
        if abs(x[2]) < 0.05 * inc:
            break
        turn += x[2]
    sd = _jack(lambda m: huber_lstsq(a[m], d0[m]), bk, BLOCKS)
    xf = huber_lstsq(a[~hd], d0[~hd])
    x[2] += turn
    # held out: the turn found on all time is a part of the model, so it too must help
    d0 = d0 + turn * g0
    xf[2] += turn
    names = [('range_bias', ('bias',), (0,)), ('range_scale', ('scale',), (1,)),
             ('lidar_mounting_yaw', ('yaw',), (2,)), ('lidar_mounting_offset', ('x', 'y'), (3, 4))]
    if sweep is not None:
        names += [('scan_distortion', ('sweep_time',), (5,)),
                  ('lidar_time_offset', ('tau',), (6,))]
    out = _judged(x, xf, sd, names, d0, a, hd, topic, notes)
    e = d0 - a @ x
    out.extend(_noise(rs, r0, e, bk, hd, topic, window, notes))
    # lost returns are counted where the sim, turned by the yaw fitted, sees a surface on both
    # sides of the real beam's direction: a turned beam next to an edge or a gap of the sim
    # scan may miss it without any dropout
    out.extend(dropout_findings(_turned(rs, x[2] / inc) if x[2] else rs, rr, ang, blk_s,
                                held_s, topic, lambda f, b: _jack(f, b, BLOCKS), notes,
                                _sim_noise(rs) or 0.01))
    return out


def _comparable(sim: list, real: list, topic: str, not_judged: list) -> Optional[tuple]:
    """
    Return the paired scans and the beams that agree, or None (the reason in ``not_judged``).

    (sim ranges, real ranges, beam angles, stamps, stamp differences, agreeing beams).
    """
    p = pair_scans(sim, real)
    if p is None or p[0].shape[0] < 20:
        not_judged.append({'channel': f'{topic}.ranges', 'reason': 'the beams are compared '
                           'only between scans of the same stamps and beam angles (an ideal '
                           'scan at the true pose, or a simulation replayed along the real '
                           'path); these recordings have none in common'})
        return None
    rs, rr = p[0], p[1]
    both = np.isfinite(rs) & np.isfinite(rr)
    agree = both & (np.abs(rr - rs) < 0.1 + 0.05 * np.nan_to_num(rs))
    share = np.median(agree.sum(axis=1) / np.maximum(both.sum(axis=1), 1))
    if share < 0.6:
        not_judged.append({'channel': f'{topic}.ranges', 'reason': 'the two recordings do not '
                           f'see the same geometry beam for beam (only {share:.0%} of the beams '
                           'agree within 0.1 m + 5 %); the beams are not compared'})
        return None
    return (*p, agree)


def _judged(x: np.ndarray, xf: np.ndarray, sd: np.ndarray, names: list, d0: np.ndarray,
            a: np.ndarray, hd: np.ndarray, topic: str, notes: list) -> list:
    """
    Return the findings of the fitted terms that clear the bar and help held-out time.

    ``x`` the fit on all time with its block-jackknife ``sd``, ``xf`` the fit on the
    fitted part; ``names``: (effect, keys, columns of ``a``); ``hd``: held-out rows.
    """
    out = []
    for effect, keys, js in names:
        z = math.sqrt(sum((x[j] / max(sd[j], 1e-12)) ** 2 for j in js))
        size = math.sqrt(sum(x[j] ** 2 for j in js))
        if z < Z_MIN or size < FLOORS[keys[0]]:
            continue
        without = xf.copy()
        without[list(js)] = 0.0
        res = [float(np.sqrt(np.mean(_clip(d0 - a @ c)[rows] ** 2)))
               for c in (without, xf) for rows in (~hd, hd)]
        if not res[3] < res[1]:
            notes.append(f'{topic}: a candidate {effect} did not improve the held-out part')
            continue
        val = float(x[js[0]])
        txt = _sentence(effect, val, x)
        chan = f'{topic}.stamp' if effect == 'lidar_time_offset' else f'{topic}.ranges'
        out.append({'channel': chan, 'effect': effect,
                    'parameters': {k: float(x[j]) for k, j in zip(keys, js)},
                    'std': {k: float(sd[j]) for k, j in zip(keys, js)}, 'window': None,
                    'fit': {'rmse_before': res[0], 'rmse_after': res[2],
                            'heldout_rmse_before': res[1], 'heldout_rmse_after': res[3]},
                    'confidence': _conf(z), 'evidence': {'z': float(z)}, 'explanation': txt})
    return out


def _sentence(effect: str, val: float, x: np.ndarray) -> str:
    """Return the explanation of a beam finding (``val`` its first parameter, ``x`` the fit)."""
    return {'range_bias': f'Real ranges are {val * 100:+.1f} cm longer than the simulated '
            'ones at the same beam (offset at every range).',
            'range_scale': f'Real ranges are {val * 100:+.2f} % longer than the simulated '
            'ones, in proportion to range.',
            'lidar_mounting_yaw': f'Real beams look {math.degrees(val):+.2f} deg off the '
            'simulated ones: the scanner is turned about z from where the simulation '
            'mounts it.',
            'lidar_mounting_offset': 'Real beams look as if the scanner sat '
            f'({x[3] * 100:+.1f}, {x[4] * 100:+.1f}) cm from where the simulation '
            'mounts it.',
            'lidar_time_offset': f'Real scans show the scene {abs(val) * 1000:.0f} ms '
            f'{"before" if val > 0 else "after"} their stamp, relative to the simulated '
            "ones (beam by beam, with the odometry's motion): their stamps are late by "
            'that much.',
            'scan_distortion': 'Real scans are bent by the sweep while the robot turns as '
            f'if each sweep took {val * 1000:+.0f} ms longer than the simulated one (beam '
            'i seen i/n of the sweep after the stamp; a deskewed simulation sweeps in 0 '
            'ms).'}[effect]


def _sweep_rows(motion, tt, nbm, min_turn, topic, not_judged) -> Optional[tuple]:
    """Return the real yaw rate and speed (rad/s, m/s) at each compared scan, or None."""
    why = None
    if motion is None:
        why = 'the sweep distortion is measured against the odometry, which a recording lacks'
    else:
        w = np.interp(tt, motion[0], motion[2])
        v = np.interp(tt, motion[0], motion[1])
        dt = float(np.median(np.diff(tt))) if tt.size > 1 else 0.0
        turned = float(np.abs(w).sum() * dt)
        if turned < min_turn or nbm < 20:
            why = (f'the sweep distortion needs turning; the compared scans turn '
                   f'{math.degrees(turned):.0f} deg in all')
    if why is not None:
        not_judged.append({'channel': f'{topic}.sweep', 'reason': why})
        return None
    return w, v


def _turned(rs: np.ndarray, k: float) -> np.ndarray:
    """Return the beams re-sampled ``k`` beams later (linear, NaN past the ends)."""
    if k == 0.0:
        return rs
    n = rs.shape[1]
    pos = np.arange(n) + k
    i0 = np.floor(pos).astype(int)
    f = pos - i0
    ok = (i0 >= 0) & (i0 + 1 < n)
    out = np.full_like(rs, np.nan)
    out[:, ok] = (1 - f[ok]) * rs[:, i0[ok]] + f[ok] * rs[:, i0[ok] + 1]
    return out


def _clip(e: np.ndarray) -> np.ndarray:
    """Return residuals clipped at 5 robust sigma (the held-out RMSE ignores stray beams)."""
    sc = 1.4826 * np.median(np.abs(e)) + 1e-9
    return np.clip(e, -5 * sc, 5 * sc)


def _sim_noise(rs: np.ndarray) -> float:
    """Return the simulation's range noise (m) from adjacent-beam second differences."""
    e = rs[:, 1:-1] - 0.5 * (rs[:, :-2] + rs[:, 2:])
    near = rs[:, 1:-1] < np.nanpercentile(rs, 33)
    v = e[near & np.isfinite(e) & (np.abs(e) < 0.1)]
    return float(1.4826 * np.median(np.abs(v)) / math.sqrt(1.5)) if v.size > 50 else 0.0


def _noise_line(r0, e, m, edges, s_sim):
    """Return (s0, s1) of the real noise line fitted to range bins of the rows ``m``."""
    rc, sg = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        k = m & (r0 >= lo) & (r0 < hi)
        if k.sum() < 30:
            continue
        sd = 1.4826 * np.median(np.abs(e[k] - np.median(e[k])))
        rc.append(np.median(r0[k]))
        sg.append(math.sqrt(max(sd ** 2 - s_sim ** 2, 0.0)))
    if len(rc) < 3:
        return np.array([np.nan, np.nan])
    return np.polyfit(rc, sg, 1)[::-1]


def _noise(rs, r0, e, bk, hd, topic, window, notes) -> list:
    s_sim = _sim_noise(rs)
    edges = np.quantile(r0, np.linspace(0, 1, 9))
    edges[-1] += 1e-9
    c = _noise_line(r0, e, np.ones(r0.size, bool), edges, s_sim)
    if not np.all(np.isfinite(c)):
        return []
    sd = _jack(lambda m: _noise_line(r0, e, m, edges, s_sim), bk, BLOCKS)
    z = c[1] / max(sd[1], 1e-12)
    if z < Z_MIN or c[1] < FLOORS['s1']:
        return []
    cf = _noise_line(r0, e, ~hd, edges, s_sim)
    sig_c = math.sqrt(np.mean((cf[0] + cf[1] * r0[~hd]) ** 2) + s_sim ** 2)
    sig_l = np.sqrt(np.maximum(cf[0] + cf[1] * r0, 1e-4) ** 2 + s_sim ** 2)
    ec = _clip(e)

    def nll(sig, rows):
        s = sig[rows] if np.ndim(sig) else sig
        return float(np.mean(np.log(s) + 0.5 * (ec[rows] / s) ** 2))
    res = [nll(sig_c, ~hd), nll(sig_c, hd), nll(sig_l, ~hd), nll(sig_l, hd)]
    if not res[3] < res[1]:
        notes.append(f'{topic}: a candidate range_noise_growth did not improve the held-out part')
        return []
    return [{'channel': f'{topic}.ranges', 'effect': 'range_noise_growth',
             'parameters': {'s0': float(c[0]), 's1': float(c[1])},
             'std': {'s0': float(sd[0]), 's1': float(sd[1])}, 'window': None,
             'fit': {'rmse_before': res[0], 'rmse_after': res[2], 'heldout_rmse_before': res[1],
                     'heldout_rmse_after': res[3], 'measure': 'mean negative log-likelihood'},
             'confidence': _conf(z), 'evidence': {'z': float(z), 'sim_noise': s_sim},
             'explanation': f'Real range noise grows with range: sigma = {c[0] * 100:.1f} cm + '
             f'{c[1] * 100:.2f} cm per m (in the simulation {s_sim * 100:.1f} cm at '
             'every range).'}]


def sweep_vs_delay(beam: list, motion: list, topic: str, prm: 'LidarMismatchParams',
                   notes: list, not_judged: list) -> None:
    """
    Take the sweep's share out of a scan delay measured by the scan-to-scan motion.

    A scan swept over ``dT`` and not deskewed registers as the motion at about
    its middle, so the motion's delay holds ``-dT / 2`` of the sweep found beam
    by beam. The delay is kept only when what is left is still significant,
    its standard error widened by ``dT / 8`` (where in the sweep an undeskewed
    scan's motion sits is known to about a quarter of it).
    """
    sw = [f for f in beam if f['effect'] == 'scan_distortion']
    dl = [f for f in motion if f['effect'] == 'lidar_time_offset']
    if not sw or not dl:
        return
    d_t, f = sw[0]['parameters']['sweep_time'], dl[0]
    tau = f['parameters']['tau'] + 0.5 * d_t
    se = math.sqrt(f['std']['tau'] ** 2 + (0.5 * sw[0]['std']['sweep_time']) ** 2 +
                   (d_t / 8) ** 2)
    z = abs(tau) / max(se, 1e-9)
    motion.remove(f)
    if z < prm.z_min or abs(tau) < prm.floor_tau:
        not_judged.append({'channel': f'{topic}.stamp', 'reason': 'the scan delay seen by the '
                           f'scan-to-scan motion ({f["parameters"]["tau"] * 1000:+.0f} ms) is '
                           f'half the sweep distortion found ({d_t * 1000:+.0f} ms); beyond it '
                           f'{tau * 1000:+.0f} +- {se * 1000:.0f} ms is not significant'})
        return
    notes.append(f'{topic}: the scan delay {f["parameters"]["tau"] * 1000:+.1f} ms less half '
                 f'the sweep distortion found ({d_t * 1000:+.0f} ms)')
    f['parameters']['tau'] = float(tau)
    f['std']['tau'] = float(se)
    f['evidence']['z'] = float(z)
    f['confidence'] = _conf(z * Z_MIN / prm.z_min)
    motion.append(f)
