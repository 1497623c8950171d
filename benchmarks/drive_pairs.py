# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Sim-vs-real pairs of wheeled robots' drives from real recordings, built as a new user would.

- :func:`mrclam_pairs`: MR.CLAM (iRobot Create, velocity commands and Vicon).
  The simulation is an ideal robot executing the recorded commands (each held
  until the next one), written as ``nav_msgs/Odometry`` at 50 Hz (integrated
  pose, commanded twist); the real recording is the Vicon motion as
  ``nav_msgs/Odometry`` at 50 Hz (the pose, and the body-frame twist from a
  zero-phase derivative: a Savitzky-Golay first derivative over +-0.1 s of the
  pose resampled onto the 50 Hz grid), plus the commands themselves as
  ``geometry_msgs/Twist`` on ``/cmd_vel`` (the analyser reads the commanded
  acceleration from a command topic). Windows of 300 s.
- :func:`woods_pair`: Lost in the Woods. The simulation is the ideal odometry
  of the true motion (Vicon, central differences over +-1 sample: a box
  kernel the real channel is compared through, see :class:`Topic`); the real
  recording is the robot's measured wheel odometry, both at the data's 10 Hz.

Motion-capture gaps are cut, never bridged: a 50 Hz sample is kept only where
the nearest poses on either side are at most :data:`MAX_GAP` apart, the
derivative is taken on each stretch between gaps on its own, and its half
window at either end of a stretch is dropped. The real topic simply has no
messages there (the analyser reads a hole as missing data).

:func:`write_pair` writes a pair as two ROS 2 bags (``sim``, ``real``) with
:class:`robot_calib.io.bags.BagWriter`, for the command line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
from pathlib import Path
from typing import Optional

import numpy as np

from robot_calib.io.datasets import lost_in_woods, mrclam
from robot_calib.mismatch.channels import ODOM_TYPE, Topic, TWIST_TYPES
from scipy.signal import savgol_filter

SHARED = Path(__file__).resolve().parents[2] / 'shared' / 'data'
RATE = 50.0
"""Hz: the rate of the written odometry."""
MAX_GAP = 0.1
"""s: the longest step between motion-capture poses that is interpolated across."""
HALF = 0.1
"""s: half width of the zero-phase derivative of the motion-capture pose."""
WINDOW = 300.0
"""s: length of one pair."""
TWIST_TYPE = TWIST_TYPES[0]


@dataclass
class DrivePair:
    """
    One pair: simulated and real odometry (s, m, m, rad, m/s, rad/s) and the commands.

    ``sim`` and ``real`` are dicts with ``t``, ``x``, ``y``, ``yaw``, ``v``,
    ``w`` (equal-length arrays); ``cmd`` has ``t``, ``v``, ``w`` (or is empty).
    ``kernels`` are the simulated twist's smoothing kernels (see :class:`Topic`).
    """

    name: str
    sim: dict
    real: dict
    cmd: dict = field(default_factory=dict)
    kernels: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


