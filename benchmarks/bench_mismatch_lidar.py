# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Lidar mismatch on real scans (issue 40 item 4): natural findings, injected effects, nulls, time.

Real logs (``../shared/data/carmen``): MIT CSAIL (raw odometry and scans,
cut into parts) and the Intel log (scans with corrected poses; its odometry
is the corrected pose, scans about 3 s apart). For each part: what the
scanner shows against its own odometry (delay, mounting: independent
evidence is their agreement across parts); known effects added to the real
scans (the "real" side) against the scans as logged (the "sim" side), each
found within 25 %; null pairs (fresh range noise only) with no finding; and
the time of a simulated 10-minute pair with a 360-beam lidar at 10 Hz.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_mismatch_lidar.py [--quick]``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import time

from mismatch_lidar_suite import describe  # benchmarks/: the same one-line findings
import numpy as np
from robot_calib.io.datasets import carmen
from robot_calib.mismatch import lidar as L
from robot_calib.mismatch import lidar_inject as inj

DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data' / 'carmen'
EFFECTS = [('lidar_mounting_yaw', (math.radians(0.5), math.radians(2.0)), ('yaw',)),
           ('lidar_mounting_offset', ((0.03, 0.0), (0.0, -0.10)), ('x', 'y')),
           ('lidar_time_offset', (0.02, 0.08), ('tau',)),
           ('range_scale', (0.005, 0.02), ('scale',)),
           ('range_bias', (0.01, 0.05), ('bias',)),
           ('dropout_rate', ((0.05, 3.0), (0.2, 6.0)), ('rate', 'beyond'))]


def _odom_from_poses(t: np.ndarray, poses: np.ndarray) -> tuple:
    yaw = np.unwrap(poses[:, 2])
    dx, dy = np.gradient(poses[:, 0], t), np.gradient(poses[:, 1], t)
    return t, np.cos(yaw) * dx + np.sin(yaw) * dy, np.gradient(yaw, t)


