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
``docs/bench/10-reliability-memory.md``. Run from the repository root:
``.venv/bin/python benchmarks/bench_reliability.py [--hours 1 4] [--nodes ...]``.
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


def measure(hours: float, nodes: str, tmp: Path) -> dict:
    """Simulate ``hours`` of driving and replay it in a child process; return the figures."""
    bag = tmp / f'drive_{hours:g}h'
    sim = subprocess.run([sys.executable, '-m', 'robot_calib.cli', 'simulate', 'drive',
                          '--out', str(bag), '--seed', '1', '--duration', str(hours * 3600)],
                         capture_output=True, text=True)
    if sim.returncode:
        raise SystemExit(f'simulation failed: {sim.stderr.strip()}')
    size = sum(f.stat().st_size for f in bag.iterdir()) / 1e6
    t0 = time.monotonic()
    run = subprocess.run([sys.executable, '-c', CHILD, str(bag), str(tmp / 'out'), nodes],
                         capture_output=True, text=True)
    wall = time.monotonic() - t0
    if run.returncode:
        raise SystemExit(f'replay failed: {run.stderr.strip()[-500:]}')
    peak, samples = 0.0, []
    for line in run.stdout.splitlines():
        parts = line.split()
        if parts[0] == 'PEAK':
            peak = float(parts[1])
        elif parts[0] == 'RSS':
            samples.append((float(parts[1]), float(parts[2])))
    for path in (bag, tmp / 'out'):
        subprocess.run(['rm', '-rf', str(path)], check=False)
    quarter, end = _rss_at(samples, 0.25), _rss_at(samples, 0.95)
    return {'hours': hours, 'bag_mb': size, 'wall': wall, 'peak': peak,
            'at': [_rss_at(samples, f) for f in (0.25, 0.5, 0.75, 0.95)],
            'growth_per_hour': (end - quarter) / (0.7 * hours)}


def main(argv=None) -> int:
    """Run the measurement and write docs/bench/10-reliability-memory.md."""
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--hours', type=float, nargs='+', default=[1.0, 4.0])
    ap.add_argument('--nodes', default='', help='comma-separated nodes (default: all)')
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(dir=os.environ.get('TMPDIR')) as tmp:
        for hours in args.hours:
            rows.append(measure(hours, args.nodes, Path(tmp)))
            print(rows[-1], flush=True)
    nodes = args.nodes or 'all five nodes'
    lines = ['# Reliability: replay memory against recording length (issue 14)', '',
             'Script: `benchmarks/bench_reliability.py`. The `drive` scenario (seed 1: IMU, '
             f'odometry, joint states, scans) simulated for each length and replayed through '
             f'{nodes} in a fresh process; resident memory sampled every second. Goal: the '
             'peak does not grow with the length of the bag (before this work: 153 MB to 836 MB '
             'for 1 h through all nodes, about 0.7 GB per recorded hour).', '',
             '| recording | bag (MB) | replay wall (s) | RSS at 25 / 50 / 75 / 95 % (MB) | peak '
             '(MB) | growth per recorded hour, 25 % to 95 % (MB/h) |',
             '|---|---|---|---|---|---|']
    for r in rows:
        at = ' / '.join(f'{m:.0f}' for m in r['at'])
        lines.append(f'| {r["hours"]:g} h | {r["bag_mb"]:.0f} | {r["wall"]:.0f} | {at} | '
                     f'{r["peak"]:.0f} | {r["growth_per_hour"]:+.0f} |')
    if len(rows) >= 2:
        a, b = rows[0], rows[-1]
        lines += ['', f'Peak ratio {b["hours"]:g} h / {a["hours"]:g} h: '
                  f'{b["peak"] / a["peak"]:.2f} (a bound independent of length gives 1.0).']
    lines += ['', f'Machine: {platform.machine()}, Python {platform.python_version()}, '
              f'{os.cpu_count()} cores (shared).', '']
    out = REPO / 'docs' / 'bench' / '10-reliability-memory.md'
    out.write_text('\n'.join(lines))
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
