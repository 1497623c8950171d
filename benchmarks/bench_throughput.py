# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Replay throughput end to end, with its floors, and the start-up of a short replay (issue 18).

Run from the repository root: ``.venv/bin/python benchmarks/bench_throughput.py [--runs N]
[--hours H] [--only wheel|startup]``. Writes ``docs/bench/13-throughput.md`` (``--only``:
that row alone is measured and replaced, the other rows are kept).

Each figure is a whole ``robot-calib replay`` process (read, decode, the node, write
output.mcap, summary, report with plots), timed by its CPU time (user + system of
the child, so other jobs on the shared machine do not count) and its wall clock;
the median of ``--runs`` (every node on the long drive: one run; the CPU seconds of
each run are listed). Bags, simulated in the same run: a 300 s IMU-only 200 Hz bag
(tilt), a 600 s vacuum bag (gyro line), a drive of ``--hours`` (wheel calibration
alone, and every node), a 10 s drive (start-up). Floors from the
same bags: reading and decoding every message alone (in this process), and each
node's pipeline alone (``process`` + ``finish`` time that replay measures around
the node, in the summary).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import resource
import statistics
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from robot_calib.io.bags import BagWriter, read_messages  # noqa: E402
from robot_calib.sim import run_scenario, simulate  # noqa: E402

OUT = REPO / 'docs' / 'bench' / '13-throughput.md'
EXE = REPO / '.venv' / 'bin' / 'robot-calib'
WHEEL_ROW = '| wheel_odometry_calibration |'
STARTUP_ROW = '| `robot-calib replay` of a 10 s drive bag'


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def replay_runs(bag: Path, nodes: str, out: Path, runs: int) -> dict:
    """Return median CPU and wall seconds of ``runs`` fresh replays, and the last summary."""
    cpu, wall = [], []
    for k in range(runs):
        # a checkout without its own .venv (a git worktree): this interpreter, this checkout
        exe = [str(EXE)] if EXE.exists() else [sys.executable, '-m', 'robot_calib.cli']
        args = exe + ['replay', str(bag), '--out', str(out / f'r{k}'), '--no-progress']
        if nodes:
            args += ['--nodes', nodes]
        c0, w0 = _children_cpu(), time.perf_counter()
        subprocess.run(args, check=True, capture_output=True, cwd=REPO)
        cpu.append(_children_cpu() - c0)
        wall.append(time.perf_counter() - w0)
    summary = json.loads((out / f'r{runs - 1}' / 'summary.json').read_text())
    return {'cpu': statistics.median(cpu), 'wall': statistics.median(wall), 'cpus': cpu,
            'summary': summary}


def compile_package() -> None:
    """
    Byte-compile robot_calib, as installing a package does.

    This machine sets PYTHONDONTWRITEBYTECODE, so an editable checkout would
    otherwise compile every module again at each start (about 0.1 s).
    """
    subprocess.run([sys.executable, '-m', 'compileall', '-q', str(REPO / 'robot_calib')],
                   check=True)


def decode_cpu(bag: Path) -> tuple[float, int]:
    """Return the CPU seconds to read and decode every supported message of ``bag``, and n."""
    c0 = time.process_time()
    n = sum(1 for _ in read_messages([bag]))
    return time.process_time() - c0, n


def _node_seconds(summary: dict, node: str) -> float:
    t = summary['nodes'][node]['timing']
    return t['process_seconds'] + t.get('finish_seconds', 0.0)


def _inputs(summary: dict, node: str) -> int:
    return int(summary['nodes'][node]['timing']['input_messages'])


def make_bags(tmp: Path, hours: float, only_wheel: bool = False
              ) -> dict[str, tuple[Path, float]]:
    """Simulate the bags (``only_wheel``: the drive alone); return name -> (path, seconds)."""
    simulate('drive', tmp / 'drive', seed=1, duration=3600.0 * hours)
    if only_wheel:
        return {'drive': (tmp / 'drive', 3600.0 * hours)}
    imu = run_scenario('bumpy_drive', seed=1, duration=300.0,
                       overrides={'lidar.rate': 0.2}).topic('/imu')
    with BagWriter(tmp / 'imu200') as w:
        for s in imu:
            w.write('/imu', s)
    simulate('vacuum', tmp / 'vacuum', seed=1, duration=600.0)
    simulate('drive', tmp / 'ten', seed=0, duration=10.0)
    return {'imu200': (tmp / 'imu200', 300.0), 'vacuum': (tmp / 'vacuum', 600.0),
            'drive': (tmp / 'drive', 3600.0 * hours), 'ten': (tmp / 'ten', 10.0)}