def parts() -> list:
    """Return ``[(name, scans, odom (t, vx, wz), params)]`` of the real logs."""
    out = []
    if (DATA / 'mit-csail.clf').exists():
        log = carmen.read_log(DATA / 'mit-csail.clf')
        od = log.odometry()
        odom = (np.array([o.t for o in od]), np.array([o.vx for o in od]),
                np.array([o.wz for o in od]))
        n = len(log.scans)
        for k, (a, b) in enumerate(((0, n // 2), (n // 2, n))):
            sel = (odom[0] >= log.scans[a].t - 1) & (odom[0] <= log.scans[b - 1].t + 1)
            out.append((f'mit-csail part {k + 1}', log.scans[a:b], tuple(x[sel] for x in odom),
                        L.LidarMismatchParams(max_pairs=500)))
    if (DATA / 'intel-corrected.log.gz').exists():
        log = carmen.read_log(DATA / 'intel-corrected.log.gz')
        t = log.scan_times
        out.append(('intel (corrected poses)', log.scans, _odom_from_poses(t, log.scan_poses),
                    L.LidarMismatchParams(max_pairs=900, max_gap=4.0, max_lag=0.3)))
    return out


def natural(items: list) -> None:
    print('\n## natural: each part against its own odometry\n')
    print('| part | scan delay (ms) | mounting x, y (cm) | yaw (deg) | odometry scale |')
    print('|---|---|---|---|---|')
    for name, scans, odom, prm in items:
        side = L.make_side(scans, *odom, prm)
        d = L.delay_estimate(side.motion, side.heading, prm)
        h = L.hand_eye(side.motion, side.odom, d.get('tau', 0.0), prm.blocks)
        print(f'| {name} | {d.get("tau", math.nan) * 1000:.1f} +- '
              f'{d.get("tau_std", math.nan) * 1000:.1f} | {h["x"] * 100:.1f} +- '
              f'{h["x_std"] * 100:.1f}, {h["y"] * 100:.1f} +- {h["y_std"] * 100:.1f} | '
              f'{math.degrees(h["yaw"]):.2f} +- {math.degrees(h["yaw_std"]):.2f} | '
              f'{h["scale"]:.4f} |')


CHANNEL = {'lidar_mounting_yaw': 'mounting', 'lidar_mounting_offset': 'mounting',
           'lidar_time_offset': 'stamp'}


def _refused(res: dict, effect: str) -> bool:
    """Return whether the analyser listed the effect's channel as not judged."""
    chan = CHANNEL.get(effect, 'ranges')
    return any(j['channel'].endswith(chan) or effect in j['reason'] for j in res['not_judged'])


def injected(items: list, quick: bool) -> tuple[int, int, int]:
    print('\n## injected effects (found within 25 %)\n')
    print('| part | effect | injected | found | ok | s |')
    print('|---|---|---|---|---|---|')
    good = total = refused = 0
    for name, scans, odom, prm in items:
        base = inj.inject(scans, 'noise', 0.01, seed=11)
        for effect, values, keys in EFFECTS:
            for v in values[:1] if quick else values:
                real = inj.inject(base, effect, v, seed=12)
                t = time.process_time()
                res = L.analyse_lidar({'/scan': scans}, {'/scan': real}, odom, odom, prm)
                dt = time.process_time() - t
                f = [f for f in res['findings'] if f['effect'] == effect]
                vals = v if isinstance(v, tuple) else (v,)
                ok = bool(f) and all(abs(f[0]['parameters'][k] - x) <= 0.25 * abs(x)
                                     for k, x in zip(keys, vals) if x != 0) and \
                    all(abs(f[0]['parameters'][k]) <= 0.01 for k, x in zip(keys, vals)
                        if x == 0)
                others = [g for g in res['findings'] if g['effect'] != effect]
                good += ok and not others
                total += 1
                status = 'yes' if ok and not others else 'no'
                if not f and not others and _refused(res, effect):
                    status = 'not observable (refused)'
                    refused += 1
                shown = tuple(round(x, 4) for x in vals)
                print(f'| {name} | {effect} | {shown} | {describe(res)} | {status} | {dt:.1f} |')
    return good, total, refused


def nulls(items: list) -> tuple[int, int]:
    print('\n## null pairs (fresh range noise 1 cm)\n')
    print('| part | seed | findings |')
    print('|---|---|---|')
    clean = total = 0
    for name, scans, odom, prm in items:
        for seed in (21, 22):
            real = inj.inject(scans, 'noise', 0.01, seed=seed)
            res = L.analyse_lidar({'/scan': scans}, {'/scan': real}, odom, odom, prm)
            clean += not res['findings']
            total += 1
            print(f'| {name} | {seed} | {describe(res)} |')
    return clean, total


def timing() -> float:
    run = inj.simulated_run(600.0, seed=5)
    real = inj.inject(inj.inject(run['scans'], 'noise', 0.005, seed=1), 'range_scale', 0.01)
    t = time.process_time()
    res = L.analyse_lidar({'/scan': run['scans']}, {'/scan': real}, run['odom'], run['odom'])
    dt = time.process_time() - t
    print(f'\n## time: 10-minute pair, 360 beams at 10 Hz: {dt:.1f} s CPU ({describe(res)})')
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument('--quick', action='store_true', help='one value per effect')
    a = ap.parse_args()
    items = parts()
    if not items:
        print('no shared data; nothing to do')
        return
    natural(items)
    g, n, r = injected(items, a.quick)
    c, m = nulls(items)
    dt = timing()
    print(f'\nsummary: injected found {g}/{n} ({100 * g / max(n, 1):.0f} %; not observable, '
          f'refused: {r}; missed otherwise: {n - g - r}), '
          f'null pairs clean {c}/{m}, 10-minute pair {dt:.1f} s')


if __name__ == '__main__':
    main()
