# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Ideal scans (issue 40 item 2) and the simulator's lidar effects (item 3): time and accuracy.

Run from the repository root: ``python benchmarks/bench_lidar_ideal.py [--quick]``.
Prints markdown tables (docs/bench/18-lidar.md, "Simulator and ideal scans").

1. Speed: the grid ray caster on 600 s of 360 beams at 10 Hz (2.16 M rays) at the
   true laser poses of the ``drive`` scenario, in the scenario's walls rasterised
   at 5 cm; and ``robot-calib ideal --map-from-scans`` end to end on that bag.
2. Simulator vs ideal: ``drive`` scans with each effect against the ideal scans
   ray-cast in a map of the simulator's own walls (2 cm cells) and in a map
   built from the scans themselves (5 cm): median absolute and signed range
   difference and median range ratio (beams finite in both).
3. Intel Research Lab (``../shared/data/carmen``, corrected log): a map from
   the scans at the corrected poses, ideal against real ranges (map from all
   scans; map from the even scans, compared on the odd ones); and a known
   range scale of 2 % added to the scans, seen through a map built from those
   scaled scans (absorbed) and through the map of the unscaled scans (an
   independent map). Skipped when the data is absent.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import shutil
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from robot_calib.core.raycast import (grid_from_points, grid_from_segments,  # noqa: E402
                                      raycast, scan_end_points)
from robot_calib.sim import run_scenario, SCENARIOS  # noqa: E402
from robot_calib.sim.engine import BuildContext, make_params, rng_for  # noqa: E402

CARMEN = REPO.parent / 'shared' / 'data' / 'carmen' / 'intel-corrected.log.gz'


def laser_poses(res) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the nominal laser poses (world, m, m, rad) at the scan stamps of a result."""
    p = res.params
    t = res.sensors['scan_t']
    tr = res.true
    x, y = np.interp(t, tr['t'], tr['x']), np.interp(t, tr['t'], tr['y'])
    yaw = np.interp(t, tr['t'], tr['yaw'])
    c, s = np.cos(yaw), np.sin(yaw)
    li = p.lidar
    return x + c * li.x - s * li.y, y + s * li.x + c * li.y, yaw + li.yaw


def beam_angles(p) -> np.ndarray:
    """Return the lidar's beam angles (rad) of the simulator parameters."""
    from robot_calib.sim.sensors import lidar_geometry
    amin, inc, _ = lidar_geometry(p)
    return amin + inc * np.arange(p.lidar.beams)


def stats(real: np.ndarray, ideal: np.ndarray) -> dict:
    """Return the comparison figures of matched ranges (m)."""
    ok = np.isfinite(real) & np.isfinite(ideal) & (ideal > 0)
    d = real[ok] - ideal[ok]
    return {'both': float(ok.mean()), 'mad': float(np.median(np.abs(d))),
            'med': float(np.median(d)), 'ratio': float(np.median(real[ok] / ideal[ok])),
            'p90': float(np.percentile(np.abs(d), 90))}


def world_grid(name: str, duration: float, seed: int, res: float):
    """Return the scenario's walls rasterised (world frame)."""
    params = make_params(SCENARIOS[name], None)
    setup = SCENARIOS[name].build(BuildContext(params, duration, seed, rng_for(seed, 'scenario')))
    return grid_from_segments(setup.world.segments, res)


def speed(duration: float) -> None:
    """Print the ray caster's and the CLI's time on ``duration`` s of scans."""
    from robot_calib import cli
    t0 = time.perf_counter()
    res = run_scenario('drive', seed=0, duration=duration)
    t_sim = time.perf_counter() - t0
    grid = world_grid('drive', duration, 0, 0.05)
    lx, ly, lyaw = laser_poses(res)
    ang = beam_angles(res.params)
    rays = lx.size * ang.size
    t0 = time.perf_counter()
    r = raycast(grid, lx[:, None], ly[:, None], lyaw[:, None] + ang[None, :], 12.0)
    t_cast = time.perf_counter() - t0
    t0 = time.perf_counter()
    ex, ey = scan_end_points(lx, ly, lyaw, ang, res.sensors['ranges'], 0.05, 12.0)
    own = grid_from_points(ex, ey, 0.05, 2)
    t_map = time.perf_counter() - t0
    t0 = time.perf_counter()
    r2 = raycast(own, lx[:, None], ly[:, None], lyaw[:, None] + ang[None, :], 12.0)
    t_cast2 = time.perf_counter() - t0
    tmp = Path(tempfile.mkdtemp())
    try:
        from robot_calib.sim import simulate
        simulate('drive', tmp / 'bag', seed=0, duration=duration)
        t0 = time.perf_counter()
        code = cli.main(['ideal', str(tmp / 'bag'), '--out', str(tmp / 'ideal'),
                         '--map-from-scans'])
        t_cli = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f'\n### Speed ({duration:.0f} s, {lx.size} scans x {ang.size} beams = {rays} rays)\n')
    print('| step | time (s) |')
    print('|---|---|')
    print(f'| simulate (in memory, for the poses) | {t_sim:.1f} |')
    print(f'| ray cast in the walls grid (5 cm, {grid.occupied.shape[1]} x '
          f'{grid.occupied.shape[0]} cells) | {t_cast:.1f} |')
    print(f'| map from the scans (end points) | {t_map:.1f} |')
    print(f'| ray cast in the map from the scans | {t_cast2:.1f} |')
    print(f'| `robot-calib ideal --map-from-scans` end to end (read, map, cast, write; '
          f'exit {code}) | {t_cli:.1f} |')
    print(f'\nfinite: walls {np.isfinite(r).mean():.3f}, own map {np.isfinite(r2).mean():.3f}')


