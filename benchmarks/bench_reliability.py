# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Replay memory against recording length (issue 14, item 8).

Goal: the peak memory of a replay does not grow with the length of the bag.
For each length (default 1 h and 4 h) the script simulates the ``drive``
scenario (seed 1) into a temporary folder, then replays it in a fresh process
through the chosen nodes (default: every node) while sampling that process's
resident memory every second. Reported: the peak, the resident memory at a
quarter, half, three quarters and the end of the replay, and the growth per
recorded hour between the first quarter and the end. Writes
``docs/bench/10-reliability-memory.md`` (``--out``); ``--per-node`` adds each node alone on
the first length. Run from the repository root:
``.venv/bin/python benchmarks/bench_reliability.py [--hours 1 4] [--nodes ...] [--per-node]``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import platform
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
NODES = ('tilt_detection', 'odometry_fusion', 'gyro_line_calibration',
         'loop_closure_correction', 'wheel_odometry_calibration')

CHILD = r"""
import resource, sys, threading, time
from robot_calib import replay as R
samples = []
done = threading.Event()
def watch():
    t0 = time.monotonic()
    while not done.is_set():
        with open('/proc/self/status') as f:
            for line in f:
                if line.startswith('VmRSS'):
                    samples.append((time.monotonic() - t0, int(line.split()[1]) / 1024))
        done.wait(1.0)
threading.Thread(target=watch, daemon=True).start()
nodes = sys.argv[3] or None
R.replay(sys.argv[1], sys.argv[2], nodes=nodes, progress=False)
done.set()
print('PEAK', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
for t, m in samples:
    print('RSS', t, m)
"""


def _rss_at(samples: list, fraction: float) -> float:
    """Return the resident memory (MB) sampled nearest ``fraction`` of the run."""
    end = samples[-1][0]
    return min(samples, key=lambda s: abs(s[0] - fraction * end))[1]


def simulate(hours: float, tmp: Path) -> tuple[Path, float]:
    """Simulate ``hours`` of the ``drive`` scenario into ``tmp``; return the bag and its MB."""
    bag = tmp / f'drive_{hours:g}h'
    sim = subprocess.run([sys.executable, '-m', 'robot_calib.cli', 'simulate', 'drive',
                          '--out', str(bag), '--seed', '1', '--duration', str(hours * 3600)],
                         capture_output=True, text=True)
    if sim.returncode:
        raise SystemExit(f'simulation failed: {sim.stderr.strip()}')
    return bag, sum(f.stat().st_size for f in bag.iterdir()) / 1e6


def replay_memory(bag: Path, nodes: str, tmp: Path) -> dict:
    """Replay ``bag`` through ``nodes`` ('' = all) in a child process; return the figures."""
    t0 = time.monotonic()
    run = subprocess.run([sys.executable, '-c', CHILD, str(bag), str(tmp / 'out'), nodes],
                         capture_output=True, text=True)
    wall = time.monotonic() - t0
    subprocess.run(['rm', '-rf', str(tmp / 'out')], check=False)
    if run.returncode:
        raise SystemExit(f'replay failed: {run.stderr.strip()[-500:]}')
    peak, samples = 0.0, []
    for line in run.stdout.splitlines():
        parts = line.split()
        if parts[0] == 'PEAK':
            peak = float(parts[1])
        elif parts[0] == 'RSS':
            samples.append((float(parts[1]), float(parts[2])))
    return {'wall': wall, 'peak': peak,
            'at': [_rss_at(samples, f) for f in (0.25, 0.5, 0.75, 0.95)]}


def _row(label: str, hours: float, bag_mb: float, r: dict) -> str:
    growth = (r['at'][3] - r['at'][0]) / (0.7 * hours)
    at = ' / '.join(f'{m:.0f}' for m in r['at'])
    return (f'| {label} | {bag_mb:.0f} | {r["wall"]:.0f} | {at} | {r["peak"]:.0f} | '
            f'{growth:+.0f} |')


HEADER = ['| recording | bag (MB) | replay wall (s) | RSS at 25 / 50 / 75 / 95 % (MB) | peak (MB) '
          '| growth per recorded hour, 25 % to 95 % (MB/h) |', '|---|---|---|---|---|---|']


def main(argv=None) -> int:
    """Run the measurement and write docs/bench/10-reliability-memory.md."""
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--hours', type=float, nargs='+', default=[1.0, 4.0])
    ap.add_argument('--nodes', default='', help='comma-separated nodes (default: all)')
    ap.add_argument('--per-node', action='store_true',
                    help='also replay the first length through each node alone')
    ap.add_argument('--out', default=str(REPO / 'docs' / 'bench' / '10-reliability-memory.md'))
    args = ap.parse_args(argv)
    rows, per_node = [], []
    with tempfile.TemporaryDirectory(dir=os.environ.get('TMPDIR')) as tmp:
        for hours in args.hours:
            bag, size = simulate(hours, Path(tmp))
            rows.append((hours, size, replay_memory(bag, args.nodes, Path(tmp))))
            print(rows[-1], flush=True)
            if args.per_node and hours == args.hours[0]:
                for node in NODES:
                    per_node.append((node, hours, size, replay_memory(bag, node, Path(tmp))))
                    print(per_node[-1], flush=True)
            subprocess.run(['rm', '-rf', str(bag)], check=False)
    nodes = args.nodes or 'all five nodes'
    lines = ['# Reliability: replay memory against recording length (issue 14)', '',
             'Script: `benchmarks/bench_reliability.py`. The `drive` scenario (seed 1: IMU, '
             f'odometry, joint states, scans) simulated for each length and replayed through '
             f'{nodes} in a fresh process; resident memory sampled every second. Goal: the '
             'peak does not grow with the length of the bag (before this work: 153 MB to 836 MB '
             'for 1 h through all nodes, about 0.7 GB per recorded hour).', '', *HEADER]
    lines += [_row(f'{h:g} h', h, size, r) for h, size, r in rows]
    if len(rows) >= 2:
        a, b = rows[0], rows[-1]
        lines += ['', f'Peak ratio {b[0]:g} h / {a[0]:g} h: {b[2]["peak"] / a[2]["peak"]:.2f} '
                  '(a bound independent of length gives 1.0).']
    if per_node:
        lines += ['', f'Each node alone on the {per_node[0][1]:g} h recording:', '',
                  HEADER[0].replace('recording', 'node'), HEADER[1]]
        lines += [_row(node, h, size, r) for node, h, size, r in per_node]
    lines += ['', f'Machine: {platform.machine()}, Python {platform.python_version()}, '
              f'{os.cpu_count()} cores (shared).', '']
    Path(args.out).write_text('\n'.join(lines))
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
