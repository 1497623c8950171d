# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Benchmark of wheel_odometry_calibration (issue 7): real data and simulated seeds.

Run from the repository root::

    .venv/bin/python benchmarks/bench_wheel_calib.py [--part all|real|sim|time|range] [--seeds N]

Parts: Censi et al. tuples (12 files, against the authors' results), the
tricycle with an external tracker (fit on the first half, dead reckoning on
the second), BreezySLAM's rover logs end to end (raw ticks + URG-04LX scans),
and ``--seeds`` simulated runs of ``agv_segments`` and ``diff_segments``
(seed-faithful vs improved), and ``diff_segments`` seen by a 4 m lidar with and
without the range margin. Prints the tables and writes them to
``docs/bench/7-wheel-calib.md`` (a part replaces only its own section).
Skips cleanly (exit 0) when ``../shared/data`` is absent (the simulated part
still runs with ``--part sim``).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import re
import sys
import time
from typing import Optional

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
DATA = REPO.parent / 'shared' / 'data'
OUT = REPO / 'docs' / 'bench' / '7-wheel-calib.md'

from robot_calib.core.estimator import run_batch  # noqa: E402
from robot_calib.methods.wheel_odometry_calibration import params as P  # noqa: E402
from robot_calib.methods.wheel_odometry_calibration import solver as S  # noqa: E402
from robot_calib.methods.wheel_odometry_calibration.improved import (  # noqa: E402
    ImprovedWheelCalibrator)
from robot_calib.methods.wheel_odometry_calibration.stages import (  # noqa: E402
    SeedSteeredCalibrator)

MM = 1e3
DEG = 180.0 / math.pi


def _ok(flag: bool) -> str:
    return 'met' if flag else 'MISSED'


# -- Censi et al. ---------------------------------------------------------------------------
def censi_section() -> str:
    """Compare with the authors' results on all 12 tuple files."""
    from robot_calib.io.datasets import censi
    folder = DATA / 'censi_calibration'
    lines = ['## Censi et al. (T-RO 2013) tuples: differential drive, against the authors',
             '',
             "Input: the authors' tuples (wheel speeds x interval, scan-matching motion of the "
             'laser). Reference: `*_results.json` of their tool. Columns: difference to the '
             'authors (ours - theirs) of left/right wheel **diameter** (mm), axle (mm) and laser '
             'yaw (deg); std = one standard deviation (ours: inverse Fisher information with the '
             'residual noise per axis; theirs: sqrt of the diagonal of their covariance, read '
             'as `l_diam, r_diam, axle, l_x, l_y, l_theta`). "Censi-faithful" is our '
             're-implementation of their closed form with their outlier trimming (4 passes '
             'dropping the worst 1 %); "improved" is the joint ML fit (`mode: improved`).',
             '',
             '| file | tuples | authors d_l / d_r / axle (mm) | std theirs d_l / axle (mm) '
             '| Censi-faithful dd_l / dd_r / daxle (mm), dyaw (deg) | improved dd_l / dd_r / '
             'daxle (mm), dyaw (deg) | std ours d_l / axle (mm) | improved goals |',
             '|---|---|---|---|---|---|---|---|']
    met = {'faithful': 0, 'improved': 0}
    z_max = 0.0
    worst = {'faithful': np.zeros(4), 'improved': np.zeros(4)}
    for name in censi.FILES:
        segs = censi.load_tuples(folder / f'{name}.tuple')
        ref = censi.load_results(folder / f'{name}_results.json')
        refx = np.array([ref[k] for k in P.DIFF_KEYS])
        faithful = S.censi_calibrate(segs)['x']
        p = P.WheelCalibParams(drive_type='differential', wheel_radius=0.02, track_width=0.09)
        res = S.calibrate('differential', segs, p)
        imp = np.array([res.values[k] for k in P.DIFF_KEYS])
        row = {}
        for tag, x in (('faithful', faithful), ('improved', imp)):
            d = np.array([2 * (x[0] - refx[0]) * MM, 2 * (x[1] - refx[1]) * MM,
                          (x[2] - refx[2]) * MM, math.remainder(x[5] - refx[5], 2 * math.pi)
                          * DEG])
            ok = abs(d[0]) <= 0.1 and abs(d[1]) <= 0.1 and abs(d[2]) <= 0.3 and \
                abs(d[3]) <= 0.1
            met[tag] += ok
            worst[tag] = np.maximum(worst[tag], np.abs(d))
            row[tag] = (d, ok)
        fd, _ = row['faithful']
        idd, iok = row['improved']
        z_max = max(z_max, abs(idd[0]) / (2 * res.stds['left_wheel_radius'] * MM),
                    abs(idd[1]) / (2 * res.stds['right_wheel_radius'] * MM),
                    abs(idd[2]) / (res.stds['track_width'] * MM))
        lines.append(
            f'| {name} | {len(segs)} | {2 * ref["left_wheel_radius"] * MM:.3f} / '
            f'{2 * ref["right_wheel_radius"] * MM:.3f} / {ref["track_width"] * MM:.2f} | '
            f'{2 * ref["left_wheel_radius_std"] * MM:.3f} / {ref["track_width_std"] * MM:.3f} | '
            f'{fd[0]:+.4f} / {fd[1]:+.4f} / {fd[2]:+.4f}, {fd[3]:+.4f} | '
            f'{idd[0]:+.3f} / {idd[1]:+.3f} / {idd[2]:+.3f}, {idd[3]:+.3f} | '
            f'{2 * res.stds["left_wheel_radius"] * MM:.3f} / {res.stds["track_width"] * MM:.3f} '
            f'| {_ok(iok)} |')
    lines += ['',
              '| estimator | files meeting all goals (diameters <= 0.1 mm, axle <= 0.3 mm, '
              'yaw <= 0.1 deg) | worst d_l, d_r (mm) | worst axle (mm) | worst yaw (deg) |',
              '|---|---|---|---|---|']
    for tag in ('faithful', 'improved'):
        w = worst[tag]
        lines.append(f'| {"Censi-faithful" if tag == "faithful" else "improved (ML)"} | '
                     f'{met[tag]} / 12 ({_ok(met[tag] == 12)}) | {w[0]:.4f}, {w[1]:.4f} | '
                     f'{w[2]:.4f} | {w[3]:.4f} |')
    lines += ['', 'The improved (ML) fit weighs the rotation and translation residuals by their '
              'estimated noise and rejects outliers by a chi-square gate instead of trimming 1 % '
              'per pass, so it is a different estimator: its largest difference to the authors '
              f'is {z_max:.2f} of its own standard deviation (diameters, axle); the 0.1 mm '
              'diameter goal is smaller than that standard deviation on every one-third file '
              '(std column). `mode: seed` for differential drive is the Censi-faithful closed '
              'form, which meets the goals on all files.', '']
    return '\n'.join(lines)


# -- tricycle ---------------------------------------------------------------------------------
def tricycle_section() -> str:
    """Fit on the first half, dead-reckon the second half against the tracker."""
    from robot_calib.io.datasets import tricycle as TR
    data = TR.load(DATA / 'tricycle' / 'dataset.txt')
    n = len(data.t)
    half = n // 2

    def errors(values, lo, hi):
        pred = TR.dead_reckon(data, values, lo, hi)
        e = np.hypot(*(pred[:, :2] - data.tracker_pose[lo:hi + 1, :2]).T)
        return float(e.mean()), float(e.max())

    nominal = dict(data.nominal)
    p = P.WheelCalibParams(drive_type='steered_wheel', **nominal)
    t0 = time.perf_counter()
    res = S.calibrate('steered_wheel', TR.segments(data, 0, half, 10), p)
    secs = time.perf_counter() - t0
    full = S.calibrate('steered_wheel', TR.segments(data, 0, n - 1, 10), p)
    seed_p = P.WheelCalibParams(drive_type='steered_wheel', mode='seed', **nominal)
    seed_stages = TR.stages(data, 0, half)
    seed = SeedSteeredCalibrator(seed_p).run(seed_stages)
    b_ho, a_ho, s_ho = errors(nominal, half, n - 1), errors(res.values, half, n - 1), \
        errors(seed.values, half, n - 1)
    b_all, a_all = errors(nominal, 0, n - 1), errors(full.values, 0, n - 1)
    names = {'steering_offset': ('steering offset', 'rad'),
             'steering_scale': ('steering scale (Ksteer)', ''),
             'wheel_radius': ('traction scale (Ktraction = 2 pi r)', 'm/turn'),
             'wheel_base': ('wheel base (axis length)', 'm'),
             'lidar_x': ('sensor x', 'm'), 'lidar_y': ('sensor y', 'm'),
             'lidar_yaw': ('sensor yaw', 'rad')}
    lines = ['## Tricycle (front-tractor, steered drive wheel) with an external tracker', '',
             f'{n} samples, {data.t[-1] - data.t[0]:.0f} s. The tracker gives the pose of a '
             'sensor nominally 1.5 m ahead of base_link; segments are 10 samples (~0.4 s); '
             "the measured motion of a segment is the tracked sensor's relative pose. "
             'Fit on the first half; the error is the position of the tracked sensor '
             'predicted by dead reckoning from the encoders (started at the tracker pose at '
             'the beginning of the half) against the tracker, mean and max over the half.', '',
             '| parameter | nominal | improved, fit on first half | std |',
             '|---|---|---|---|']
    for k in P.STEER_KEYS:
        label, unit = names[k]
        scale = 2 * math.pi if k == 'wheel_radius' else 1.0
        lines.append(f'| {label} {f"({unit})" if unit else ""} | {nominal[k] * scale:.6g} | '
                     f'{res.values[k] * scale:.6g} | {res.stds[k] * scale:.2g} |')
    lines += ['', f'Verdict (first half): {res.verdict}. Fit time {secs:.2f} s.', '',
              '| held-out second half | mean error (m) | max error (m) |', '|---|---|---|',
              f'| nominal parameters | {b_ho[0]:.3f} | {b_ho[1]:.3f} |',
              f'| improved (fit on first half) | {a_ho[0]:.3f} | {a_ho[1]:.3f} |',
              f'| seed-faithful (fit on first half) | {s_ho[0]:.3f} | {s_ho[1]:.3f} |', '',
              f'Goal: held-out mean error <= 0.3 m: **{_ok(a_ho[0] <= 0.3)}** '
              f'({a_ho[0]:.3f} m; a public course solution claims 14.4 m -> 0.82 m mean over '
              f'the whole run). For comparison over the whole run (fit on the whole run): '
              f'nominal {b_all[0]:.2f} m mean / {b_all[1]:.2f} m max -> improved '
              f'{a_all[0]:.3f} m mean / {a_all[1]:.3f} m max.', '',
              f'Seed-faithful: {len(seed_stages)} straight stage(s) by the nominal steering '
              f'conversion in the first half; verdict: {seed.verdict}. The nominal steering '
              "scale (0.1) is far from the calibrated one, so the seed's straight-stage test "
              'finds almost no stages on this run and it keeps the nominal values.', '']
    rows = ['| segment length (samples) | held-out mean (m) | held-out max (m) |',
            '|---|---|---|']
    for win in (5, 10, 20, 40):
        r = S.calibrate('steered_wheel', TR.segments(data, 0, half, win), p)
        m = errors(r.values, half, n - 1)
        rows.append(f'| {win} | {m[0]:.3f} | {m[1]:.3f} |')
    lines += ['Sensitivity to the segment length (improved):', ''] + rows + ['']
    return '\n'.join(lines)


# -- BreezySLAM -------------------------------------------------------------------------------
def breezy_section() -> str:
    """Calibrate both rover logs end to end and compare them."""
    from robot_calib.io.datasets import breezyslam as B
    lines = ['## BreezySLAM rover logs (raw wheel ticks + URG-04LX scans, end to end)', '',
             'Wheel ticks -> joint positions; scans matched by `robot_calib.core.scan_match` '
             'between key frames (0.3 m / 0.2 rad of nominal odometry). Nominal values: '
             "BreezySLAM's rover model (effective radius 154 mm, track 330 mm, laser 145 mm "
             'ahead). No ground truth: agreement between the two runs is the check.', '',
             '| run | segments (matched / attempted) | outliers | left r (mm) | right r (mm) '
             '| track (mm) | lidar x (mm) | lidar y (mm) | lidar yaw (deg) | time (s) | '
             'verdict |', '|---|---|---|---|---|---|---|---|---|---|---|']
    results = []
    for run in ('exp1', 'exp2'):
        samples = B.load(DATA / 'breezyslam' / f'{run}.dat')
        p = P.WheelCalibParams(drive_type='differential', wheel_radius=B.WHEEL_RADIUS,
                               track_width=B.TRACK_WIDTH, lidar_x=B.LIDAR_X)
        t0 = time.perf_counter()
        res = run_batch(ImprovedWheelCalibrator(p, max_range=5.6, periodic=False),
                        samples).result
        secs = time.perf_counter() - t0
        results.append(res)
        v, s = res.values, res.stds
        c = res.counts
        lines.append(
            f'| {run} | {res.segments} / {c["match_attempts"]} | '
            f'{res.details.get("outliers", 0)} | {v["left_wheel_radius"] * MM:.1f} +- '
            f'{s["left_wheel_radius"] * MM:.1f} | {v["right_wheel_radius"] * MM:.1f} +- '
            f'{s["right_wheel_radius"] * MM:.1f} | {v["track_width"] * MM:.1f} +- '
            f'{s["track_width"] * MM:.1f} | {v["lidar_x"] * MM:.0f} +- {s["lidar_x"] * MM:.0f} '
            f'| {v["lidar_y"] * MM:.0f} +- {s["lidar_y"] * MM:.0f} | {v["lidar_yaw"] * DEG:.2f} '
            f'+- {s["lidar_yaw"] * DEG:.2f} | {secs:.1f} | {res.verdict} |')
    shifted = []
    for run in ('exp1', 'exp2'):
        p = P.WheelCalibParams(drive_type='differential', wheel_radius=B.WHEEL_RADIUS,
                               track_width=B.TRACK_WIDTH, lidar_x=B.LIDAR_X,
                               scan_time_offset=-0.1)
        r = run_batch(ImprovedWheelCalibrator(p, max_range=5.6, periodic=False),
                      B.load(DATA / 'breezyslam' / f'{run}.dat')).result
        shifted.append(f'{run}: {r.details.get("outliers", 0)} outliers of '
                       f'{r.segments}, radii {r.values["left_wheel_radius"] * MM:.1f} / '
                       f'{r.values["right_wheel_radius"] * MM:.1f} mm, track '
                       f'{r.values["track_width"] * MM:.1f} mm')
    lines += ['', 'Many segments disagree with the model (fast rover, ~1 m/s and ~1 rad/s, in '
              'corridors). Diagnostic: with the scans paired 0.1 s earlier than their stamp '
              '(`scan_time_offset: -0.1`) the outliers drop (' + '; '.join(shifted) + '): the '
              "log's scan and tick stamps are probably not simultaneous. The benchmark keeps "
              'offset 0 (no per-data-set tuning); the estimator does not estimate a time '
              'offset.']
    a, b = results
    lines += ['', '| quantity | exp1 - exp2 | combined std | difference / std |',
              '|---|---|---|---|']
    for k in P.DIFF_KEYS:
        d = a.values[k] - b.values[k]
        sd = math.hypot(a.stds[k], b.stds[k])
        unit = DEG if k == 'lidar_yaw' else MM
        lines.append(f'| {k} ({"deg" if k == "lidar_yaw" else "mm"}) | {d * unit:+.2f} | '
                     f'{sd * unit:.2f} | {d / sd:+.1f} |')
    lines.append('')
    return '\n'.join(lines)


# -- simulation -------------------------------------------------------------------------------
SIM_NOMINAL = {
    'agv_segments': {'drive_type': 'steered_wheel', 'wheel_radius': 0.1, 'wheel_base': 1.0,
                     'lidar_x': 0.5},
    'diff_segments': {'drive_type': 'differential', 'wheel_radius': 0.05, 'track_width': 0.3,
                      'lidar_x': 0.1},
}


def _sim_one(name: str, seed: int, with_time: bool = False, overrides: Optional[dict] = None,
             **params) -> dict:
    from robot_calib.sim import run_scenario
    t0 = time.perf_counter()
    sim = run_scenario(name, seed=seed, overrides=overrides)
    t1 = time.perf_counter()
    p = P.WheelCalibParams(**SIM_NOMINAL[name], **params)
    cal = ImprovedWheelCalibrator(p, periodic=False)
    res = run_batch(cal, [sample for topic, sample in sim.messages
                          if topic.lstrip('/') in ('joint_states', 'scan')]).result
    t2 = time.perf_counter()
    out = {'truth': sim.truth, 'res': res, 'sim_s': t1 - t0, 'calib_s': t2 - t1,
           'duration': sim.truth['duration']}
    gate = cal.stage_gate  # the seed's stages of the same drive, for comparison
    if gate is not None:
        out['seed'] = gate.result()
        out['stages'] = len(gate.records)
        out['stages_needed'] = gate.stages_needed
        if gate.stages_needed:
            out['seed_time'] = gate.records[gate.stages_needed - 1].t1
        if with_time:  # drive time the improved estimator needs (prefix solves every 20 s)
            truth = sim.truth
            for t_end in np.arange(20.0, sim.truth['duration'] + 1.0, 20.0):
                segs = [s for s in cal.front.segments if s.t1 <= t_end]
                r = S.calibrate(p.drive_type, segs, p)
                if r.converged and abs(r.values['steering_offset']
                                       - truth['steering_offset']) * DEG <= 0.02:
                    out['improved_time'] = float(t_end)
                    break
    return out


def time_section(n_seeds: int) -> str:
    """Return the drive time each method needs on the AGV drive (a few seeds)."""
    runs = [_sim_one('agv_segments', s, with_time=True) for s in range(n_seeds)]
    lines = ['### Drive time needed (`agv_segments`)', '',
             f'Seeds 0..{n_seeds - 1}. Improved: the estimator re-run on the segments of the '
             'first T s (T every 20 s) until its verdict is converged and the offset is within '
             '0.02 deg of the truth. Seed-faithful: the end of the stage at which the '
             'consecutive-stage counter reached its threshold.', '',
             '| method | drive time to converge (s) | stages |', '|---|---|---|',
             f'| improved | {_med(runs, "improved_time")} | uses every segment (straight and '
             'turning) |',
             f'| seed-faithful | {_med(runs, "seed_time")} | '
             f'{_med(runs, "stages_needed")} straight stages |', '']
    return '\n'.join(lines)


def _med(runs: list, key: str) -> str:
    vals = [r[key] for r in runs if r.get(key) is not None]
    return f'median {np.median(vals):.0f} of {len(vals)} runs' if vals else 'never'


def sim_section(n_seeds: int, budget_s: float = math.inf) -> str:
    """Run ``n_seeds`` seeds of both scenarios; accuracy, coverage, seed vs improved."""
    runs = {'agv_segments': [], 'diff_segments': []}
    start = time.perf_counter()
    for s in range(n_seeds):
        if s >= 2 and time.perf_counter() - start > budget_s:
            break
        for name in runs:
            runs[name].append(_sim_one(name, s))
    done = len(runs['agv_segments'])
    requested, n_seeds = n_seeds, done
    lines = ['## Simulated calibration drives (`agv_segments`, `diff_segments`)', '',
             f'{n_seeds} seeds each (seeds 0..{n_seeds - 1}; sensor noise differs per seed, the '
             'true errors are the scenario defaults). Full pipeline: joint_states + simulated '
             'lidar (0.01 m range noise, motion distortion) -> deskewed key frames -> '
             '`scan_match` -> estimator -> key frames deskewed again with the estimate, '
             're-matched and re-solved. Coverage: fraction of runs whose 95 % interval '
             '(estimate +- 1.96 std) contains the truth.', '']
    if done < requested:
        lines.insert(2, f'**Time budget reached: {done} of {requested} seeds were run.**\n')
    agv = runs['agv_segments']
    keys = P.STEER_KEYS
    err = {k: np.array([r['res'].values[k] - r['truth'][k] for r in agv]) for k in keys}
    std = {k: np.array([r['res'].stds[k] for r in agv]) for k in keys}
    conv = sum(r['res'].converged for r in agv)
    lines += ['### Steered-wheel AGV (`agv_segments`, 240 s: true offset 1 deg, radius +1.2 %, '
              'wheel base +1 %)', '',
              '| parameter | median abs error | max abs error | median std | 95 % coverage |',
              '|---|---|---|---|---|']
    for k in keys:
        unit, fmt = (DEG, 'deg') if k in P.ANGLE_KEYS else (1.0, '')
        rel = k in ('wheel_radius', 'wheel_base', 'steering_scale')
        e = np.abs(err[k]) / (agv[0]['truth'][k] if rel else 1.0) * (100 if rel else unit)
        sd = std[k] / (agv[0]['truth'][k] if rel else 1.0) * (100 if rel else unit)
        u = '%' if rel else (fmt or 'm')
        cov = np.mean(np.abs(err[k]) <= 1.96 * std[k])
        lines.append(f'| {k} | {np.median(e):.4f} {u} | {np.max(e):.4f} {u} | '
                     f'{np.median(sd):.4f} {u} | {cov * 100:.0f} % |')
    off_e = np.abs(err['steering_offset']) * DEG
    rad_e = np.abs(err['wheel_radius']) / agv[0]['truth']['wheel_radius'] * 100
    cov_off = np.mean(np.abs(err['steering_offset']) <= 1.96 * std['steering_offset'])
    cov_rad = np.mean(np.abs(err['wheel_radius']) <= 1.96 * std['wheel_radius'])
    seed_off = np.array([abs(r['seed'].values['steering_offset'] - r['truth']['steering_offset'])
                         * DEG for r in agv if r['seed'].converged])
    seed_rad = np.array([abs(r['seed'].values['wheel_radius'] / r['truth']['wheel_radius'] - 1)
                         * 100 for r in agv if r['seed'].converged])
    needed = [r['stages_needed'] for r in agv if r['stages_needed']]
    total_stages = [r['stages'] for r in agv]
    lines += ['', f'Verdict converged in {conv} / {n_seeds} runs (improved).', '',
              '| goal (AGV) | improved | seed-faithful |', '|---|---|---|',
              f'| steering offset within 0.02 deg (runs) | {np.sum(off_e <= 0.02)} / {n_seeds} '
              f'({_ok(np.all(off_e <= 0.02))}; max {off_e.max():.4f} deg) | '
              f'{np.sum(seed_off <= 0.02)} / {n_seeds} (converged {len(seed_off)}; max '
              f'{seed_off.max() if len(seed_off) else float("nan"):.4f} deg) |',
              f'| wheel radius within 0.05 % (runs) | {np.sum(rad_e <= 0.05)} / {n_seeds} '
              f'({_ok(np.all(rad_e <= 0.05))}; max {rad_e.max():.4f} %) | '
              f'{np.sum(seed_rad <= 0.05)} / {n_seeds} (max '
              f'{seed_rad.max() if len(seed_rad) else float("nan"):.4f} %) |',
              f'| 95 % interval covers truth in >= 90 % | offset {cov_off * 100:.0f} %, radius '
              f'{cov_rad * 100:.0f} % ({_ok(min(cov_off, cov_rad) >= 0.9)}) | no std from the '
              'seed (spread of the cached stages only) |',
              f'| straight stages used / needed | all segments of the drive (median '
              f'{np.median([r["res"].segments_used for r in agv]):.0f}), stages found: median '
              f'{np.median(total_stages):.0f} | converged after median '
              f'{np.median(needed) if needed else float("nan"):.0f} stages (max '
              f'{max(needed) if needed else float("nan")}) |',
              '| wheel base, steering scale, lidar pose | estimated (table above) | not '
              'estimated (nominal) |', '']
    diff = runs['diff_segments']
    keys = P.DIFF_KEYS
    lines += ['### Differential drive (`diff_segments`, 180 s: radii +0.8 % / -0.5 %, track '
              '+2 %)', '',
              '| parameter | median abs error | max abs error | median std | 95 % coverage |',
              '|---|---|---|---|---|']
    for k in keys:
        e = np.array([r['res'].values[k] - r['truth'][k] for r in diff])
        sd = np.array([r['res'].stds[k] for r in diff])
        cov = np.mean(np.abs(e) <= 1.96 * sd)
        if k == 'lidar_yaw':
            lines.append(f'| {k} | {np.median(np.abs(e)) * DEG:.4f} deg | '
                         f'{np.max(np.abs(e)) * DEG:.4f} deg | {np.median(sd) * DEG:.4f} deg | '
                         f'{cov * 100:.0f} % |')
        elif k.startswith('lidar'):
            lines.append(f'| {k} | {np.median(np.abs(e)) * MM:.2f} mm | '
                         f'{np.max(np.abs(e)) * MM:.2f} mm | {np.median(sd) * MM:.2f} mm | '
                         f'{cov * 100:.0f} % |')
        else:
            tr = diff[0]['truth'][k]
            lines.append(f'| {k} | {np.median(np.abs(e)) / tr * 100:.4f} % | '
                         f'{np.max(np.abs(e)) / tr * 100:.4f} % | {np.median(sd) / tr * 100:.4f} '
                         f'% | {cov * 100:.0f} % |')
    conv = sum(r['res'].converged for r in diff)
    sim_s = np.median([r['sim_s'] for r in agv + diff])
    cal_s = [r['calib_s'] / r['duration'] for r in agv + diff]
    lines += ['', f'Verdict converged in {conv} / {n_seeds} runs (differential). Speed: the '
              f'calibration processes a drive {1 / np.median(cal_s):.0f}x faster than real time '
              f'(median; simulation itself {sim_s:.1f} s per run, not counted).', '']
    return '\n'.join(lines)


def _short_range_one(seed: int, margin: float) -> dict:
    """Calibrate diff_segments seen by a 4 m lidar with ``range_margin`` = ``margin``."""
    r = _sim_one('diff_segments', seed, overrides={'lidar.range_max': SHORT_RANGE},
                 range_margin=margin)
    res = r['res']
    z = {k: (res.values[k] - r['truth'][k]) / res.stds[k]
         for k in ('left_wheel_radius', 'right_wheel_radius', 'track_width') if k in res.values}
    return {'seed': seed, 'margin': margin, 'z': z, 'converged': res.converged}


SHORT_RANGE = 4.0
"""range_max (m) of the short-range lidar part (a cheap 2D lidar: RPLIDAR A1 class)."""


def short_range_section(n_seeds: int) -> str:
    """diff_segments with a 4 m lidar: the range margin against the selection bias."""
    from concurrent.futures import ProcessPoolExecutor
    default = P.WheelCalibParams().range_margin
    cases = [(seed, m) for seed in range(n_seeds) for m in (0.0, default)]
    with ProcessPoolExecutor(max_workers=2) as ex:
        runs = list(ex.map(_short_range_one, *zip(*cases)))
    lines = [f'## Short-range lidar (`diff_segments`, `lidar.range_max` {SHORT_RANGE:.0f} m)', '',
             f'{n_seeds} seeds. Near `range_max` only the returns whose noise fell short '
             'survive, so a wall at the limit reads closer than it is; as the robot moves, '
             'different walls sit at the limit, and every scan-matched displacement comes out '
             f'short. `range_margin` ({default:g}, default) leaves out the returns beyond '
             f'{1 - default:g} x `range_max`; 0 is the code before it. Error over std of each '
             'estimate (the radii scale every length):', '',
             '| seed | range_margin | left radius z | right radius z | track width z | '
             'verdict |', '|---|---|---|---|---|---|']
    for r in runs:
        z = r['z']
        lines.append(f'| {r["seed"]} | {r["margin"]:g} | {z["left_wheel_radius"]:+.1f} | '
                     f'{z["right_wheel_radius"]:+.1f} | {z["track_width"]:+.1f} | '
                     f'{"converged" if r["converged"] else "not converged"} |')
    for m in (0.0, default):
        zs = np.array([list(r['z'].values()) for r in runs if r['margin'] == m])
        lines += ['', f'range_margin {m:g}: z mean {zs.mean():+.2f}, RMS '
                  f'{math.sqrt(float(np.mean(zs ** 2))):.2f}, max |z| {np.abs(zs).max():.1f}.']
    return '\n'.join(lines + [''])


# -- output -----------------------------------------------------------------------------------
HEADER = ('# Wheel odometry calibration (issue 7) benchmark\n\n'
          'Generated by `benchmarks/bench_wheel_calib.py`. Goals from the issue; "met" / '
          '"MISSED" are computed by the script.\n')


def write_sections(sections: dict) -> None:
    """Replace the given sections in the markdown file, keeping the others."""
    text = OUT.read_text() if OUT.is_file() else HEADER
    for key, body in sections.items():
        block = f'<!-- {key} -->\n{body}\n<!-- /{key} -->'
        pattern = re.compile(rf'<!-- {key} -->.*?<!-- /{key} -->', re.S)
        if pattern.search(text):
            text = pattern.sub(lambda _m: block, text)
        else:
            text = text.rstrip('\n') + '\n\n' + block + '\n'
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(text)


def main() -> int:
    """Run the requested parts, print and write their tables."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--part', choices=('all', 'real', 'sim', 'time', 'range'), default='all')
    ap.add_argument('--seeds', type=int, default=10, help='simulated seeds per scenario')
    ap.add_argument('--budget', type=float, default=math.inf,
                    help='stop starting new seeds after this many minutes')
    args = ap.parse_args()
    sections = {}
    if args.part in ('all', 'real'):
        if not DATA.is_dir():
            print('bench_wheel_calib: ../shared/data is absent; skipping the real-data part')
        else:
            for key, fn in (('censi', censi_section), ('tricycle', tricycle_section),
                            ('breezyslam', breezy_section)):
                t0 = time.perf_counter()
                sections[key] = fn()
                print(sections[key])
                print(f'[{key}: {time.perf_counter() - t0:.1f} s]\n')
    if args.part in ('all', 'sim'):
        t0 = time.perf_counter()
        sections['sim'] = sim_section(args.seeds, args.budget * 60.0)
        print(sections['sim'])
        print(f'[sim: {time.perf_counter() - t0:.1f} s]')
    if args.part in ('all', 'time'):
        t0 = time.perf_counter()
        sections['simtime'] = time_section(3)
        print(sections['simtime'])
        print(f'[time: {time.perf_counter() - t0:.1f} s]')
    if args.part in ('all', 'range'):
        t0 = time.perf_counter()
        sections['shortrange'] = short_range_section(args.seeds)
        print(sections['shortrange'])
        print(f'[range: {time.perf_counter() - t0:.1f} s]')
    if sections:
        write_sections(sections)
        print(f'wrote {OUT.relative_to(REPO)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
