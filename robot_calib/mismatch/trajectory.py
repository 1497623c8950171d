# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Trajectories of a sim-vs-real pair (and of a corrected simulation): drift and a plot.

The pose drift over the run is what a user of a simulation feels: where the
simulated robot ends up against the real one for the same commands. Each
recording's planar odometry pose (``nav_msgs/Odometry``) is taken on the same
topic in every bag (a ground-truth one when all bags have it, else the first
common odometry topic), put on the simulation's clock (the analyser's clock
offset), and expressed relative to its own pose at the first common time, so
the tracks start together. The drift is the distance between the simulated and
the real position at each common time: its value at the end and its RMS over
the run (m), and the heading difference at the end (rad); over a long open-loop
run an early heading difference dominates it, so the RMS error of the motion
over 10 s windows (a relative pose error, each track in its own start pose) is
given too.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import numpy as np


def _is_truth(topic: str) -> bool:
    from robot_calib.sim.follow import _is_truth as truth_name
    return truth_name(topic)


def odometry_topics(path: str) -> list:
    """Return the nav_msgs/Odometry topics of a bag (with messages)."""
    from robot_calib import codec
    from robot_calib.io import bags
    odom = codec.KINDS['odom'].msgtype
    return sorted(t for t, (tp, n) in bags.list_topics([path]).items() if tp == odom and n > 2)


def poses(path: str, topic: str) -> dict:
    """Return ``t`` (s), ``x``, ``y`` (m) and unwrapped ``yaw`` (rad) of an odometry topic."""
    from robot_calib.io import bags
    rows = []
    for msg in bags.read_messages([path], topics=[topic]):
        rows += [(s.t, s.x, s.y, s.yaw) for s in msg.samples]
    a = np.array(sorted(rows), float).reshape(-1, 4)
    keep = np.concatenate(([True], np.diff(a[:, 0]) > 0)) if len(a) else np.zeros(0, bool)
    a = a[keep]
    return {'t': a[:, 0], 'x': a[:, 1], 'y': a[:, 2], 'yaw': np.unwrap(a[:, 3])}


def pick_topic(paths: list) -> Optional[str]:
    """Return the odometry topic to compare in all bags (ground truth first), or None."""
    common = None
    for p in paths:
        tops = set(odometry_topics(p))
        common = tops if common is None else common & tops
    if not common:
        return None
    truth = sorted(t for t in common if _is_truth(t))
    return truth[0] if truth else sorted(common)[0]


def _relative(tr: dict, t: np.ndarray) -> np.ndarray:
    """Return (N, 3) poses at ``t`` relative to the pose at ``t[0]`` (x, y m; yaw rad)."""
    x = np.interp(t, tr['t'], tr['x'])
    y = np.interp(t, tr['t'], tr['y'])
    yaw = np.interp(t, tr['t'], tr['yaw'])
    c, s = math.cos(yaw[0]), math.sin(yaw[0])
    dx, dy = x - x[0], y - y[0]
    return np.column_stack((c * dx + s * dy, -s * dx + c * dy, yaw - yaw[0]))


def compare(sim: str, real: str, corrected: Optional[str] = None, offset: float = 0.0,
            topic: Optional[str] = None) -> Optional[dict]:
    """
    Return the tracks and drifts of the pair (and of the corrected simulation), or None.

    :param sim: simulated bag
    :param real: real bag
    :param corrected: a simulation with the findings applied (optional)
    :param offset: clock offset (s): real time + offset = simulation time
    :param topic: the odometry topic (default: :func:`pick_topic`)
    :returns: None when the bags share no odometry topic or no common time
    """
    paths = [sim, real] + ([corrected] if corrected else [])
    topic = topic or pick_topic(paths)
    if topic is None:
        return None
    tracks = {'sim': poses(sim, topic), 'real': poses(real, topic)}
    tracks['real']['t'] = tracks['real']['t'] + offset
    if corrected:
        tracks['corrected'] = poses(corrected, topic)
    lo = max(tr['t'][0] for tr in tracks.values() if tr['t'].size)
    hi = min(tr['t'][-1] for tr in tracks.values() if tr['t'].size)
    if any(tr['t'].size < 3 for tr in tracks.values()) or hi - lo <= 0:
        return None
    ref = tracks['sim']['t']
    t = ref[(ref >= lo) & (ref <= hi)]
    if t.size < 3:
        return None
    rel = {k: _relative(tr, t) for k, tr in tracks.items()}
    out = {'topic': topic, 't': t - t[0], 'tracks': rel, 'span_s': float(t[-1] - t[0]),
           'real_path_m': float(np.sum(np.hypot(*np.diff(rel['real'][:, :2], axis=0).T)))}
    for k in [k for k in rel if k != 'real']:
        d = np.hypot(*(rel[k][:, :2] - rel['real'][:, :2]).T)
        out[f'{k}_drift'] = {'end_m': float(d[-1]), 'rms_m': float(np.sqrt(np.mean(d * d))),
                             'max_m': float(d.max()),
                             'end_heading_rad': float(rel[k][-1, 2] - rel['real'][-1, 2]),
                             f'rpe_{RPE_WINDOW:g}s_m': relative_error(t, rel[k], rel['real'])}
    return out