def held(t_cmd: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Return the command ``x`` held from each stamp until the next (zero before the first)."""
    idx = np.searchsorted(t_cmd, t, side='right') - 1
    return np.where(idx >= 0, x[np.clip(idx, 0, None)], 0.0)


def integrate(t: np.ndarray, v: np.ndarray, w: np.ndarray, pose0: tuple) -> tuple:
    """Return x, y, yaw (m, m, rad) of a unicycle with speeds held over each step (exact arcs)."""
    dt = np.diff(t)
    dth = w[:-1] * dt
    yaw = pose0[2] + np.concatenate(([0.0], np.cumsum(dth)))
    ds = v[:-1] * dt
    half = 0.5 * dth  # chord of the arc: length 2 r sin(dth/2), heading the mid angle
    sinc = np.where(np.abs(half) > 1e-9, np.sin(half) / np.where(half == 0, 1, half), 1.0)
    mid = yaw[:-1] + half
    x = pose0[0] + np.concatenate(([0.0], np.cumsum(ds * sinc * np.cos(mid))))
    y = pose0[1] + np.concatenate(([0.0], np.cumsum(ds * sinc * np.sin(mid))))
    return x, y, yaw


def mocap_odometry(t_gt: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray,
                   t0: float, t1: float, rate: float = RATE, max_gap: float = MAX_GAP,
                   half: float = HALF) -> dict:
    """
    Return the motion capture as odometry on a ``rate`` grid over [t0, t1), gaps cut.

    Pose interpolated linearly (yaw unwrapped); the twist in the body frame
    from a zero-phase Savitzky-Golay derivative (order 2, +-``half`` s) of
    each gap-free stretch; samples within ``half`` of a stretch's ends are
    dropped (no derivative is taken across a gap).
    """
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(yaw)
    ts, xs, ys, ths = t_gt[ok], x[ok], y[ok], np.unwrap(yaw[ok])
    grid = np.arange(t0, t1, 1.0 / rate)
    out: dict = {k: [] for k in ('t', 'x', 'y', 'yaw', 'v', 'w')}
    if ts.size < 3 or grid.size == 0:
        return {k: np.zeros(0) for k in out}
    idx = np.clip(np.searchsorted(ts, grid), 1, ts.size - 1)
    inside = (grid >= ts[0]) & (grid <= ts[-1]) & (ts[idx] - ts[idx - 1] <= max_gap)
    h = max(1, int(round(half * rate)))
    edges = np.flatnonzero(np.diff(np.concatenate(([0], inside.astype(int), [0]))))
    for a, b in zip(edges[::2], edges[1::2]):
        if b - a < 2 * h + 3:
            continue
        tg = grid[a:b]
        px, py, pth = (np.interp(tg, ts, s) for s in (xs, ys, ths))
        dx, dy, dth = (savgol_filter(s, 2 * h + 1, 2, deriv=1, delta=1.0 / rate)
                       for s in (px, py, pth))
        keep = slice(h, tg.size - h)
        c, s = np.cos(pth), np.sin(pth)
        for k, arr in (('t', tg), ('x', px), ('y', py), ('yaw', pth),
                       ('v', c * dx + s * dy), ('w', dth)):
            out[k].append(arr[keep])
    return {k: np.concatenate(v) if v else np.zeros(0) for k, v in out.items()}


def mrclam_pairs(folder: Optional[Path] = None, robots: tuple = (1, 2),
                 window: float = WINDOW, rate: float = RATE) -> list[DrivePair]:
    """
    Return the MR.CLAM pairs: each robot's run cut into whole windows of ``window`` s.

    A window starts at the later of the first command and the first pose; the
    simulated robot starts where the motion capture has it at the window's
    first real sample.
    """
    folder = Path(folder or SHARED / 'mrclam')
    pairs = []
    for r in robots:
        run = mrclam.load(folder, r)
        start = max(run.t_cmd[0], run.t_gt[0])
        end = min(run.t_cmd[-1], run.t_gt[-1])
        k = 0
        while start + window <= end + 1e-9:
            t0, t1 = start, start + window
            real = mocap_odometry(run.t_gt, run.x, run.y, run.yaw, t0, t1, rate)
            t = np.arange(t0, t1, 1.0 / rate)
            v, w = held(run.t_cmd, run.v_cmd, t), held(run.t_cmd, run.w_cmd, t)
            p0 = (real['x'][0], real['y'][0], real['yaw'][0]) if real['t'].size else (0, 0, 0)
            j0 = int(np.searchsorted(t, real['t'][0])) if real['t'].size else 0
            x, y, yaw = integrate(t, v, w, (0.0, 0.0, 0.0))
            # start the ideal robot at the first real pose: shift and turn the whole path
            c, s = np.cos(p0[2] - yaw[j0]), np.sin(p0[2] - yaw[j0])
            xr, yr = x - x[j0], y - y[j0]
            x, y = p0[0] + c * xr - s * yr, p0[1] + s * xr + c * yr
            yaw = yaw + (p0[2] - yaw[j0])
            sel = (run.t_cmd >= t0) & (run.t_cmd < t1)
            cut = window - real['t'].size / rate
            pairs.append(DrivePair(
                f'{run.name}_w{k}', {'t': t, 'x': x, 'y': y, 'yaw': yaw, 'v': v, 'w': w}, real,
                {'t': run.t_cmd[sel], 'v': run.v_cmd[sel], 'w': run.w_cmd[sel]},
                notes=[f'{cut:.1f} s of the window without motion capture (cut, not bridged)']))
            start, k = t1, k + 1
    return pairs


def woods_pair(path: Optional[Path] = None, window: Optional[float] = None,
               start: float = 0.0) -> DrivePair:
    """
    Return Lost in the Woods: ideal odometry of the Vicon motion vs the measured odometry.

    ``window`` (s) cuts ``[start, start + window)``; None keeps the whole run.
    The ideal twist is a central difference over +-1 sample on each valid
    stretch (box kernel of +-1 sample period); invalid truth is cut.
    """
    run = lost_in_woods.load(path or SHARED / 'utias_lost_in_woods' / 'dataset2.mat')
    t = run.t
    sel = (t >= t[0] + start) & ((t < t[0] + start + window) if window else True)
    dt = float(np.median(np.diff(t)))
    ok = run.valid.copy()
    # a difference over +-1 sample needs both neighbours valid and evenly spaced
    good = np.zeros(t.size, bool)
    good[1:-1] = ok[:-2] & ok[2:] & ok[1:-1] & (np.abs(t[2:] - t[:-2] - 2 * dt) < 0.5 * dt)
    yaw = np.unwrap(np.where(ok, run.yaw, 0.0))
    v = np.full(t.size, np.nan)
    w = np.full(t.size, np.nan)
    rel_x = np.zeros(t.size)
    rel_y = np.zeros(t.size)
    rel_x[1:-1] = run.x[2:] - run.x[:-2]
    rel_y[1:-1] = run.y[2:] - run.y[:-2]
    span = np.ones(t.size)
    span[1:-1] = t[2:] - t[:-2]
    c, s = np.cos(yaw), np.sin(yaw)
    v[good] = ((c * rel_x + s * rel_y) / span)[good]
    dyaw = np.zeros(t.size)
    dyaw[1:-1] = np.angle(np.exp(1j * (yaw[2:] - yaw[:-2])))
    w[good] = (dyaw / span)[good]
    gs = good & sel
    sim = {'t': t[gs], 'x': run.x[gs], 'y': run.y[gs], 'yaw': run.yaw[gs], 'v': v[gs],
           'w': w[gs]}
    x, y, th = integrate(t[sel], run.v[sel], run.om[sel],
                         (run.x[sel][0], run.y[sel][0], run.yaw[sel][0]))
    real = {'t': t[sel], 'x': x, 'y': y, 'yaw': th, 'v': run.v[sel], 'w': run.om[sel]}
    box = ('box', dt)
    return DrivePair('lost_in_woods', sim, real, {},
                     {'twist.twist.linear.x': box, 'twist.twist.angular.z': box},
                     [f'{int((sel & ~good).sum())} samples without valid truth (cut)'])


def recordings(pair: DrivePair, odom: str = '/odom', cmd: str = '/cmd_vel') -> tuple:
    """Return the pair as (sim, real) ``{topic: Topic}`` dicts; the commands go with the real."""
    def topic(d: dict, kernels: dict) -> Topic:
        return Topic(odom, ODOM_TYPE, np.asarray(d['t'], float),
                     {'twist.twist.linear.x': np.asarray(d['v'], float),
                      'twist.twist.angular.z': np.asarray(d['w'], float)}, dict(kernels))

    sim = {odom: topic(pair.sim, pair.kernels)}
    real = {odom: topic(pair.real, {})}
    if pair.cmd and len(pair.cmd['t']) > 2:
        real[cmd] = Topic(cmd, TWIST_TYPE, np.asarray(pair.cmd['t'], float),
                          {'linear.x': np.asarray(pair.cmd['v'], float),
                           'angular.z': np.asarray(pair.cmd['w'], float)})
    return sim, real


def write_pair(pair: DrivePair, folder: os.PathLike, odom: str = '/odom',
               cmd: str = '/cmd_vel') -> tuple[Path, Path]:
    """
    Write ``folder/sim`` and ``folder/real`` bags (mcap); return their paths.

    Odometry in ``odom`` -> ``base_link`` with pose and twist; the commands
    as ``geometry_msgs/Twist`` on ``cmd`` in the real bag (receive time = the
    command's stamp); the simulated twist's kernels in the sim bag's metadata.
    """
    from robot_calib.core import types as T
    from robot_calib.io.bags import BagWriter
    from robot_calib.mismatch.channels import encode_kernels, KERNELS_KEY
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sim_rec, _ = recordings(pair, odom, cmd)
    paths = []
    for side, d in (('sim', pair.sim), ('real', pair.real)):
        items = []
        for i in range(len(d['t'])):
            vals = [float(d[k][i]) for k in ('t', 'x', 'y', 'yaw', 'v', 'w')]
            if not all(np.isfinite(vals)):
                continue
            ns = int(round(vals[0] * 1e9))
            items.append((ns, odom, T.OdomSample(vals[0], vals[1], vals[2], vals[3], vx=vals[4],
                                                 wz=vals[5], stamp_ns=ns)))
        if side == 'real' and pair.cmd:
            for ti, v, w in zip(pair.cmd['t'], pair.cmd['v'], pair.cmd['w']):
                ns = int(round(float(ti) * 1e9))
                items.append((ns, cmd, T.TwistSample(float(ti), float(v), wz=float(w),
                                                     stamp_ns=ns)))
        items.sort(key=lambda z: z[0])
        custom = {KERNELS_KEY: encode_kernels(sim_rec)} if side == 'sim' else None
        path = folder / side
        with BagWriter(path, custom=custom) as wr:
            for ns, name, s in items:
                wr.write(name, s, ns)
        paths.append(path)
    return paths[0], paths[1]


def main() -> None:
    """Write the MR.CLAM and Lost in the Woods pairs as bags under the given folder."""
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('out', help='output folder (one sub-folder per pair)')
    ap.add_argument('--window', type=float, default=WINDOW, help='pair length (s)')
    a = ap.parse_args()
    pairs = mrclam_pairs(window=a.window) + [woods_pair(window=a.window)]
    for p in pairs:
        s, r = write_pair(p, Path(a.out) / p.name)
        print(f'{p.name}: {s} {r} ({"; ".join(p.notes)})')


if __name__ == '__main__':
    main()
