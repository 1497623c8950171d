# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Benchmark of the loop-closure heading correction (seed 001).

1. Simulated ``revisit`` scenario (three rooms and a corridor, gyro bias and
   bias drift, wheel slip), seeds 0..N-1: heading RMSE against the simulator's
   ground truth (every published pose at the odometry rate, truth
   interpolated, no alignment: both start at heading 0) of the raw gyro
   (integrated, no correction), the seed-faithful mode, the default
   (improved) mode and the global pose-graph optimisation baseline (same
   keyframes and closures, scipy least squares after each closure). A closure
   is *false* when the pose it sets is more than 0.5 m or 3 deg from the
   truth. Closure latency: wall time of each attempt (and its CPU thread
   time, since the machine is shared) over all seeds. Speed-up: the global
   optimisation's last solve (end of the run, the largest graph) against the
   median closure latency of the default mode in the same run.
2. Real ``mit-csail.clf`` (raw odometry, no IMU: heading from the odometry
   yaw): closures accepted and refused (by reason), corrections, latency.

Stops starting new seeds after ``--budget`` seconds and says how many ran.
Writes ``docs/bench/6-loop-closure.md``. Exit 0 (with a message) when
``../shared/data`` is absent (the simulated part needs no data, the real part
does; both are skipped then only for the real part).

