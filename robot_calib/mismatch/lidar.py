# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The lidar in the mismatch analysis: the scanner as a motion sensor, and beam by beam.

(a) Motion. Consecutive scans of each recording are registered with the
project's scan matcher (:func:`robot_calib.core.scan_match.register`); each
match is the scanner's motion ``T_l`` between two scans. The odometry of the
same recording gives the base's motion ``T_b`` over the same times. With the
scanner at ``M = (p, phi)`` in the base frame, ``T_b M = M T_l``, whose
translation part is linear in ``(s cos phi, s sin phi, p_x, p_y)``
(2D hand-eye calibration with an odometry scale ``s``; Censi, Franchi,
Marchionni, Oriolo, "Simultaneous calibration of odometry and sensor
parameters", IEEE T-RO 2013, eq. 11)::

    s R(phi) t_l - (R(dtheta) - I) p = t_b

The scanner's rotation ``dtheta`` (the same for base and scanner) is taken
from the match. The scan stamps' delay ``tau`` against the odometry is the
shift that best aligns ``dtheta`` with the odometry's heading change
``theta_o(t1 - tau) - theta_o(t0 - tau)`` (with a gain for a yaw-rate scale).
The analysis runs in each recording; the real minus the simulated value is
the finding (``lidar_mounting_yaw``, ``lidar_mounting_offset``,
``lidar_time_offset``), so what the method shares in both cancels.

Separability: ``phi`` needs translation, ``p`` needs rotation (the columns of
``p`` scale with ``R(dtheta) - I``); a recording without turning gives no
offset, one without driving no yaw: the finding is refused and the motion
that would separate them named.

(b) Beams, in :mod:`.lidar_beams`.

Every finding is tested on time blocks: the estimate's spread over blocks
gives its standard error (block jackknife), and the effect fitted on two of
every three chunks must lower the residual on the third (held out).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import os
from typing import Optional

import numpy as np
from robot_calib.core.params import param

__all__ = ['LidarMismatchParams', 'ScanMotion', 'read_scans', 'scan_motion', 'hand_eye',
           'scan_delay', 'motion_findings', 'analyse_lidar', 'odom_heading']

SCAN_TYPE = 'sensor_msgs/msg/LaserScan'


@dataclass
class LidarMismatchParams:
    """Parameters of the lidar comparison (SI units)."""

    max_pairs: int = param(1200, '', 'scan pairs registered per recording (spread over it)',
                           minimum=10)
    max_points: int = param(360, '', 'points per scan given to the matcher', minimum=20)
    max_range: float = param(30.0, 'm', 'beams beyond are not used by the matcher', minimum=0.5)
    max_gap: float = param(0.5, 's', 'longest time between the two scans of a pair',
                           minimum=0.01)
    max_lag: float = param(0.3, 's', 'largest scan delay searched', minimum=0.01)
    blocks: int = param(6, '', 'time blocks for the block standard error', minimum=3)
    heldout_chunks: int = param(12, '', 'chunks of the time line; every third is held out',
                                minimum=3)
    z_min: float = param(5.0, '', 'smallest z (difference / its block standard error) of a '
                         'finding', minimum=1.0)
    min_turn: float = param(0.5, 'rad', 'summed absolute turning that makes an offset '
                            'observable', minimum=0.0)
    min_travel: float = param(2.0, 'm', 'summed travel that makes a yaw observable',
                              minimum=0.0)
    floor_yaw: float = param(0.0035, 'rad', 'smallest mounting yaw worth naming', minimum=0.0)
    floor_offset: float = param(0.015, 'm', 'smallest mounting offset worth naming',
                                minimum=0.0)
    floor_tau: float = param(0.008, 's', 'smallest scan delay worth naming', minimum=0.0)


@dataclass
class ScanMotion:
    """
    The scanner's motion between scan pairs of one recording.

    ``t0``, ``t1`` (s): the scans' stamps; ``pose`` (K, 3): the later scan's
    frame in the earlier one's (m, m, rad); ``rmse`` (m) the match residual.
    """

    t0: np.ndarray
    t1: np.ndarray
    pose: np.ndarray
    rmse: np.ndarray

    def __len__(self) -> int:
        """Return the number of registered pairs."""
        return int(self.t0.size)


def read_scans(path: os.PathLike | str) -> dict:
    """Return ``{topic: [ScanSample, ...]}`` of the LaserScan topics of a bag (time order)."""
    from robot_calib.io import bags
    out: dict = {}
    topics = [k for k, (typ, _) in bags.list_topics([path]).items() if typ == SCAN_TYPE]
    if not topics:
        return out
    for msg in bags.read_messages([path], topics):
        out.setdefault(msg.topic, []).extend(msg.samples)
    for k in out:
        out[k].sort(key=lambda s: s.t)
    return out


def scan_points(scan, max_range: float, max_points: int) -> np.ndarray:
    """Return (N, 2) points (m) of a scan's returns within ``max_range`` (``max_points``)."""
    _, r, a = scan.beams(max_range)
    if r.size > max_points:
        keep = np.linspace(0, r.size - 1, max_points).astype(int)
        r, a = r[keep], a[keep]
    return np.c_[r * np.cos(a), r * np.sin(a)]


def odom_heading(t: np.ndarray, wz: np.ndarray) -> np.ndarray:
    """Return the heading (rad) integrated from yaw rates (rad/s) by the trapezoid rule."""
    th = np.zeros(t.size)
    if t.size > 1:
        th[1:] = np.cumsum(0.5 * (wz[1:] + wz[:-1]) * np.diff(t))
    return th


def odom_poses(t: np.ndarray, vx: np.ndarray, wz: np.ndarray) -> np.ndarray:
    """Return (N, 3) planar poses (m, m, rad) integrated from speed and yaw rate."""
    th = odom_heading(t, wz)
    dt = np.diff(t, prepend=t[:1])
    vm = 0.5 * (vx + np.r_[vx[:1], vx[:-1]])
    thm = 0.5 * (th + np.r_[th[:1], th[:-1]])
    return np.c_[np.cumsum(vm * np.cos(thm) * dt), np.cumsum(vm * np.sin(thm) * dt), th]


def _pose_at(t: np.ndarray, poses: np.ndarray, q: np.ndarray) -> np.ndarray:
    return np.c_[[np.interp(q, t, poses[:, i]) for i in range(3)]].T


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return b in the frame of a, row-wise (m, m, rad)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.c_[c * dx + s * dy, -s * dx + c * dy, b[:, 2] - a[:, 2]]


def scan_motion(scans: list, prm: LidarMismatchParams,
                guess: Optional[tuple] = None) -> ScanMotion:
    """
    Register consecutive scans (``max_pairs`` spread over the recording) with the scan matcher.

    :param guess: ``(t, poses)`` of the odometry, for each match's initial guess
    """
    from robot_calib.core.scan_match import register, ScanMatchParams
    n = len(scans)
    idx = np.arange(n - 1)
    if idx.size > prm.max_pairs:
        idx = np.unique(np.linspace(0, n - 2, prm.max_pairs).astype(int))
    mp = ScanMatchParams()
    rows = []
    for k in idx:
        a, b = scans[k], scans[k + 1]
        if not 0 < b.t - a.t <= prm.max_gap:
            continue
        g = (0.0, 0.0, 0.0)
        if guess is not None:
            gt, gp = guess
            g = tuple(_between(_pose_at(gt, gp, np.array([a.t])),
                               _pose_at(gt, gp, np.array([b.t])))[0])
        res = register(scan_points(b, prm.max_range, prm.max_points),
                       scan_points(a, prm.max_range, prm.max_points), g, mp)
        if res.ok:
            rows.append((a.t, b.t, *res.pose, res.rmse))
    arr = np.array(rows, float).reshape(-1, 6)
    return ScanMotion(arr[:, 0], arr[:, 1], arr[:, 2:5], arr[:, 5])


# -- hand-eye ------------------------------------------------------------------------------
def _he_rows(m: ScanMotion, tb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the hand-eye design (2K, 4) and target (2K,) (Censi et al. 2013, eq. 11)."""
    tlx, tly, dth = m.pose[:, 0], m.pose[:, 1], m.pose[:, 2]
    c1, s = np.cos(dth) - 1.0, np.sin(dth)
    ax = np.c_[tlx, -tly, -c1, s]
    ay = np.c_[tly, tlx, -s, -c1]
    a = np.empty((2 * len(m), 4))
    a[0::2], a[1::2] = ax, ay
    y = np.empty(2 * len(m))
    y[0::2], y[1::2] = tb[:, 0], tb[:, 1]
    return a, y


def _solve(a: np.ndarray, y: np.ndarray, mask: np.ndarray) -> Optional[np.ndarray]:
    """Return the robust (Huber IRLS) least-squares solution on the rows of ``mask``."""
    if mask.sum() < 8:
        return None
    from robot_calib.mismatch.lidar_beams import huber_lstsq
    return huber_lstsq(a[mask], y[mask])


def _mount(x: np.ndarray) -> np.ndarray:
    """Return (p_x, p_y, phi, s) from the hand-eye unknowns."""
    return np.array([x[2], x[3], math.atan2(x[1], x[0]), math.hypot(x[0], x[1])])


def base_motion(m: ScanMotion, odom: tuple, tau: float = 0.0) -> np.ndarray:
    """Return the odometry's motion (K, 3) over each pair's times, read ``tau`` s earlier."""
    t, poses = odom
    return _between(_pose_at(t, poses, m.t0 - tau), _pose_at(t, poses, m.t1 - tau))


def hand_eye(m: ScanMotion, odom: tuple, tau: float = 0.0, blocks: int = 6,
             pairs: Optional[np.ndarray] = None, span: Optional[tuple] = None) -> dict:
    """
    Return the scanner mounting in one recording: ``x``, ``y`` (m), ``yaw`` (rad), ``scale``.

    With the block standard errors ``x_std``... (jackknife over ``blocks``
    time blocks), the summed turning ``turn`` (rad) and travel ``travel`` (m).
    """
    tb = base_motion(m, odom, tau)
    a, y = _he_rows(m, tb)
    use = np.ones(len(m), bool) if pairs is None else pairs
    x = _solve(a, y, np.repeat(use, 2))
    out = {'turn': float(np.abs(m.pose[use, 2]).sum()),
           'travel': float(np.hypot(m.pose[use, 0], m.pose[use, 1]).sum())}
    if x is None:
        return out
    est = _mount(x)
    blk = time_blocks(m, blocks, span)
    loo = []
    for b in range(blocks):
        xb = _solve(a, y, np.repeat(use & (blk != b), 2))
        if xb is not None:
            loo.append(_mount(xb))
    out.update(dict(zip(('x', 'y', 'yaw', 'scale'), est)))
    if len(loo) == blocks:
        out['loo'] = np.array(loo)
    if len(loo) >= 3:
        loo = np.array(loo)
        nb = len(loo)
        d = loo - loo.mean(axis=0)
        d[:, 2] = np.angle(np.exp(1j * (loo[:, 2] - est[2])))
        std = np.sqrt((nb - 1) / nb * (d ** 2).sum(axis=0))
        out.update({f'{k}_std': float(v) for k, v in zip(('x', 'y', 'yaw', 'scale'), std)})
    return out


def he_residual(m: ScanMotion, odom: tuple, mount: tuple, tau: float,
                rows: np.ndarray) -> float:
    """Return the RMS hand-eye residual (m) of ``rows`` for a mounting (x, y, yaw, scale)."""
    tb = base_motion(m, odom, tau)
    a, y = _he_rows(m, tb)
    px, py, phi, s = mount
    x = np.array([s * math.cos(phi), s * math.sin(phi), px, py])
    r = (y - a @ x).reshape(-1, 2)[rows]
    return float(np.sqrt(np.mean(r ** 2))) if r.size else float('nan')


# -- delay ---------------------------------------------------------------------------------
def _turn_residual(m: ScanMotion, th: tuple, tau: float, rows: np.ndarray) -> tuple:
    """Return (RMS, gain): scan turning minus the gain times the odometry's, ``tau`` late."""
    t, h = th
    d = np.interp(m.t1[rows] - tau, t, h) - np.interp(m.t0[rows] - tau, t, h)
    dl = m.pose[rows, 2]
    den = float(d @ d)
    g = float(d @ dl) / den if den > 0 else 1.0
    return float(np.sqrt(np.mean((dl - g * d) ** 2))), g


def scan_delay(m: ScanMotion, th: tuple, max_lag: float, rows: np.ndarray) -> float:
    """
    Return the scan stamps' delay (s) against the odometry heading ``th = (t, heading)``.

    A 2 ms grid over ``+-max_lag``, then a parabola through the best three.
    """
    grid = np.arange(-max_lag, max_lag + 1e-9, 0.002)
    cost = np.array([_turn_residual(m, th, g, rows)[0] for g in grid])
    i = int(np.argmin(cost))
    if 0 < i < grid.size - 1:
        c0, c1, c2 = cost[i - 1:i + 2]
        den = c0 - 2 * c1 + c2
        if den > 0:
            return float(grid[i] + 0.5 * (c0 - c2) / den * 0.002)
    return float(grid[i])


def _blocks(n: int, nb: int) -> np.ndarray:
    return np.minimum((np.arange(n) * nb) // max(n, 1), nb - 1)


def time_blocks(m: ScanMotion, nb: int, span: Optional[tuple] = None) -> np.ndarray:
    """Return each pair's block of ``nb`` equal time blocks over ``span`` (s; default its own)."""
    lo, hi = span if span is not None else (float(m.t0[0]), float(m.t1[-1]))
    k = np.floor((m.t0 - lo) / max(hi - lo, 1e-9) * nb).astype(int)
    return np.clip(k, 0, nb - 1)


def diff_std(a: dict, b: dict, key: str, col: Optional[int] = None) -> float:
    """
    Return the block-jackknife standard error of ``b[key] - a[key]``.

    Both recordings' estimates left out block by block on the same time
    blocks, so what the two share (the same surfaces, the same drive) cancels;
    without them, the two standard errors combined as independent.
    """
    la, lb = a.get('loo'), b.get('loo')
    if la is not None and lb is not None and len(la) == len(lb) and len(la) >= 3:
        xa = la if col is None else la[:, col]
        xb = lb if col is None else lb[:, col]
        d = np.asarray(xb - xa, float)
        if key == 'yaw':
            d = np.angle(np.exp(1j * d))
        n = d.size
        return float(np.sqrt((n - 1) / n * ((d - d.mean()) ** 2).sum()))
    return float(math.hypot(a[f'{key}_std'], b[f'{key}_std']))


def delay_estimate(m: ScanMotion, th: tuple, prm: LidarMismatchParams,
                   rows: Optional[np.ndarray] = None, span: Optional[tuple] = None) -> dict:
    """Return the scan delay ``tau`` (s), its block standard error ``tau_std`` and the turning."""
    rows = np.ones(len(m), bool) if rows is None else rows
    out = {'turn': float(np.abs(m.pose[rows, 2]).sum())}
    if rows.sum() < 10:
        return out
    out['tau'] = scan_delay(m, th, prm.max_lag, rows)
    blk = time_blocks(m, prm.blocks, span)
    loo = np.array([scan_delay(m, th, prm.max_lag, rows & (blk != b))
                    for b in range(prm.blocks) if (rows & (blk != b)).sum() >= 10])
    if loo.size == prm.blocks:
        out['loo'] = loo
    if loo.size >= 3:
        out['tau_std'] = float(np.sqrt((loo.size - 1) / loo.size *
                                       ((loo - loo.mean()) ** 2).sum()))
    return out


# -- findings ------------------------------------------------------------------------------
def _confidence(z: float, z_min: float) -> float:
    """Return a confidence in [0, 1] from a z value (0.5 at ``z_min``, 0.95 at twice it)."""
    return float(1.0 - 0.5 ** ((max(z, 0.0) / z_min) ** 2.1))


def _fit_dict(before: float, after: float, hb: float, ha: float) -> dict:
    return {'rmse_before': before, 'rmse_after': after,
            'heldout_rmse_before': hb, 'heldout_rmse_after': ha}


@dataclass
class Side:
    """One recording's scanner: its motion, odometry poses (t, poses) and heading (t, h)."""

    motion: ScanMotion
    odom: tuple
    heading: tuple


def make_side(scans: list, odom_t: np.ndarray, vx: np.ndarray, wz: np.ndarray,
              prm: LidarMismatchParams) -> Side:
    """Return a :class:`Side` from scans and the same recording's odometry twist."""
    poses = odom_poses(odom_t, vx, wz)
    m = scan_motion(scans, prm, (odom_t, poses))
    return Side(m, (odom_t, poses), (odom_t, poses[:, 2]))


def motion_findings(sim: Side, real: Side, topic: str, prm: LidarMismatchParams,
                    notes: list, not_judged: list) -> list:
    """Return the motion findings (real minus sim) of one scan topic."""
    out: list = []
    ms, mr = sim.motion, real.motion
    if len(ms) < 30 or len(mr) < 30:
        not_judged.append({'channel': f'{topic}.motion', 'reason': 'too few scan pairs '
                           f'registered (sim {len(ms)}, real {len(mr)}; the scans are too far '
                           'apart or the matcher found no structure)'})
        return out
    held = (_blocks(len(mr), prm.heldout_chunks) % 3) == 2
    window = [float(min(mr.t0[0], ms.t0[0])), float(max(mr.t1[-1], ms.t1[-1]))]
    # delay first: the mounting is then fitted on aligned odometry
    span = (window[0], window[1])
    ds = delay_estimate(ms, sim.heading, prm, span=span)
    dr = delay_estimate(mr, real.heading, prm, span=span)
    tau_s, tau_r = ds.get('tau', 0.0), dr.get('tau', 0.0)
    if min(ds['turn'], dr['turn']) < prm.min_turn:
        not_judged.append({'channel': f'{topic}.stamp', 'reason': 'the scan delay needs '
                           'turning (the recordings turn too little); drive turns that start '
                           'and stop'})
    elif 'tau_std' in ds and 'tau_std' in dr:
        f = _delay_finding(ms, mr, sim, real, ds, dr, held, topic, window, prm, notes,
                           not_judged)
        if f is not None:
            out.append(f)
    hs = hand_eye(ms, sim.odom, tau_s, prm.blocks, span=span)
    hr = hand_eye(mr, real.odom, tau_r, prm.blocks, span=span)
    out.extend(_mount_findings(ms, mr, sim, real, hs, hr, tau_s, tau_r, held, topic, window,
                               prm, notes, not_judged))
    return out


def _delay_finding(ms, mr, sim, real, ds, dr, held, topic, window, prm, notes, not_judged):
    d = dr['tau'] - ds['tau']
    se = diff_std(ds, dr, 'tau')
    z = abs(d) / max(se, 1e-6)
    if prm.z_min * se >= prm.max_lag:  # no delay within the search could be told from none
        gap = float(np.median(ms.t1 - ms.t0))
        not_judged.append({'channel': f'{topic}.stamp', 'reason': 'the scan delay is not '
                           f'observable: its standard error is {se * 1000:.0f} ms (scan pairs '
                           f'{gap:.2f} s apart), so no delay within +-{prm.max_lag * 1000:.0f} '
                           'ms could be told from none'})
        return None
    if z < prm.z_min or abs(d) < prm.floor_tau:
        if abs(d) >= prm.floor_tau:
            notes.append(f'{topic}: a scan delay of {d * 1000:+.1f} ms is not significant '
                         f'(z {z:.1f} < {prm.z_min:g})')
        return None
    fit_rows = ~held
    tau_fit = scan_delay(mr, real.heading, prm.max_lag, fit_rows) - ds['tau']
    res = [_turn_residual(mr, real.heading, ds['tau'] + x, rows)[0]
           for x in (0.0, tau_fit) for rows in (fit_rows, held)]
    if not res[3] < res[1]:
        notes.append(f'{topic}: a scan delay of {d * 1000:+.1f} ms did not improve the held-out '
                     'part and is not reported')
        return None
    return {'channel': f'{topic}.stamp', 'effect': 'lidar_time_offset',
            'parameters': {'tau': float(d)}, 'std': {'tau': float(se)}, 'window': None,
            'fit': _fit_dict(res[0], res[2], res[1], res[3]),
            'confidence': _confidence(z, prm.z_min), 'evidence': {'z': float(z)},
            'explanation': f'The real scans are stamped {d * 1000:.0f} ms '
            f'{"later" if d > 0 else "earlier"} than the motion they saw (measured against '
            'the odometry of each recording by the scan-to-scan turning); the simulation '
            'stamps its scans at the instant they see.'}


def _mount_findings(ms, mr, sim, real, hs, hr, tau_s, tau_r, held, topic, window, prm,
                    notes, not_judged):
    out = []
    need = ('yaw_std', 'x_std')
    if not all(k in hs and k in hr for k in need):
        not_judged.append({'channel': f'{topic}.mounting', 'reason': 'the scanner mounting '
                           'could not be fitted (too few registered scan pairs)'})
        return out
    fit_rows = ~held
    hr_fit = hand_eye(mr, real.odom, tau_r, prm.blocks, pairs=fit_rows)
    turned = min(hs['turn'], hr['turn']) >= prm.min_turn
    moved = min(hs['travel'], hr['travel']) >= prm.min_travel
    specs = [('lidar_mounting_yaw', ('yaw',), prm.floor_yaw, moved,
              "the scanner's yaw needs the robot to drive (translate); the recordings travel "
              f'{min(hs["travel"], hr["travel"]):.1f} m'),
             ('lidar_mounting_offset', ('x', 'y'), prm.floor_offset, turned,
              "the scanner's offset needs the robot to turn (a turn on the spot or while "
              'driving separates it from the yaw); the recordings turn '
              f'{math.degrees(min(hs["turn"], hr["turn"])):.0f} deg in all')]
    for effect, keys, floor, ok, why in specs:
        d = {k: (math.remainder(hr[k] - hs[k], 2 * math.pi) if k == 'yaw' else hr[k] - hs[k])
             for k in keys}
        se = {k: diff_std(hs, hr, k, ('x', 'y', 'yaw').index(k)) for k in keys}
        z = math.sqrt(sum((d[k] / max(se[k], 1e-9)) ** 2 for k in keys))
        size = math.sqrt(sum(d[k] ** 2 for k in keys))
        if not ok:
            if size >= floor:
                not_judged.append({'channel': f'{topic}.mounting', 'reason':
                                   f'{effect} cannot be judged: {why}'})
            continue
        if z < prm.z_min or size < floor:
            continue
        base = (hs['x'], hs['y'], hs['yaw'], hr['scale'])
        after = list(base)
        for k in keys:
            after[('x', 'y', 'yaw').index(k)] = hs[k] + (hr_fit.get(k, hr[k]) - hs[k])
        after[3] = hr_fit.get('scale', hr['scale'])
        res = [he_residual(mr, real.odom, tuple(p), tau_r, rows)
               for p in (base, after) for rows in (fit_rows, held)]
        if not res[3] < res[1]:
            notes.append(f'{topic}: a candidate {effect} did not improve the held-out part and '
                         'is not reported')
            continue
        txt = (f'The real scanner is turned {math.degrees(d["yaw"]):+.2f} deg about z from '
               'where the simulation mounts it (scan-to-scan motion against odometry).'
               if effect == 'lidar_mounting_yaw' else
               f'The real scanner sits ({d["x"] * 100:+.1f}, {d["y"] * 100:+.1f}) cm from where '
               'the simulation mounts it, in the base frame (scan-to-scan motion against '
               'odometry while turning).')
        out.append({'channel': f'{topic}.mounting', 'effect': effect,
                    'parameters': {k: float(v) for k, v in d.items()},
                    'std': {k: float(v) for k, v in se.items()}, 'window': None,
                    'fit': _fit_dict(res[0], res[2], res[1], res[3]),
                    'confidence': _confidence(z, prm.z_min),
                    'evidence': {'z': float(z)}, 'explanation': txt})
    return out


def analyse_lidar(sim_scans: dict, real_scans: dict, sim_odom: Optional[tuple],
                  real_odom: Optional[tuple], prm: Optional[LidarMismatchParams] = None
                  ) -> dict:
    """
    Compare the scans of two recordings.

    Returns ``findings``, ``not_judged``, ``notes`` and ``judged`` (the scan topics compared).

    :param sim_scans: ``{topic: [ScanSample]}`` of the simulation
    :param real_scans: the same of the real recording
    :param sim_odom: ``(t, vx, wz)`` arrays (s, m/s, rad/s) of the simulation's odometry, or None
    :param real_odom: the same of the real recording
    """
    from robot_calib.mismatch import lidar_beams as B
    prm = prm or LidarMismatchParams()
    findings, not_judged, notes, judged = [], [], [], []
    for topic in sorted(set(sim_scans) | set(real_scans)):
        if topic not in sim_scans or topic not in real_scans:
            side = 'simulated' if topic not in sim_scans else 'real'
            not_judged.append({'channel': topic, 'reason': f'scan topic missing in the {side} '
                               'recording'})
            continue
        ss, rs = sim_scans[topic], real_scans[topic]
        if len(ss) < 20 or len(rs) < 20:
            not_judged.append({'channel': topic, 'reason': f'too few scans (sim {len(ss)}, '
                               f'real {len(rs)})'})
            continue
        judged.append(topic)
        beam = B.beam_findings(ss, rs, topic, notes, not_judged, motion=real_odom,
                               min_turn=prm.min_turn)
        if sim_odom is None or real_odom is None:
            not_judged.append({'channel': f'{topic}.motion', 'reason': "the scanner's motion "
                               'is compared with odometry, which a recording lacks'})
            motion = []
        else:
            sides = [make_side(sc, *od, prm) for sc, od in ((ss, sim_odom), (rs, real_odom))]
            motion = motion_findings(sides[0], sides[1], topic, prm, notes, not_judged)
        # the beams see a moved or turned scanner more precisely than the motion does
        for eff in ('lidar_mounting_yaw', 'lidar_mounting_offset', 'lidar_time_offset'):
            bf = [f for f in beam if f['effect'] == eff]
            for f in [f for f in motion if f['effect'] == eff and bf]:
                motion.remove(f)
                notes.append(f'{topic}: the scan-to-scan motion gives {eff} {f["parameters"]}; '
                             f'the beam comparison gives {bf[0]["parameters"]} and is reported')
        B.sweep_vs_delay(beam, motion, topic, prm, notes, not_judged)
        findings.extend(beam + motion)
    return {'findings': findings, 'not_judged': not_judged, 'notes': notes, 'judged': judged}


def _odom_of(rec: dict) -> Optional[tuple]:
    """Return ``(t, vx, wz)`` of a recording's odometry (ground truth last), or None."""
    from robot_calib.mismatch.channels import ODOM_TYPE
    odoms = [tp for tp in rec.values() if tp.msgtype == ODOM_TYPE and len(tp) > 10 and
             'twist.twist.linear.x' in tp.fields]
    odoms.sort(key=lambda tp: ('truth' in tp.name, tp.name))
    if not odoms:
        return None
    o = odoms[0]
    v, w = o.fields['twist.twist.linear.x'], o.fields['twist.twist.angular.z']
    ok = np.isfinite(v) & np.isfinite(w)
    return o.t[ok], v[ok], w[ok]


def merge_into(findings: dict, sim_bag, real_bag, sim_rec: dict, real_rec: dict,
               prm: Optional[LidarMismatchParams] = None) -> None:
    """Add the lidar comparison of two bags to a findings dict (findings, verdict, not_judged)."""
    ss, rs = read_scans(sim_bag), read_scans(real_bag)
    if not ss and not rs:
        return
    res = analyse_lidar(ss, rs, _odom_of(sim_rec), _odom_of(real_rec), prm)
    t0 = float(findings.get('bag_start') or 0.0)
    for f in res['findings']:  # windows in seconds from the bag start (contract)
        if f.get('window'):
            f['window'] = [f['window'][0] - t0, f['window'][1] - t0]
    findings['findings'].extend(res['findings'])
    findings.setdefault('not_judged', []).extend(res['not_judged'])
    findings.setdefault('notes', []).extend(res['notes'])
    findings['lidar'] = {'judged': res['judged']}
    findings['verdict'] = 'mismatch' if findings['findings'] else 'consistent'