CASES = (
    ('noiseless, deskewed', {'lidar.noise': 0.0, 'lidar.motion_distortion': False}),
    ('noise 1 cm, deskewed', {'lidar.motion_distortion': False}),
    ('defaults (noise 1 cm, sweep 0.1 s)', {}),
    ('range_scale 0.02', {'lidar.motion_distortion': False, 'lidar.range_scale': 0.02}),
    ('range_bias 0.03 m', {'lidar.motion_distortion': False, 'lidar.range_bias': 0.03}),
    ('mounting yaw 1 deg', {'lidar.motion_distortion': False,
                            'lidar.yaw_error': math.radians(1.0)}),
    ('mounting offset x 5 cm', {'lidar.motion_distortion': False, 'lidar.x_error': 0.05}),
    ('time offset 50 ms', {'lidar.motion_distortion': False, 'lidar.time_offset': 0.05}),
    ('noise growth 0.5 %/m', {'lidar.motion_distortion': False, 'lidar.noise_growth': 0.005}),
)


def simulator(duration: float) -> None:
    """Print simulated scans with each effect against their ideal scans."""
    walls = world_grid('drive', duration, 1, 0.02)
    print(f'\n### Simulator vs ideal (`drive`, {duration:.0f} s, seed 1, 360 beams)\n')
    print('| simulated lidar | map | beams finite in both | median abs diff (m) | '
          'median diff (m) | median ratio | 90 % abs diff (m) |')
    print('|---|---|---|---|---|---|---|')
    for label, over in CASES:
        res = run_scenario('drive', seed=1, duration=duration, overrides=over)
        lx, ly, lyaw = laser_poses(res)
        ang = beam_angles(res.params)
        real = res.sensors['ranges']
        ex, ey = scan_end_points(lx, ly, lyaw, ang, real, 0.05, 12.0)
        own = grid_from_points(ex, ey, 0.05, 2)
        for name, grid in (('walls 2 cm', walls), ('own scans 5 cm', own)):
            ideal = raycast(grid, lx[:, None], ly[:, None], lyaw[:, None] + ang[None, :], 12.0)
            s = stats(real, ideal)
            print(f'| {label} | {name} | {s["both"]:.3f} | {s["mad"]:.4f} | {s["med"]:+.4f} | '
                  f'{s["ratio"]:.4f} | {s["p90"]:.3f} |')


def intel(max_scans: int | None) -> None:
    """Print the Intel log's real scans against ideal scans from maps of its scans."""
    if not CARMEN.exists():
        print('\n### Intel Research Lab: skipped (no ../shared/data/carmen)')
        return
    from robot_calib.io.datasets.carmen import read_log
    log = read_log(CARMEN, max_scans=max_scans)
    real = np.vstack([s.ranges for s in log.scans])
    ang = log.scans[0].angles()
    x, y, yaw = log.scan_poses.T
    rmax = 40.0  # beyond it the SICK's returns are sparse
    print(f'\n### Intel Research Lab (corrected poses, {real.shape[0]} scans x '
          f'{real.shape[1]} beams)\n')
    print('| map | compared on | beams finite in both | median abs diff (m) | median diff (m) | '
          'median ratio | 90 % abs diff (m) | time (s) |')
    print('|---|---|---|---|---|---|---|---|')
    even = np.arange(real.shape[0]) % 2 == 0

    def row(label, on, grid_rows, scans, test_rows, ref=None):
        t0 = time.perf_counter()
        ex, ey = scan_end_points(x[grid_rows], y[grid_rows], yaw[grid_rows], ang,
                                 scans[grid_rows], 0.01, rmax)
        grid = grid_from_points(ex, ey, 0.05, 2)
        ideal = raycast(grid, x[test_rows, None], y[test_rows, None],
                        yaw[test_rows, None] + ang[None, :], rmax)
        dt = time.perf_counter() - t0
        target = (scans if ref is None else ref)[test_rows]
        target = np.where(target < rmax, target, np.inf)
        s = stats(target, ideal)
        print(f'| {label} | {on} | {s["both"]:.3f} | {s["mad"]:.4f} | {s["med"]:+.4f} | '
              f'{s["ratio"]:.4f} | {s["p90"]:.3f} | {dt:.1f} |')

    every = np.ones(real.shape[0], dtype=bool)
    row('all scans, 5 cm', 'all scans', every, real, every)
    row('even scans, 5 cm', 'odd scans (held out)', even, real, ~even)
    scaled = real * 1.02
    row('scans x 1.02 (absorbs the scale)', 'scans x 1.02', every, scaled, every)
    row('even scans, unscaled (independent map)', 'odd scans x 1.02', even, real, ~even,
        ref=scaled)


def main() -> None:
    """Run the three parts."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--quick', action='store_true', help='60 s and 2000 Intel scans')
    args = ap.parse_args()
    speed(60.0 if args.quick else 600.0)
    simulator(60.0 if args.quick else 120.0)
    intel(2000 if args.quick else None)


if __name__ == '__main__':
    main()