Run from the repository root: ``.venv/bin/python benchmarks/bench_loop_closure.py``.
"""

import argparse
from collections import Counter
import json
import math
from pathlib import Path
import sys
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / 'shared' / 'data'
OUT = REPO / 'docs' / 'bench' / '6-loop-closure.md'


def _messages(result):
    out = []
    for topic, s in result.messages:
        key = topic.lstrip('/')
        if key == 'tf_static':
            for tf in (s if isinstance(s, list) else [s]):
                out.append((key, tf))
        elif key in ('imu', 'odom', 'scan'):
            out.append((key, s))
    return out


def _truth(result, se2_between):
    gt = [s for topic, s in result.messages if topic.lstrip('/') == 'ground_truth/odom']
    start = np.array([gt[0].x, gt[0].y, gt[0].yaw])
    rel = np.array([se2_between(start, [s.x, s.y, s.yaw]) for s in gt])
    return np.array([s.t for s in gt]), rel


def _raw_heading(msgs):
    t, yaw, last = [], [], None
    th = 0.0
    for key, s in msgs:
        if key != 'imu':
            continue
        if last is not None:
            th += 0.5 * (last[1] + s.gyro[2]) * (s.t - last[0])
        last = (s.t, float(s.gyro[2]))
        t.append(s.t)
        yaw.append(th)
    return np.array(t), np.array(yaw)


def _run_pipeline(msgs, pipeline_cls, params, core=None):
    pipe = pipeline_cls(params)
    if core is not None:
        pipe.estimator = core
    ts, poses = [], []
    start = time.perf_counter()
    for key, s in msgs:
        for out_key, out in pipe.process(key, s):
            if out_key == 'odom':
                ts.append(out.t)
                poses.append((out.x, out.y, out.yaw))
    return pipe, np.array(ts), np.array(poses), time.perf_counter() - start


def _false_closures(reports, tg, truth, wrap_angle):
    n = 0
    for r in reports:
        if not r.accepted:
            continue
        i = min(np.searchsorted(tg, r.t), len(tg) - 1)
        d = r.pose_after - truth[i]
        if math.hypot(d[0], d[1]) > 0.5 or abs(wrap_angle(d[2])) > math.radians(3.0):
            n += 1
    return n


def simulated(args, out_lines):
    """Run the simulated part; append markdown to ``out_lines``; return the goal rows."""
    from robot_calib.core.geometry import se2_between, wrap_angle
    from robot_calib.methods.loop_closure_correction.params import LoopClosureParams
    from robot_calib.methods.loop_closure_correction.pipeline import LoopClosurePipeline
    from robot_calib.methods.loop_closure_correction.pose_graph import (  # noqa: F401
        GraphCorrector, optimise)
    from robot_calib.methods.loop_closure_correction.report import heading_rmse
    from robot_calib.sim import run_scenario

    rows, lat, cpu, ratios = [], [], [], []
    false_total = {'seed': 0, 'improved': 0, 'global': 0}
    start = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        if time.perf_counter() - start > args.budget:
            break
        res = run_scenario('revisit', seed=seed, duration=args.duration)
        msgs = _messages(res)
        tg, truth = _truth(res, se2_between)
        t_raw, y_raw = _raw_heading(msgs)
        row = {'n': seed, 'raw': heading_rmse(t_raw, y_raw, tg, truth[:, 2]),
               'bias': res.truth.get('gyro_bias_z', float('nan'))}
        for name in ('seed', 'improved', 'global'):
            params = LoopClosureParams(mode='seed' if name == 'seed' else 'improved')
            core = GraphCorrector(params) if name == 'global' else None
            pipe, ts, poses, wall = _run_pipeline(msgs, LoopClosurePipeline, params, core)
            row[name] = heading_rmse(ts, poses[:, 2], tg, truth[:, 2])
            result = pipe.estimator.result()
            reports = result.closures
            false_total[name] += _false_closures(reports, tg, truth, wrap_angle)
            row[name + '_acc'] = sum(r.accepted for r in reports)
            row[name + '_wall'] = wall
            if name == 'improved':
                done = [r for r in reports if r.reason != 'kidnap_suspected']
                lat += [r.latency_ms for r in done]
                cpu += [r.cpu_ms for r in done]
                row['lat_med'] = float(np.median([r.latency_ms for r in done])) if done \
                    else float('nan')
                row['cpu_med'] = float(np.median([r.cpu_ms for r in done])) if done \
                    else float('nan')
                row['refused'] = dict(Counter(r.reason for r in reports if not r.accepted))
                row['est_bias'] = result.gyro_bias
                row['mem'] = result.keyframe_memory_bytes
                row['kf'] = result.keyframes
            if name == 'global':
                graph = pipe.estimator
                row['graph_last_ms'] = 1000 * graph.graph_seconds[-1] \
                    if graph.graph_seconds else float('nan')
                row['graph_last_cpu_ms'] = 1000 * graph.graph_cpu_seconds[-1] \
                    if graph.graph_cpu_seconds else float('nan')
                row['graph_nodes'] = graph.graph_nodes()
        row['ratio'] = row['graph_last_ms'] / row['lat_med']
        row['ratio_cpu'] = row['graph_last_cpu_ms'] / row['cpu_med']
        ratios.append(min(row['ratio'], row['ratio_cpu']))
        rows.append(row)
        if args.json:   # saved after every seed, so a cut run still leaves its results
            Path(args.json).write_text(json.dumps(
                {'rows': rows, 'lat': lat, 'cpu': cpu, 'ratios': ratios, 'false': false_total,
                 'duration': args.duration, 'requested': args.seeds, 'budget': args.budget}))
        print(f'seed {seed}: heading RMSE deg raw {math.degrees(row["raw"]):.2f} seed '
              f'{math.degrees(row["seed"]):.3f} improved {math.degrees(row["improved"]):.3f} '
              f'global {math.degrees(row["global"]):.3f}; closures {row["improved_acc"]}; '
              f'bias {row["bias"]:.5f} est {row["est_bias"]:.5f}; latency median '
              f'{row["lat_med"]:.1f} ms; last global solve {row["graph_last_ms"]:.0f} ms '
              f'({row["graph_nodes"]} nodes), x{row["ratio"]:.1f} wall, '
              f'x{row["ratio_cpu"]:.1f} cpu; '
              f'refused {dict(row["refused"])}',
              flush=True)
    data = {'rows': rows, 'lat': lat, 'cpu': cpu, 'ratios': ratios, 'false': false_total,
            'duration': args.duration, 'requested': args.seeds, 'budget': args.budget}
    return render_simulated(data, out_lines)


def render_simulated(data, out_lines):
    """Append the simulated tables to ``out_lines``; return the goal rows."""
    rows, lat, cpu = data['rows'], data['lat'], data['cpu']
    false_total = data['false']
    if not rows:
        return []
    deg = {k: np.degrees([r[k] for r in rows]) for k in ('raw', 'seed', 'improved', 'global')}
    p95_wall = float(np.percentile(lat, 95))
    p95_cpu = float(np.percentile(cpu, 95))
    out_lines += [
        f'## Simulated `revisit`: {len(rows)} seeds of {data["duration"]:.0f} s '
        f'(seeds {", ".join(str(r["n"]) for r in rows)}'
        + (f'; {data["requested"]} requested: the rest did not fit the time available on the '
           'shared machine)' if len(rows) < data['requested'] else ')'),
        '',
        'Heading RMSE (deg) per seed, against ground truth at every published pose. The true '
        'gyro bias column is the turn-on value; the scenario adds a drift of 4e-6 rad/s^2 '
        '(+0.0024 rad/s by 600 s), and the learned bias is the filter’s value at the end.',
        '',
        '| seed | true gyro bias (rad/s) | learned bias | raw gyro | seed-faithful | '
        'default (improved) | global optimisation | closures (default) | refusals |',
        '|---|---|---|---|---|---|---|---|---|',
    ]
    for r in rows:
        out_lines.append(
            f'| {r["n"]} | {r["bias"]:.5f} | {r["est_bias"]:.5f} | '
            f'{math.degrees(r["raw"]):.2f} | {math.degrees(r["seed"]):.3f} | '
            f'{math.degrees(r["improved"]):.3f} | {math.degrees(r["global"]):.3f} | '
            f'{r["improved_acc"]} | '
            f'{", ".join(f"{k} {v}" for k, v in sorted(r["refused"].items())) or "-"} |')
    out_lines += [
        '',
        '| method | mean heading RMSE (deg) | median | max | false closures accepted |',
        '|---|---|---|---|---|',
    ]
    for k, label in (('raw', 'raw gyro'), ('seed', 'seed-faithful'),
                     ('improved', 'default (improved)'), ('global', 'global optimisation')):
        fc = false_total.get(k, '-') if k != 'raw' else '-'
        out_lines.append(f'| {label} | {deg[k].mean():.3f} | {np.median(deg[k]):.3f} | '
                         f'{deg[k].max():.3f} | {fc} |')
    mem = max(r['mem'] for r in rows)
    out_lines += [
        '',
        f'Closure latency (default mode, {len(lat)} attempts over all seeds): median '
        f'{np.median(lat):.1f} ms wall / {np.median(cpu):.1f} ms CPU, p95 {p95_wall:.1f} ms '
        f'wall / {p95_cpu:.1f} ms CPU. Global optimisation, last solve of each run: median '
        f'{np.median([r["graph_last_ms"] for r in rows]):.0f} ms wall / '
        f'{np.median([r["graph_last_cpu_ms"] for r in rows]):.0f} ms CPU over about '
        f'{int(np.median([r["graph_nodes"] for r in rows]))} nodes (keyframes and closure '
        f'frames); ratio to the default mode’s median closure latency in the same run: see '
        f'the goals (wall-clock ratios swing with the machine’s load, CPU ratios do not). '
        f'Keyframe memory at the end: at most {mem / 1e3:.0f} kB.',
        '',
        'A closure makes the heading agree with the keyframe it matched, and a keyframe keeps '
        'the heading error it was stored with on the first lap, so the first lap’s dead '
        'reckoning sets the level a seed stays at. The default mode’s gyro filter learns the '
        'bias, its drift rate and the gyro scale error from the registrations against the last '
        'keyframe (issue 18): the earlier bias-only filter lagged the scenario’s drift of 4e-6 '
        'rad/s^2 by about 5e-4 rad/s (its time constant, about 120 s, times the drift), which '
        'put seed 11 at 0.416 deg and seed 17 at 0.321 deg. The scale (0.003 here) is learned '
        'only from scans taken while turning slower than `bias_max_rate` and stays loosely '
        'known (sigma about 0.006 after 600 s); taking scans of faster turns too '
        '(`bias_max_rate` 1 rad/s) put seeds 5, 11 and 17 at 0.40-0.51 deg. A 1-D heading '
        'smoother over the keyframes (headings and bias history, re-solved after each closure) '
        'was tried and not adopted: mean 0.204 deg, worst seed 0.326 deg.',
        '',
    ]
    mean_imp = float(deg['improved'].mean())
    rw = [r['ratio'] for r in rows]
    rc = [r['ratio_cpu'] for r in rows]

    def met(ok):
        return 'met' if ok else 'missed'
    over = [(r['n'], math.degrees(r['improved']), math.degrees(r['global'])) for r in rows
            if math.degrees(r['improved']) > 0.3]
    return [('heading RMSE <= 0.3 deg (default mode, mean over seeds)', f'{mean_imp:.3f} deg',
             met(mean_imp <= 0.3)),
            ('heading RMSE <= 0.3 deg (default mode, every seed)',
             f'{len(rows) - len(over)} of {len(rows)} seeds'
             + ''.join(f'; seed {n}: {a:.3f} deg (global optimisation {g:.3f})'
                       for n, a, g in over), met(not over)),
            ('zero accepted false closures (default mode, all seeds)',
             str(false_total['improved']), met(false_total['improved'] == 0)),
            ('closure latency p95 <= 30 ms', f'{p95_wall:.1f} ms wall, {p95_cpu:.1f} ms CPU',
             f'{met(p95_wall <= 30.0)} on wall clock, {met(p95_cpu <= 30.0)} on CPU time'),
            ('>= 10x faster than the global optimisation at the end of the run',
             f'wall x{np.median(rw):.1f} median (worst x{min(rw):.1f}); CPU '
             f'x{np.median(rc):.1f} median (worst x{min(rc):.1f})',
             f'{met(min(rw) >= 10.0)} on wall clock, {met(min(rc) >= 10.0)} on CPU time')]


def mit_csail(out_lines):
    """Run the real part on mit-csail.clf; append markdown."""
    from robot_calib.io.datasets import carmen
    from robot_calib.methods.loop_closure_correction.params import LoopClosureParams
    from robot_calib.methods.loop_closure_correction.pipeline import LoopClosurePipeline

    path = DATA / 'carmen' / 'mit-csail.clf'
    log = carmen.read_log(path)
    msgs = list(log.messages())
    out_lines += ['## Real: `mit-csail.clf` (raw odometry, no IMU)', '',
                  '| mode | closures accepted | refused (by reason) | kidnaps declared | '
                  'sum of heading corrections (deg) | largest position correction (m) | '
                  'latency median / p95 (ms wall) | CPU p95 (ms) | run time (s) |',
                  '|---|---|---|---|---|---|---|---|---|']
    for mode in ('improved', 'seed'):
        pipe, ts, poses, wall = _run_pipeline(msgs, LoopClosurePipeline,
                                              LoopClosureParams(mode=mode))
        result = pipe.estimator.result()
        reps = result.closures
        acc = [r for r in reps if r.accepted]
        refused = Counter(r.reason for r in reps if not r.accepted and
                          r.reason != 'kidnap_suspected')
        lat = [r.latency_ms for r in reps if r.reason != 'kidnap_suspected']
        cpu = [r.cpu_ms for r in reps if r.reason != 'kidnap_suspected']
        corr = sum(abs(r.correction[2]) for r in acc)
        pos = max((math.hypot(*r.correction[:2]) for r in acc), default=0.0)
        out_lines.append(
            f'| {mode} | {len(acc)} | {", ".join(f"{k} {v}" for k, v in refused.items())} | '
            f'{result.counts.get("kidnaps", 0)} | {math.degrees(corr):.1f} | {pos:.2f} | '
            f'{np.median(lat):.1f} / {np.percentile(lat, 95):.1f} | '
            f'{np.percentile(cpu, 95):.1f} | {wall:.1f} |')
        print(out_lines[-1], flush=True)
    out_lines += [
        '',
        'No ground truth here, so closures cannot be scored; the table shows what the '
        'method does on real raw data. The log has no IMU, so the heading comes from the raw '
        'wheel odometry, whose rotation is about 9 % short of what scan matching measures: '
        'between revisits of this 374 m route the heading drifts by tens of degrees, beyond '
        'the similarity check (a yaw search of at most +-30 deg around the prediction and a '
        '0.3 m gate), so most attempts end as `no_similar_keyframe` and few closures are '
        'made. No kidnap is declared on this real log (the local check tells a low-overlap '
        'view on the predicted pose from a changed view of a standing robot). The method is '
        'built for a gyro heading, which this log lacks.',
        '',
    ]


def main() -> int:
    """Run the benchmark, print and write the tables."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--seeds', type=int, default=20)
    ap.add_argument('--duration', type=float, default=600.0,
                    help='simulated seconds per seed (the scenario default: 600)')
    ap.add_argument('--budget', type=float, default=420.0,
                    help='seconds after which no new seed is started')
    ap.add_argument('--no-real', action='store_true', help='skip mit-csail.clf')
    ap.add_argument('--out', default=str(OUT), help='markdown file to write')
    ap.add_argument('--first-seed', type=int, default=0)
    ap.add_argument('--json', default='', help='also save the raw simulated results here')
    ap.add_argument('--merge', nargs='*', default=[],
                    help='render saved --json results (of runs over other seeds) instead '
                         'of simulating')
    ap.add_argument('--concurrent', action='store_true',
                    help='with --merge: the runs merged ran at the same time')
    args = ap.parse_args()
    out = Path(args.out)
    sys.path.insert(0, str(REPO))
    lines = ['# 6 — Loop-closure heading correction (seed 001)', '']
    if args.merge:
        parts = [json.loads(Path(f).read_text()) for f in args.merge]
        data = {'rows': [], 'lat': [], 'cpu': [], 'ratios': [],
                'false': {'seed': 0, 'improved': 0, 'global': 0},
                'duration': parts[0]['duration'], 'requested': args.seeds,
                'budget': parts[0]['budget']}
        for part in parts:
            for key in ('rows', 'lat', 'cpu', 'ratios'):
                data[key] += part[key]
            for key in data['false']:
                data['false'][key] += part['false'][key]
        data['rows'].sort(key=lambda r: r['n'])
        lines += [f'Simulated results merged from {len(parts)} runs of this script over '
                  'disjoint seed ranges (`--first-seed N --json FILE`, then `--merge FILE ...`), '
                  f'run {"at the same time, one per core," if args.concurrent else "one after"}'
                  f'{"" if args.concurrent else " the other"} on the shared machine.', '']
        goals = render_simulated(data, lines)
    else:
        goals = simulated(args, lines)
    if not args.no_real:
        if (DATA / 'carmen' / 'mit-csail.clf').is_file():
            mit_csail(lines)
        else:
            print(f'real part skipped: {DATA} is absent')
    lines += ['## Goals', '', '| goal | measured | status |', '|---|---|---|']
    for goal, value, status in goals:
        lines.append(f'| {goal} | {value} | {status} |')
    lines += ['', 'Machine: 2 cores shared with other jobs during the run, so wall-clock '
              'latencies are inflated; CPU (thread) time is given next to them.', '']
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