def main() -> int:
    """Measure and write docs/bench/13-throughput.md."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--hours', type=float, default=1.0)
    ap.add_argument('--only', choices=('all', 'wheel', 'startup'), default='all',
                    help='wheel: measure the wheel calibration row alone and replace it; '
                         'startup: the same for the 10 s start-up row')
    args = ap.parse_args()
    compile_package()
    if args.only == 'startup':
        return startup_only(args)
    load0 = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        bags = make_bags(tmp, args.hours, args.only == 'wheel')
        cases = [('tilt_detection', 'imu200', 'tilt_detection', args.runs),
                 ('gyro_line_calibration', 'vacuum', 'gyro_line_calibration', args.runs),
                 ('wheel_odometry_calibration', 'drive', 'wheel_odometry_calibration',
                  args.runs),
                 ('every node', 'drive', '', 1)]
        if args.only == 'wheel':
            cases = cases[2:3]
        for label, bag_name, nodes, runs in cases:
            bag, seconds = bags[bag_name]
            res = replay_runs(bag, nodes, tmp / f'out_{label.replace(" ", "_")}', runs)
            dec, n_msgs = decode_cpu(bag)
            summary = res['summary']
            node_list = [nodes] if nodes else sorted(summary['nodes'])
            core = {n: _node_seconds(summary, n) for n in node_list}
            inputs = {n: _inputs(summary, n) for n in node_list}
            rows.append({'label': label, 'bag': bag_name, 'seconds': seconds, 'runs': runs,
                         'cpu': res['cpu'], 'wall': res['wall'], 'cpus': res['cpus'],
                         'messages': n_msgs,
                         'decode': dec, 'core': core, 'inputs': inputs})
        if args.only == 'wheel':
            text = replace_wheel_row(OUT.read_text(), rows[0], load0, os.getloadavg()[0])
            print(text)
            OUT.write_text(text)
            return 0
        ten = replay_runs(bags['ten'][0], '', tmp / 'out_ten', max(args.runs, 5))
    load1 = os.getloadavg()[0]
    text = render(rows, ten, load0, load1, args)
    print(text)
    OUT.write_text(text)
    return 0


def startup_only(args: argparse.Namespace) -> int:
    """Re-measure the start-up row and replace it in the existing table."""
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        simulate('drive', tmp / 'ten', seed=0, duration=10.0)
        ten = replay_runs(tmp / 'ten', '', tmp / 'out_ten', max(args.runs, 5))
    lines = OUT.read_text().split('\n')
    at = _row_index(lines, STARTUP_ROW)
    lines[at] = startup_row(ten, args)
    OUT.write_text('\n'.join(lines))
    print(lines[at])
    return 0


def _row_index(lines: list[str], prefix: str) -> int:
    """Return the index of the table row starting with ``prefix`` (SystemExit if none)."""
    at = next((i for i, line in enumerate(lines) if line.startswith(prefix)), None)
    if at is None:
        raise SystemExit(f'{OUT}: no row {prefix!r} to replace; run the whole benchmark')
    return at


def startup_row(ten: dict, args: argparse.Namespace) -> str:
    """Return the start-up table row (load average at the time of measuring included)."""
    return (f'{STARTUP_ROW}, every node, report and plots included, bytecode compiled, wall '
            f'clock (median of {max(args.runs, 5)}; load {os.getloadavg()[0]:.1f} after) | '
            f'{ten["wall"]:.2f} s (CPU {ten["cpu"]:.2f} s) | < 2 s | '
            f'{"met" if ten["wall"] < 2.0 else "missed"} |')


def _goal(row: dict) -> tuple[str, str, bool]:
    """Return (goal text, measured text, met) of a row."""
    label, cpu = row['label'], row['cpu']
    if label == 'tilt_detection':
        rate = row['inputs'][label] / cpu
        return '>= 20k msg/s', f'{rate:,.0f} msg/s', rate >= 20000
    if label == 'gyro_line_calibration':
        x = row['seconds'] / cpu
        return '>= 50x real time', f'{x:.0f}x', x >= 50
    if label == 'wheel_odometry_calibration':
        rate = row['inputs'][label] / cpu
        return '>= 10k msg/s', f'{rate:,.0f} msg/s', rate >= 10000
    x = row['seconds'] / cpu
    return '>= 30x real time', f'{x:.0f}x', x >= 30


def _row_line(row: dict) -> str:
    """Return the markdown table line of one replay row."""
    goal, measured, met = _goal(row)
    dec_rate = row['messages'] / row['decode']
    core = '; '.join(f'{n} {row["inputs"][n] / max(s, 1e-9):,.0f} msg/s '
                     f'({row["seconds"] / max(s, 1e-9):.0f}x)' for n, s in row['core'].items())
    runs = ('' if len(row['cpus']) < 2 else
            f'; runs {", ".join(f"{c:.1f}" for c in row["cpus"])}')
    return (f'| {row["label"]} | {row["bag"]} ({row["seconds"]:.0f} s, '
            f'{row["messages"]:,} msgs) | {row["cpu"]:.1f} ({row["wall"]:.1f}){runs} | '
            f'{measured} | {goal} | {"met" if met else "missed"} | '
            f'{dec_rate:,.0f} msg/s ({row["seconds"] / row["decode"]:.0f}x) | {core} |')


def replace_wheel_row(text: str, row: dict, load0: float, load1: float) -> str:
    """Return ``text`` with its wheel calibration row replaced by ``row`` (and a note)."""
    lines = text.split('\n')
    at = _row_index(lines, WHEEL_ROW)
    lines[at] = _row_line(row)
    note = (f'The wheel calibration row was measured again alone (`--only wheel`; load '
            f'average {load0:.1f} at the start, {load1:.1f} at the end); the other rows are '
            'from the run above.')
    end = next(i for i in range(at, len(lines)) if not lines[i].startswith('|'))
    if end + 1 < len(lines) and lines[end + 1].startswith('The wheel calibration row was'):
        lines[end + 1] = note
    else:
        lines[end:end] = ['', note]
    return '\n'.join(lines)


def render(rows: list, ten: dict, load0: float, load1: float, args: argparse.Namespace) -> str:
    """Return the markdown section."""
    lines = ['# Replay throughput and start-up (issue 18)', '',
             f'Generated by `benchmarks/bench_throughput.py` (`--runs {args.runs} --hours '
             f'{args.hours:g}`); load average {load0:.1f} at the start, {load1:.1f} at the end '
             '(2 shared cores). Rates are per CPU second of the whole `robot-calib replay` '
             'process (median of the runs), so other jobs on the machine do not lower them; '
             'wall times are shown beside.', '',
             '| replay | bag | CPU s (wall s) | end to end | goal | status | floor: decode alone '
             '| floor: node(s) alone |', '|---|---|---|---|---|---|---|---|']
    for row in rows:
        lines.append(_row_line(row))
    core_all = sum(rows[-1]['core'].values())
    by_node = sorted(rows[-1]['core'].items(), key=lambda kv: -kv[1])
    lines += ['', f'Every node on the {rows[-1]["seconds"] / 3600:g} h drive: '
              f'{rows[-1]["cpu"]:.0f} CPU s, of which the nodes {core_all:.0f} s '
              f'({", ".join(f"{n} {s:.0f} s" for n, s in by_node)}) '
              f'and decoding {rows[-1]["decode"]:.0f} s; the rest is writing the output and the '
              'report.', '',
              '| start-up | value | goal | status |', '|---|---|---|---|',
              startup_row(ten, args), '']
    return '\n'.join(lines)


if __name__ == '__main__':
    sys.exit(main())
