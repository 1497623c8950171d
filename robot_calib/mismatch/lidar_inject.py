# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Known lidar effects added to scans (tests and benchmarks), and a small simulated scan pair.

:func:`inject` returns copies of :class:`~robot_calib.core.types.ScanSample`
with one effect of the contract table added: a mounting yaw (the beams'
ranges re-cast from the scan's own returns joined into a polyline), a
mounting offset (the same, from the moved origin), a stamp delay, a range bias or scale,
range noise growing with range, dropouts beyond a range. All randomness from
a seeded generator.
"""

from __future__ import annotations

from dataclasses import replace
import math

import numpy as np
from robot_calib.core.types import ScanSample

__all__ = ['inject', 'simulated_run']


def _recast(s: ScanSample, origin: tuple, yaw: float) -> np.ndarray:
    """
    Return the scan seen from ``origin`` (m) turned by ``yaw`` (rad) in its own frame.

    The returns become a polyline (neighbours joined unless a depth edge,
    more than 0.1 m + 5 % apart); each beam is cast against it. A return
    whose neighbour on one side is not joined (a depth edge, a lost or an
    isolated return) covers half the angle to that neighbour at its own range
    (the beam's share of the angle: nearest-neighbour in angle), so a turned
    or moved beam between two unjoined returns meets the nearer one in angle
    instead of passing through a gap the original scan never showed. A
    surface the original scan did not see stays unseen (inf).
    """
    from robot_calib.sim.world import World
    r = np.array(s.ranges, float)
    a = s.angles()
    fin = np.isfinite(r)
    rz = np.where(fin, r, 0.0)
    p = np.c_[rz * np.cos(a), rz * np.sin(a)]
    join = fin[:-1] & fin[1:]
    join[join] &= np.abs(np.diff(rz)[join]) < 0.1 + 0.05 * rz[:-1][join]
    half = 0.5 * abs(float(s.angle_increment)) * 1.001
    segs = [np.hstack((p[:-1][join], p[1:][join]))]
    for side, free in ((1.0, fin & ~np.r_[join, False]), (-1.0, fin & ~np.r_[False, join])):
        e = a[free] + side * half
        q = np.c_[rz[free] * np.cos(e), rz[free] * np.sin(e)]
        segs.append(np.hstack((p[free], q)))
    seg = np.vstack(segs)
    d = 1e-3 * (seg[:, 2:] - seg[:, :2])  # a ray through a shared end point meets one of them
    w = World(segments=np.hstack((seg[:, :2] - d, seg[:, 2:] + d)))
    out = w.raycast(float(origin[0]), float(origin[1]), a + yaw)
    out[~np.isfinite(out)] = np.inf
    return out


def inject(scans: list, effect: str, value, seed: int = 0) -> list:
    """
    Return the scans with one effect added.

    :param effect: ``lidar_mounting_yaw`` (rad), ``lidar_mounting_offset`` ((x, y) m),
        ``lidar_time_offset`` (s), ``range_bias`` (m), ``range_scale``,
        ``range_noise_growth`` (s1: extra sigma per m of range), ``dropout_rate``
        ((rate, beyond m)), ``noise`` (white range noise, m: a null pair)
    """
    rng = np.random.default_rng(seed)
    out = []
    for s in scans:
        r = np.array(s.ranges, float)
        fin = np.isfinite(r)
        if effect == 'lidar_mounting_yaw':
            # the scanner turned by +yaw: a surface at base angle a is seen at beam a - yaw
            r = _recast(s, (0.0, 0.0), float(value))
        elif effect == 'lidar_mounting_offset':
            r = _recast(s, tuple(value), 0.0)
        elif effect == 'lidar_time_offset':
            out.append(replace(s, t=s.t + float(value)))
            continue
        elif effect == 'range_bias':
            r = r + float(value)
        elif effect == 'range_scale':
            r = r * (1.0 + float(value))
        elif effect == 'range_noise_growth':
            r = r + rng.normal(0.0, 1.0, r.size) * float(value) * np.nan_to_num(r, posinf=0.0)
        elif effect == 'noise':
            r = r + rng.normal(0.0, float(value), r.size)
        elif effect == 'dropout_rate':
            rate, beyond = value
            lose = fin & (r >= beyond) & (rng.random(r.size) < rate)
            r[lose] = np.inf
        else:
            raise ValueError(f'unknown lidar effect {effect!r}')
        out.append(replace(s, ranges=r))
    return out


def _world():
    from robot_calib.sim.world import World
    w = World().add_room(16.0, 12.0, -8.0, -6.0)
    for cx, cy, bw, bh in ((-3, 2, 1.0, 2.0), (3.5, -2, 2.0, 1.0), (0.5, 3.5, 1.5, 0.8),
                           (-4, -3, 0.8, 0.8), (5, 3, 1.0, 1.5)):
        w.add_box(cx, cy, bw, bh)
    return w


def simulated_run(duration: float = 120.0, rate: float = 10.0, beams: int = 360,
                  mount: tuple = (0.1, 0.0, 0.0), noise: float = 0.005, seed: int = 0,
                  turn: bool = True) -> dict:
    """
    Return a run in a room: ``scans`` (ScanSample list), ``odom`` (t, vx, wz) at 50 Hz, ``truth``.

    The robot drives a figure of eight (or straight back and forth when
    ``turn`` is False); the scanner at ``mount`` (x m, y m, yaw rad) in the
    base frame; ranges with white noise ``noise`` (m).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 0.02)
    if turn:
        vx = 0.4 + 0.1 * np.sin(2 * np.pi * t / 17.0)
        wz = 0.5 * np.sin(2 * np.pi * t / 23.0) + 0.25 * np.sin(2 * np.pi * t / 7.3)
    else:
        vx = 0.4 * np.sign(np.sin(2 * np.pi * t / 20.0))
        wz = np.zeros_like(t)
    from robot_calib.mismatch.lidar import odom_poses
    pose = odom_poses(t, vx, wz)
    pose[:, 0] -= 1.5
    pose[:, 1] -= 0.5
    ts = np.arange(0.05, duration - 0.05, 1.0 / rate)
    px, py, ph = (np.interp(ts, t, pose[:, i]) for i in range(3))
    ang = -math.pi + np.arange(beams) * (2 * math.pi / beams)
    mx, my, myaw = mount
    ox = px + np.cos(ph) * mx - np.sin(ph) * my
    oy = py + np.sin(ph) * mx + np.cos(ph) * my
    w = _world()
    rr = w.raycast(ox[:, None], oy[:, None], (ph + myaw)[:, None] + ang[None, :], 30.0)
    rr = rr + rng.normal(0.0, noise, rr.shape)
    scans = [ScanSample(t=float(ts[k]), angle_min=float(ang[0]),
                        angle_increment=float(ang[1] - ang[0]), ranges=rr[k],
                        range_min=0.05, range_max=30.0) for k in range(ts.size)]
    return {'scans': scans, 'odom': (t, vx, wz), 'truth': pose}