RPE_WINDOW = 10.0
"""Window (s) of the relative pose error: drift that does not carry an early heading error."""


def relative_error(t: np.ndarray, track: np.ndarray, ref: np.ndarray,
                   window: float = RPE_WINDOW) -> Optional[float]:
    """
    Return the RMS translation error (m) of the motion over ``window`` s, or None if too short.

    For each start time the motion of both tracks over the window is expressed in
    each one's own pose at the start (a relative pose error), so a heading
    difference gathered earlier in the run does not count.
    """
    j = np.searchsorted(t, t + window)
    ok = j < t.size
    if not np.any(ok):
        return None
    i, j = np.flatnonzero(ok), j[ok]

    def local(tr: np.ndarray) -> np.ndarray:
        c, s = np.cos(tr[i, 2]), np.sin(tr[i, 2])
        dx, dy = tr[j, 0] - tr[i, 0], tr[j, 1] - tr[i, 1]
        return np.column_stack((c * dx + s * dy, -s * dx + c * dy))
    e = np.hypot(*(local(track) - local(ref)).T)
    return float(np.sqrt(np.mean(e * e)))


def summary(cmp: Optional[dict]) -> Optional[dict]:
    """Return the JSON-able part of :func:`compare` (no arrays)."""
    if cmp is None:
        return None
    return {k: v for k, v in cmp.items() if k not in ('t', 'tracks')}


def plot(out: Path, cmp: dict, name: str = 'trajectories.png') -> str:
    """Draw the tracks (and the drift along the run) into ``out/name``; return the name."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 5), gridspec_kw={'width_ratios': [1.2, 1]})
    styles = {'real': ('black', 'real'), 'sim': ('tab:red', 'sim'),
              'corrected': ('tab:blue', 'corrected sim')}
    for k, tr in cmp['tracks'].items():
        color, label = styles[k]
        ax[0].plot(tr[:, 0], tr[:, 1], lw=1.0 if k != 'real' else 1.4, color=color, label=label)
        ax[0].plot(tr[-1, 0], tr[-1, 1], 'o', color=color, ms=4)
        if k != 'real':
            d = np.hypot(*(tr[:, :2] - cmp['tracks']['real'][:, :2]).T)
            ax[1].plot(cmp['t'], d, color=color, lw=1.0,
                       label=f'{label}: end {d[-1]:.2f} m, RMS {np.sqrt(np.mean(d * d)):.2f} m')
    ax[0].set_aspect('equal', adjustable='datalim')
    ax[0].set_xlabel('x (m), start frame')
    ax[0].set_ylabel('y (m)')
    ax[0].set_title(f'{cmp["topic"]}: tracks from a common start', fontsize=9)
    ax[0].legend(fontsize=8)
    ax[1].set_xlabel('t (s)')
    ax[1].set_ylabel('distance to the real position (m)')
    ax[1].set_title('pose drift over the run', fontsize=9)
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / name, dpi=90)
    plt.close(fig)
    return name


def markdown(traj: Optional[dict], plot_name: Optional[str]) -> list:
    """Return the report section on the trajectories (lines)."""
    if not traj:
        return []
    lines = ['## Trajectories', '',
             f'Planar pose of `{traj["topic"]}` in each recording, from a common start, over '
             f'{traj["span_s"]:.1f} s ({traj["real_path_m"]:.1f} m driven by the real robot).',
             '', f'| simulation | end drift (m) | RMS drift (m) | max drift (m) | '
             f'end heading difference (deg) | RMS error of the motion over {RPE_WINDOW:g} s (m) |',
             '|---|---|---|---|---|---|']
    for k, label in (('sim', 'as simulated'), ('corrected', 'corrected')):
        d = traj.get(f'{k}_drift')
        if d:
            rpe = d.get(f'rpe_{RPE_WINDOW:g}s_m')
            lines.append(f'| {label} | {d["end_m"]:.3f} | {d["rms_m"]:.3f} | {d["max_m"]:.3f} '
                         f'| {math.degrees(d["end_heading_rad"]):+.1f} | '
                         + (f'{rpe:.3f} |' if rpe is not None else 'n/a |'))
    lines.append('')
    if plot_name:
        lines += [f'![trajectories]({plot_name})', '']
    return lines
