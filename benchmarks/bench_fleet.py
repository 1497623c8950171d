# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Fleet benchmark (issue 17): a simulated fleet with drifts, scored and timed.

Run from the repository root: ``.venv/bin/python benchmarks/bench_fleet.py [--robots N]
[--recordings K] [--duration S] [--timing-bags B] [--skip-scoring] [--skip-timing]``.
Writes ``docs/bench/12-fleet.md`` (a part skipped keeps its section from the file).

Scoring: ``robot-calib simulate fleet`` (``--robots`` x ``--recordings`` bags of
``--duration`` s, a week apart; 20 % of the robots' tyres wear 0.1 % a week, 10 %
get a 0.02 rad/s gyro z bias step on their last bag) through ``robot-calib fleet``
with the wheel calibration and the fusion on 2 workers; a drift counts as found
when its robot is flagged on the right estimate (a wheel radius for wear, the
fusion's gyro bias for the step), a flag on an unchanged robot is false.

Timing, side by side in one run on the first ``--timing-bags`` bags: the fleet on 1
and on 2 worker processes and on a local Ray with 2 CPUs; the fixed cost of a bag
in a fresh process (1 s and 10 s bags, and its parts: imports, plots) and in a
warm worker; the cluster size for 10,000 one-hour bags in 8 hours from these.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench_throughput import compile_package  # noqa: E402 - a sibling script
from robot_calib.fleet import run_fleet  # noqa: E402
from robot_calib.sim.fleet import read_truth, simulate_fleet  # noqa: E402

OUT = REPO / 'docs' / 'bench' / '12-fleet.md'
NODES = ['wheel_odometry_calibration', 'odometry_fusion']
RADII = {'left_wheel_radius', 'right_wheel_radius'}


def _load() -> str:
    with open('/proc/loadavg') as f:
        return f.read().split()[0]


def score(out: Path, truth: list[dict]) -> dict:
    """Return the drifts found and the false flags of a fleet run against the fleet's truth."""
    with open(out / 'flags.csv', newline='') as f:
        found = list(csv.DictReader(f))
    drift = {r['robot']: r['drift'] for r in truth}
    hit = {'wear': set(), 'gyro_step': set(), 'wear_yaw_rate': set()}
    other, false = [], []
    for f in found:
        kind = drift.get(f['robot'], 'unchanged')
        right = (kind == 'wear' and f['parameter'] in RADII) or \
            (kind == 'gyro_step' and f['node'] == 'odometry_fusion'
             and f['parameter'] == 'gyro_bias')
        # both radii shrink, so the odometry over-reads its turns by as much: the fusion's
        # yaw-rate scale (odometry against gyro) grows with the wear
        seen = kind == 'wear' and f['node'] == 'odometry_fusion' and \
            f['parameter'] == 'yaw_rate_scale'
        if right:
            hit[kind].add(f['robot'])
        elif seen:
            hit['wear_yaw_rate'].add(f['robot'])
        elif kind == 'unchanged':
            false.append(f)
        else:
            other.append(f)
    return {'robots': {k: sorted(r for r, d in drift.items() if d == k)
                       for k in ('wear', 'gyro_step', 'unchanged')},
            'hit': hit, 'false': false, 'other': other, 'flags': found}


def _reason_kinds(flags: list[dict]) -> str:
    kinds: dict[str, int] = {}
    for f in flags:
        key = f'{f["parameter"] or "bag"} {f["reason"].split(" ")[0]}'
        kinds[key] = kinds.get(key, 0) + 1
    return ', '.join(f'{k}: {n}' for k, n in sorted(kinds.items())) or 'none'


def scoring_section(args: argparse.Namespace, tmp: Path) -> list[str]:
    """Simulate the fleet, run it on 2 workers, score the flags; return the section's lines."""
    t0 = time.perf_counter()
    keys = [f'fleet.robots={args.robots}', f'fleet.recordings={args.recordings}']
    simulate_fleet(tmp / 'fleet', seed=1, duration=args.duration, overrides=keys, workers=2,
                   progress=False)
    sim_s = time.perf_counter() - t0
    load0 = _load()
    res = run_fleet(tmp / 'fleet', tmp / 'out', nodes=NODES, workers=2, progress=False)
    s = score(tmp / 'out', read_truth(tmp / 'fleet'))
    n_wear, n_step = len(s['robots']['wear']), len(s['robots']['gyro_step'])
    n_same = len(s['robots']['unchanged'])
    false_robots = sorted({f['robot'] for f in s['false']})
    peaks = [r['peak_rss_mb'] for r in res['rows'] if isinstance(r.get('peak_rss_mb'), float)]
    ok = [r for r in res['rows'] if r['status'] == 'ok']
    runtimes = sorted({(r['robot'], r['bag']): r['runtime_s'] for r in ok}.values())
    nbags = args.robots * args.recordings
    missed = sorted(set(s['robots']['wear']) - s['hit']['wear']) + \
        sorted(set(s['robots']['gyro_step']) - s['hit']['gyro_step'])

    def status(good: bool) -> str:
        return 'met' if good else 'missed'
    lines = [
        '## Flags against the truth', '',
        f'`robot-calib simulate fleet` (seed 1): {args.robots} robots x {args.recordings} '
        f'recordings a week apart, {args.duration:.0f}-s `drive` bags ({nbags} bags, '
        f'simulated in {sim_s:.0f} s on 2 processes); each robot with its own wheel radius, '
        'track width and gyro bias errors and a day-to-day gyro turn-on change of 0.0003 '
        'rad/s; 20 % of the robots lose 0.1 % of wheel radius a week, 10 % get a 0.02 rad/s '
        'gyro z bias step on their last bag. `robot-calib fleet --nodes '
        f'{",".join(NODES)} --workers 2`, default flag threshold 4 sigma; '
        f'{res["seconds"]:.0f} s, load {load0} at the start.', '',
        '| measure | value | goal | status |', '|---|---|---|---|',
        f'| wearing robots flagged on a wheel radius | {len(s["hit"]["wear"])} of {n_wear} | '
        f'all | {status(len(s["hit"]["wear"]) == n_wear)} |',
        "| wearing robots also flagged on the fusion's odometry yaw-rate scale (the same wear: "
        f'the odometry over-reads turns as the radii shrink) | {len(s["hit"]["wear_yaw_rate"])} '
        f'of {n_wear} | | |',
        f'| gyro-step robots flagged on the fusion gyro bias | {len(s["hit"]["gyro_step"])} of '
        f'{n_step} | all | {status(len(s["hit"]["gyro_step"]) == n_step)} |',
        f'| unchanged robots flagged | {len(false_robots)} of {n_same}'
        f'{" (" + ", ".join(false_robots) + ")" if false_robots else ""} | 0 | '
        f'{status(not false_robots)} |',
        f'| failed bags | {res["failed"]} | 0 | {status(not res["failed"])} |',
        "| replay time per bag (one worker's wall clock), median | "
        f'{statistics.median(runtimes):.2f} s | | |',
        f'| peak resident memory of a worker | {max(peaks):.0f} MB | bounded | '
        f'{status(max(peaks) < 2048)} |', '',
        f'Flags on unchanged robots by parameter and rule: {_reason_kinds(s["false"])}. '
        f'Other flags on drifting robots (not their drift): {_reason_kinds(s["other"])}.',
    ]
    if missed:
        lines += ['', f'Drifts not flagged: {", ".join(missed)}.']
    return lines


def _cold(bag: Path, tmp: Path, runs: int = 5) -> float:
    """Return the median wall time (s) of a fresh ``robot-calib replay`` of ``bag``."""
    exe = REPO / '.venv' / 'bin' / 'robot-calib'
    times = []
    for k in range(runs):
        t0 = time.perf_counter()
        subprocess.run([str(exe), 'replay', str(bag), '--out', str(tmp / f'cold{k}'),
                        '--no-progress'], check=True, capture_output=True, cwd=REPO)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _import_seconds(runs: int = 5) -> float:
    code = ('import time; t = time.perf_counter(); import robot_calib.replay; '
            'from robot_calib import methods; [methods.load(n) for n in methods.REGISTRY]; '
            'print(time.perf_counter() - t)')
    out = [float(subprocess.run([sys.executable, '-c', code], check=True, capture_output=True,
                                text=True, cwd=REPO).stdout) for _ in range(runs)]
    return statistics.median(out)


def _warm(bag: Path, tmp: Path, runs: int = 5, plots: bool = True) -> tuple[float, float]:
    """Return the median in-process replay time of ``bag`` and of its report (s)."""
    import robot_calib.replay as R
    spent = {'report': 0.0}
    original = R.write_report

    def timed(*a, **k):
        t0 = time.perf_counter()
        original(*a, **k)
        spent['report'] = time.perf_counter() - t0
    R.write_report = timed
    total, report = [], []
    try:
        for k in range(runs + 1):
            t0 = time.perf_counter()
            R.replay([bag], tmp / f'warm{k}_{plots}', progress=False, plots=plots)
            if k:
                total.append(time.perf_counter() - t0)
                report.append(spent['report'])
    finally:
        R.write_report = original
    return statistics.median(total), statistics.median(report)


def _ray_row(walls: dict, bags: int) -> str:
    if walls.get('ray') is None:
        return '| Ray (local, 2 CPUs) against the process pool | Ray not installed | <= 10 % | - |'
    ratio = walls['ray'] / walls[2] - 1.0
    return (f'| Ray (local, 2 CPUs, start-up included) against the process pool, 2 workers | '
            f'{walls["ray"]:.1f} s against {walls[2]:.1f} s: {ratio * 100:+.0f} % '
            f'({(walls["ray"] - walls[2]) / bags:+.2f} s per bag) | <= 10 % per bag | '
            f'{"met" if ratio <= 0.10 else "missed"} |\n'
            f'| Ray already running (started before the clock) against '
            f'the process pool | {walls["ray_up"]:.1f} s against {walls[2]:.1f} s: '
            f'{(walls["ray_up"] / walls[2] - 1) * 100:+.0f} % '
            f'({(walls["ray_up"] - walls[2]) / bags:+.2f} s per bag) | <= 10 % per bag | '
            f'{"met" if walls["ray_up"] / walls[2] - 1 <= 0.10 else "missed"} |')


def _fleet_walls(source: Path, tmp: Path) -> dict:
    walls = {}
    for workers in (1, 2):
        t0 = time.perf_counter()
        run_fleet(source, tmp / f'out{workers}', nodes=NODES, workers=workers, progress=False)
        walls[workers] = time.perf_counter() - t0
    try:
        import ray
    except ImportError:
        return walls
    t0 = time.perf_counter()
    run_fleet(source, tmp / 'out_ray', nodes=NODES, workers=2, progress=False, ray='auto')
    walls['ray'] = time.perf_counter() - t0
    # a cluster that is already up (as in production): Ray started before the clock
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        t0 = time.perf_counter()
        run_fleet(source, tmp / 'out_ray_up', nodes=NODES, workers=2, progress=False,
                  ray='auto')
        walls['ray_up'] = time.perf_counter() - t0
    finally:
        ray.shutdown()
    return walls


def timing_section(args: argparse.Namespace, tmp: Path) -> list[str]:
    """Time the executors and the fixed cost; return the section's lines."""
    from robot_calib import sim
    keys = [f'fleet.robots={max(1, args.timing_bags // 2)}', 'fleet.recordings=2']
    simulate_fleet(tmp / 'fleet', seed=2, duration=args.duration, overrides=keys, workers=2,
                   progress=False)
    compile_package()
    load0 = _load()
    walls = _fleet_walls(tmp / 'fleet', tmp)
    bags = 2 * max(1, args.timing_bags // 2)
    one_hour = walls[1] / bags / args.duration * 3600.0
    size_h = sum(p.stat().st_size for p in (tmp / 'fleet').rglob('*.mcap')) / bags \
        / args.duration * 3600.0 / 1e6
    sim.simulate('drive', tmp / 'tiny', seed=0, duration=1.0)
    cold1 = _cold(tmp / 'tiny', tmp)
    imports = _import_seconds()
    warm1, report1 = _warm(tmp / 'tiny', tmp)
    bare1, _ = _warm(tmp / 'tiny', tmp, plots=False)
    cores = math.ceil(10000 * one_hour / (8 * 3600.0) / 0.9)
    speedup = walls[1] / walls[2]
    return [
        '## Executors and fixed cost', '',
        f'{bags} bags of {args.duration:.0f} s (`simulate fleet`, seed 2), nodes '
        f'{", ".join(NODES)}; load {load0} at the start (a shared 2-core machine).', '',
        '| measure | value | goal | status |', '|---|---|---|---|',
        f'| fleet wall time, 1 worker | {walls[1]:.1f} s ({walls[1] / bags:.2f} s per bag) | | |',
        f'| fleet wall time, 2 workers | {walls[2]:.1f} s | | |',
        f'| speed-up 1 -> 2 workers | {speedup:.2f}x | >= 1.8x | '
        f'{"met" if speedup >= 1.8 else "missed"} |',
        _ray_row(walls, bags),
        f'| fixed cost of a bag in a warm worker (1 s bag replayed in-process, median of 5), '
        f'as the fleet runs it (no per-bag plots) | {bare1:.2f} s | < 1 s | '
        f'{"met" if bare1 < 1.0 else "missed"} |',
        f'| the same with the per-bag plots (`--bag-plots`) | {warm1:.2f} s, of which report '
        f'and plots {report1:.2f} s | < 1 s | {"met" if warm1 < 1.0 else "missed"} |',
        f'| fixed cost in a fresh process (`robot-calib replay` of a 1 s bag, median of 5) | '
        f'{cold1:.2f} s, of which imports {imports:.2f} s | < 1 s | '
        f'{"met" if cold1 < 1.0 else "missed"} |', '',
        '## Cluster size on paper', '',
        f'From the 1-worker run: {one_hour:.0f} CPU-seconds per recorded hour for these two '
        f'nodes (one core), and {size_h:.0f} MB of bag per hour (uncompressed mcap: a 360-beam '
        'lidar at 10 Hz, IMU 200 Hz, joint states and odometry). 10,000 one-hour bags in 8 '
        f'hours need {10000 * one_hour / 3600:.0f} core-hours in 8 h, so about **{cores} '
        'cores** at 90 % use (a worker per core; bags are independent, so the time scales '
        f'with 1/cores). Reading: {10000 * size_h / 1e6:.1f} TB in 8 h, about '
        f'{10000 * size_h / 8 / 3600:.0f} MB/s from shared storage for the whole cluster, '
        f'{10000 * size_h / 8 / 3600 / max(cores, 1):.1f} MB/s per core: well inside a '
        "disk's or a 10 Gbit/s link's reach, so the CPU, not I/O, bounds the job. Ray carries "
        "only each bag's path and its result rows (a few kB), so the object store and the "
        f'scheduler see {10000 / 8 / 3600:.2f} tasks/s, far below the thousands per second a '
        'Ray head schedules; the output (summary, corrected odometry) is written by each '
        'worker to the shared result folder. With all five nodes a recorded hour costs more '
        '(see the replay throughput of issue 18), and the core count scales in proportion.',
    ]


def _keep(name: str) -> list[str]:
    """Return the lines of section ``name`` of the existing table file (to keep it)."""
    if not OUT.exists():
        return []
    lines, keep = [], False
    for line in OUT.read_text().splitlines():
        if line.startswith('## '):
            keep = line[3:].strip() in name
        if keep:
            lines.append(line)
    while lines and not lines[-1].strip():
        lines.pop()   # the caller adds the blank line between sections
    return lines


def main() -> int:
    """Run the parts asked for and write docs/bench/12-fleet.md."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('--robots', type=int, default=50)
    ap.add_argument('--recordings', type=int, default=4)
    ap.add_argument('--duration', type=float, default=120.0, help='seconds per bag')
    ap.add_argument('--timing-bags', type=int, default=16)
    ap.add_argument('--skip-scoring', action='store_true')
    ap.add_argument('--skip-timing', action='store_true')
    args = ap.parse_args()
    lines = ['# Fleet (issue 17)', '']
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        if args.skip_scoring:
            lines += _keep('Flags against the truth')
        else:
            (tmp / 'score').mkdir()
            lines += scoring_section(args, tmp / 'score')
        lines.append('')
        if args.skip_timing:
            lines += _keep('Executors and fixed cost | Cluster size on paper')
        else:
            (tmp / 'time').mkdir()
            lines += timing_section(args, tmp / 'time')
    text = '\n'.join(lines).rstrip() + '\n'
    print(text)
    OUT.write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
