# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Fleet benchmark (issue 17): a simulated fleet with injected drifts through ``robot-calib fleet``.

Run from the repository root: ``.venv/bin/python benchmarks/bench_fleet.py [--robots N]
[--days D] [--duration S]``. Writes ``docs/bench/12-fleet.md``.

The fleet: ``--robots`` robots, ``--days`` bags each of the ``drive`` scenario
(``--duration`` s), seeds per robot and day. Every third robot's gyro bias steps
from 0.01 to 0.04 rad/s on the last day (a drift the fusion node's gyro-bias
estimate must flag); the others keep 0.01. Scored: drifted robots flagged on
their last bag, flags on unchanged robots (false). Timed side by side in one
run: the whole fleet on 1 and on 2 worker processes (wall clock), and the
fixed cost of one bag (a 1 s bag replayed by a fresh ``robot-calib`` process).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from robot_calib import sim  # noqa: E402
from robot_calib.fleet import run_fleet  # noqa: E402

OUT = REPO / 'docs' / 'bench' / '12-fleet.md'
NODES = ['odometry_fusion']


def make_fleet(root: Path, robots: int, days: int, duration: float) -> set[str]:
    """Simulate the fleet under ``root``; return the robots given a gyro-bias step."""
    drifted = set()
    for r in range(robots):
        robot = f'robot{r:03d}'
        step = r % 3 == 0
        if step:
            drifted.add(robot)
        (root / robot).mkdir(parents=True)
        for d in range(days):
            bias = 0.04 if step and d == days - 1 else 0.01
            sim.simulate('drive', root / robot / f'day{d + 1}', seed=1000 * r + d,
                         duration=duration, overrides={'imu.gyro_bias': f'0,0,{bias}'})
    return drifted


def score(out: Path, drifted: set[str], days: int) -> tuple[int, int, list[str]]:
    """Return (drifted robots flagged on their last bag, robots falsely flagged, the false)."""
    with open(out / 'flags.csv', newline='') as f:
        flags = [r for r in csv.DictReader(f) if r['reason'].startswith('moved')]
    hit = {f['robot'] for f in flags if f['robot'] in drifted
           and Path(f['bag']).name == f'day{days}' and f['parameter'] == 'gyro_bias'}
    false = sorted({f['robot'] for f in flags if f['robot'] not in drifted})
    return len(hit), len(false), false


def fixed_cost(tmp: Path) -> float:
    """Return the wall time (s, median of 3) of a fresh process replaying a 1 s bag."""
    sim.simulate('drive', tmp / 'tiny', seed=0, duration=1.0)
    times = []
    for k in range(3):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, '-m', 'robot_calib.cli', 'replay', str(tmp / 'tiny'),
                        '--out', str(tmp / f'tiny_out{k}'), '--no-progress'], check=True,
                       capture_output=True, cwd=REPO)
        times.append(time.perf_counter() - t0)
    return sorted(times)[1]


def _ray_line(walls: dict, bags: int) -> str:
    """Return the table row of Ray's overhead against the process pool (both 2 workers)."""
    if walls['ray'] is None:
        return '| Ray (local, 2 CPUs) against the process pool | Ray not installed | <= 10 % | - |'
    extra = (walls['ray'] - walls[2]) / bags
    ratio = walls['ray'] / walls[2] - 1.0
    return (f'| Ray (local, 2 CPUs, start-up included) against the process pool, 2 workers | '
            f'{walls["ray"]:.1f} s against {walls[2]:.1f} s: {ratio * 100:+.0f} % '
            f'({extra:+.2f} s per bag) | <= 10 % per bag | '
            f'{"met" if ratio <= 0.10 else "missed"} |')


def main() -> int:
    """Build the fleet, run it on 1 and 2 workers, score the flags, write the table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('--robots', type=int, default=12)
    ap.add_argument('--days', type=int, default=4)
    ap.add_argument('--duration', type=float, default=60.0, help='seconds per bag')
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        t0 = time.perf_counter()
        drifted = make_fleet(tmp / 'fleet', args.robots, args.days, args.duration)
        sim_s = time.perf_counter() - t0
        walls = {}
        for workers in (1, 2):
            t0 = time.perf_counter()
            res = run_fleet(tmp / 'fleet', tmp / f'out{workers}', nodes=NODES, workers=workers,
                            progress=False)
            walls[workers] = time.perf_counter() - t0
        try:
            import ray  # noqa: F401 - the optional extra
            t0 = time.perf_counter()
            run_fleet(tmp / 'fleet', tmp / 'out_ray', nodes=NODES, workers=2, progress=False,
                      ray='auto')
            walls['ray'] = time.perf_counter() - t0
        except ImportError:
            walls['ray'] = None
        hit, false, names = score(tmp / 'out2', drifted, args.days)
        fixed = fixed_cost(tmp)
    bags = args.robots * args.days
    speedup = walls[1] / walls[2]
    lines = [
        '# Fleet (issue 17)', '',
        f'{args.robots} robots x {args.days} days of {args.duration:.0f}-s `drive` bags '
        f'({bags} bags, simulated in {sim_s:.0f} s), node `odometry_fusion`; every third robot '
        'has its gyro bias step 0.01 -> 0.04 rad/s on its last day. Shared 2-core machine.', '',
        '| measure | value | goal | status |', '|---|---|---|---|',
        f'| drifted robots flagged on the drifted bag | {hit} of {len(drifted)} | all | '
        f'{"met" if hit == len(drifted) else "missed"} |',
        f'| unchanged robots flagged | {false} of {args.robots - len(drifted)}'
        f'{" (" + ", ".join(names) + ")" if names else ""} | 0 | '
        f'{"met" if not false else "missed"} |',
        f'| failed bags | {res["failed"]} | 0 | {"met" if not res["failed"] else "missed"} |',
        f'| fleet wall time, 1 worker | {walls[1]:.1f} s ({walls[1] / bags:.2f} s per bag) | | |',
        f'| fleet wall time, 2 workers | {walls[2]:.1f} s | | |',
        f'| speed-up 1 -> 2 workers | {speedup:.2f}x | >= 1.8x | '
        f'{"met" if speedup >= 1.8 else "missed"} |',
        f'| fixed cost of one bag (fresh process, 1 s bag, median of 3) | {fixed:.2f} s | < 1 s | '
        f'{"met" if fixed < 1.0 else "missed"} |',
        _ray_line(walls, bags),
        '',
    ]
    text = '\n'.join(lines)
    print(text)
    OUT.write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
