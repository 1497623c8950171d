# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Benchmark of ``odometry_fusion`` (issue 4): real Husky bags, the fusion_drive simulation, speed.

Run from the repository root::

    .venv/bin/python benchmarks/bench_fusion.py [--seeds 20] [--jobs 2] [--skip-sim]

Prints the tables and writes them to ``docs/bench/4-fusion.md``. Skips cleanly
(exit 0) when ``../shared/data`` is absent.

Metrics
-------
- ATE against GPS (real bags): the fix latitude/longitude is turned into local
  ENU metres (equirectangular about the first fix, WGS-84 radius; the runs span
  < 200 m so the projection error is < 1 mm); every estimate is linearly
  interpolated at the fix stamps; ONE rigid SE(2) transform (rotation +
  translation, no scale; closed-form Kabsch/Umeyama over all fixes of the run)
  aligns the estimate to the GPS; ATE is the RMS of the remaining distances.
  The final-position error is the aligned distance at the last fix. GPS is
  never an input of the filters.
- ATE against ground truth (simulation): the same SE(2) alignment against
  ``ground_truth/odom``; final heading error is the aligned yaw difference at
  the end of the run.
- NIS: per odometry update, the normalised innovation squared against the
  two-sided 95 % chi-square band of its dof; also its moving average over 20
  updates against the band of that average.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
import math
import os
from pathlib import Path
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / 'shared' / 'data'
OUT = REPO / 'docs' / 'bench' / '4-fusion.md'
HUSKY_IMU_RPY = [math.pi / 2, 0.0, -math.pi / 2]
"""base_link -> imu_link of robot_localization's test1 (roll pi/2, yaw -pi/2; data README)."""

sys.path.insert(0, str(REPO))

from fusion_analysis import (  # noqa: E402,I100
    accel_speed_events, dead_reckoning, enu, gps_wander, hindsight_bounds, score,
    standstill_gyro_bias)
from robot_calib.core.estimator import run_batch  # noqa: E402
from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix, wrap_angle  # noqa: E402
from robot_calib.methods.odometry_fusion.common import from_odometry  # noqa: E402
from robot_calib.methods.odometry_fusion.improved import IBG, IKV, IKW  # noqa: E402
from robot_calib.methods.odometry_fusion.params import FusionParams  # noqa: E402
from robot_calib.methods.odometry_fusion.variants import make_estimator  # noqa: E402


# ---------------------------------------------------------------------------------------
# metrics
# ---------------------------------------------------------------------------------------
def run_filter(seq: list, **kw) -> tuple[dict, object, float, np.ndarray]:
    """
    Run the core over (kind, sample) pairs; return (trajectory arrays, result, s, pose covs).

    One estimate per accepted odometry sample (the IMU dead-reckoning ones are left out).
    """
    t0 = time.perf_counter()
    run = run_batch(make_estimator(FusionParams(**kw)), [s for _, s in seq], keep=from_odometry)
    el = time.perf_counter() - t0
    outs = run.outputs
    tr = {'t': np.array([o.t for o in outs]), 'xy': np.array([[o.x, o.y] for o in outs]),
          'yaw': np.array([o.yaw for o in outs])}
    return tr, run.result, el, np.array([o.pose_cov for o in outs])


def covariance_coverage(tr: dict, covs: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """
    Return the fractions of outputs whose position / heading error is inside its 95 % region.

    Both in the odometry frame, which the simulator starts at the true start pose (no
    alignment): position NEES e' P^-1 e <= chi2(2, 0.95) = 5.99, |yaw error| <= 1.96 sigma.
    """
    t = tr['t']
    m = (t >= gt[0, 0]) & (t <= gt[-1, 0])
    ex = tr['xy'][m, 0] - np.interp(t[m], gt[:, 0], gt[:, 1])
    ey = tr['xy'][m, 1] - np.interp(t[m], gt[:, 0], gt[:, 2])
    gyaw = np.interp(t[m], gt[:, 0], np.unwrap(gt[:, 3]))
    eyaw = np.abs(wrap_angle(tr['yaw'][m] - gyaw))
    c = covs[m]
    det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] ** 2
    nees = (c[:, 1, 1] * ex ** 2 - 2 * c[:, 0, 1] * ex * ey + c[:, 0, 0] * ey ** 2) / det
    pos = float(np.mean(nees <= 5.991))
    yaw = float(np.mean(eyaw <= 1.96 * np.sqrt(c[:, 2, 2])))
    return pos, yaw


def odom_track(odoms: list) -> dict:
    """Return the raw odometry as trajectory arrays."""
    return {'t': np.array([o.t for o in odoms]), 'xy': np.array([[o.x, o.y] for o in odoms]),
            'yaw': np.array([o.yaw for o in odoms])}


# ---------------------------------------------------------------------------------------
# real bags
# ---------------------------------------------------------------------------------------
def load_bag(path: Path, imu_topic: str, odom_topic: str, fix_topic: str):
    """Return (sequence of (kind, sample), odometry samples, fixes) of a bag."""
    from robot_calib.io.bags import read_messages
    seq, odoms, fixes = [], [], []
    for m in read_messages([path], topics=[imu_topic, odom_topic, fix_topic]):
        for s in m.samples:
            if m.topic == imu_topic:
                seq.append(('imu', s))
            elif m.topic == odom_topic:
                seq.append(('odom', s))
                odoms.append(s)
            elif getattr(s, 'status', -1) >= 0:
                fixes.append(s)
    return seq, odoms, fixes


def fmt(v: float, n: int = 2) -> str:
    """Format a number (or n/a)."""
    return 'n/a' if v is None or not math.isfinite(v) else f'{v:.{n}f}'


def husky_arrays(seq: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return test1's gyro z (t, rad/s), forward force (t, m/s^2) and wheels (t, v, w)."""
    rot = quat_to_matrix(quat_from_rpy(*HUSKY_IMU_RPY))
    imu = sorted((s for k, s in seq if k == 'imu'), key=lambda s: s.t)
    gyro = np.array([(s.t, float(rot[2] @ s.gyro)) for s in imu])
    accel = np.array([(s.t, float(rot[0] @ s.accel)) for s in imu])
    wheels = np.array([(s.t, s.vx, s.wz) for k, s in seq if k == 'odom'])
    return gyro, accel, wheels


def real_husky(lines: list) -> dict:
    """Benchmark test1.bag (robot_localization): raw odometry, seed, default, variants, bounds."""
    seq, odoms, fixes = load_bag(SHARED / 'robot_localization' / 'test1.bag', '/imu/data',
                                 '/husky_velocity_controller/odom', '/fix')
    ref = enu(fixes)
    gps_end = float(np.hypot(*(ref[-1, 1:3] - ref[0, 1:3])))
    rows = [('raw wheel odometry', score(**odom_track(odoms), ref=ref), None, None)]
    runs = [
        ('seed-faithful (mode seed)', {'mode': 'seed', 'imu_rpy': HUSKY_IMU_RPY}),
        ('improved, default (extrinsic as parameter)', {'imu_rpy': HUSKY_IMU_RPY}),
        ('improved, no extrinsic given (up axis from gravity)', {}),
        ('improved, adaptation iae (R only)', {'imu_rpy': HUSKY_IMU_RPY, 'adaptation': 'iae'}),
        ('improved, no adaptation', {'imu_rpy': HUSKY_IMU_RPY, 'adaptive': False}),
        ('improved, wheel yaw rate also corrects the gyro bias',
         {'imu_rpy': HUSKY_IMU_RPY, 'bias_from_wheels': True}),
        ('improved, no gravity compensation',
         {'imu_rpy': HUSKY_IMU_RPY, 'gravity_compensation': False}),
        ('improved, odometry_delay 0.3 s from the start (the delay the fit finds here)',
         {'imu_rpy': HUSKY_IMU_RPY, 'odometry_delay': 0.3}),
        ('improved, the delay found applied once the fit is ok (odometry_delay_auto)',
         {'imu_rpy': HUSKY_IMU_RPY, 'odometry_delay_auto': True}),
    ]
    result = {}
    for name, kw in runs:
        tr, f, el, _ = run_filter(seq, **kw)
        rows.append((name, score(**tr, ref=ref), f, len(seq) / el))
    gyro, accel, wheels = husky_arrays(seq)
    bounds = hindsight_bounds(gyro, wheels[:, :2], ref)
    lines += ['## Real robot: robot_localization test1.bag (Husky, 395 s, 359 m)', '',
              f'GPS: {len(fixes)} fixes; the GPS puts the end {gps_end:.1f} m from the start. '
              'Goal (issue 18): ATE <= 2.7 m and final error <= 5.5 m, causally, GPS not used '
              'by the filter (issue 4 asked for 2.0 m and 3 m). The bounds are gyro + '
              'wheel-speed dead reckoning with constants chosen knowing the GPS answer '
              '(analysis, not methods).',
              '', '| estimate | ATE (m) | final error (m) | end from start (m) | '
              'gyro bias (rad/s) | NIS in band | core msgs/s |', '|---|---|---|---|---|---|---|']
    for name, sc, f, rate in rows:
        bias = nis = '-'
        if f is not None and f.nis is not None:
            bias = f'{f.state[IBG]:.5f}'
            nis = fmt(f.nis.in_band / max(f.nis.checked, 1))
        lines.append(f'| {name} | {fmt(sc["ate"])} | {fmt(sc["final"])} | '
                     f'{fmt(sc["end_from_start"])} | {bias} | {nis} | '
                     f'{fmt(rate, 0) if rate else "-"} |')
        result[name] = sc
    for key, name in (('bias', 'bound: best constant gyro bias (wheel speed as measured)'),
                      ('bias_scale', 'bound: best constant gyro bias and wheel-speed scale '
                       f'({bounds["bias_scale"]["scale"]:.3f})')):
        bd = bounds[key]
        lines.append(f'| {name} | {bd["ate"]:.2f} | {bd["final"]:.2f} | - | {bd["bias"]:.5f} '
                     '| - | - |')
    d = rows[2][1]
    met_a, met_f = d['ate'] <= 2.7, d['final'] <= 5.5
    lines += ['', husky_sensor_text(gyro, accel, wheels, ref, bounds), '',
              f'GPS self-consistency: over 4-s windows the GPS displacement differs from the '
              f'wheel distance by {gps_wander(ref, wheels):.2f} m RMS while the robot drives '
              'straight at about 1 m/s, so the GPS itself wanders by metres; and in the last '
              '8 s the GPS moves about 3 m while wheels, gyro and accelerometer agree on 7 m of '
              'straight driving.']
    lines += ['', f'Default: ATE {d["ate"]:.2f} m (goal <= 2.7: {"met" if met_a else "MISSED"}; '
              f'bounds {bounds["bias"]["ate"]:.2f} and {bounds["bias_scale"]["ate"]:.2f}), '
              f'final error {d["final"]:.2f} m (goal <= 5.5: {"met" if met_f else "MISSED"}; '
              f'bounds {bounds["bias"]["final"]:.2f} and {bounds["bias_scale"]["final"]:.2f}); '
              f'raw odometry ATE {rows[0][1]["ate"]:.2f} m.', '']
    default = rows[2][2]
    fit, state, sd = default.yaw_rate_fit, default.state, np.sqrt(np.diag(default.covariance))
    if 'yaw_rate_scale' in fit:
        lines += [f'Odometry yaw-rate calibration (default run, `{fit["status"]}`): scale '
                  f'{fit["yaw_rate_scale"]:.3f} +- {fit["yaw_rate_scale_std"]:.3f}, yaw rate per '
                  f'speed {fit["yaw_rate_per_speed"]:+.4f} +- {fit["yaw_rate_per_speed_std"]:.4f} '
                  f'rad/m over {fit["blocks"]} blocks ({fit["blocks_dropped"]} dropped), the '
                  f'odometry {fit["odometry_delay"]:.2f} +- {fit["odometry_delay_std"]:.2f} s '
                  'behind the gyro (the fit searches the delay; at no delay the same data give '
                  f'a scale of {husky_scale_at_no_delay(seq):.3f}); the '
                  f"filter's internal states, reported before, end at {state[IKW]:.3f} +- "
                  f'{sd[IKW]:.3f} and {state[IKV]:+.4f} +- {sd[IKV]:.4f}. No reference exists '
                  'for this skid-steer ratio.', '']
    result['goal_ate_met'], result['goal_final_met'] = met_a, met_f
    result['seq'] = seq
    return result


def husky_scale_at_no_delay(seq: list) -> float:
    """Return the default run's yaw-rate scale on test1 with the delay search off."""
    _, f, _, _ = run_filter(seq, imu_rpy=HUSKY_IMU_RPY, yaw_rate_fit_max_delay=0.0)
    return f.yaw_rate_fit.get('yaw_rate_scale', math.nan)


def husky_sensor_text(gyro: np.ndarray, accel: np.ndarray, wheels: np.ndarray,
                      ref: np.ndarray, bounds: dict) -> str:
    """Say which of the bounds' constants the Husky's own sensors could have told a filter."""
    bias, sem, first, still = standstill_gyro_bias(gyro, wheels)
    causal = score(**dead_reckoning(gyro, wheels[:, :2], bias, 1.0, bias_until=first), ref=ref)
    scale = bounds['bias_scale']['scale']
    given = score(**dead_reckoning(gyro, wheels[:, :2], bias, scale, bias_until=first), ref=ref)
    # the gyro minus the wheel yaw rate while driving straight: a bias learnt from the wheels
    w_at_gyro = np.interp(gyro[:, 0], wheels[:, 0], wheels[:, 2])
    v_at_gyro = np.interp(gyro[:, 0], wheels[:, 0], wheels[:, 1])
    straight = (np.abs(w_at_gyro) < 0.02) & (v_at_gyro > 0.5)
    from_wheels = float(np.mean(gyro[straight, 1] - w_at_gyro[straight]))
    finals = [score(**dead_reckoning(gyro, wheels[:, :2], b), ref=ref)['final']
              for b in np.linspace(-0.002, 0.002, 81)]
    events = accel_speed_events(accel, wheels[:, :2])
    ratios = ', '.join(f'{e[3]:.2f}' for e in events)
    med = float(np.median([e[3] for e in events])) if events else float('nan')
    shift = max((abs(e[4]) for e in events), default=float('nan'))
    return (
        'What the sensors can tell (no GPS): the wheels are still once, for '
        f'{still:.0f} s from {first - wheels[0, 0]:.0f} s on (the robot drives from its first '
        f'second); the gyro reads {bias:+.5f} +- {sem:.5f} rad/s there, against '
        f'{bounds["bias"]["bias"]:+.5f} for the best constant in hindsight. Dead reckoning '
        'with no bias until then and that standstill bias after it (no correction of the '
        f'past) scores ATE {causal["ate"]:.2f} m, final error {causal["final"]:.2f} m; given '
        "the bound's wheel-speed scale "
        f'({scale:.3f}) too, ATE {given["ate"]:.2f} m, final error {given["final"]:.2f} m. '
        'In motion the wheels cannot teach the bias: driving straight, the gyro minus the '
        f'wheel yaw rate averages {from_wheels:+.5f} rad/s, neither the standstill reading nor '
        'the hindsight constant. With the wheel speed as measured, no constant gyro bias in '
        '+-0.002 rad/s brings the final '
        f'error below {min(finals):.2f} m: the final goal needs the wheel-speed scale. The '
        "accelerometer's velocity change over the wheels' across the "
        f'{len(events)} speed changes of the run (baseline: its mean 2 s before and after) '
        f'is {ratios} (median {med:.2f}). Its baseline moves by up to {shift:.2f} m/s^2 '
        'across one speed change (g sin(pitch): the slopes of the lot, the pitch of the '
        'body), as much as the acceleration itself, so the 2-3 % scale the GPS prefers is '
        'not observable from this IMU (the simulation section gives the same '
        'ratio on flat simulated ground).')


def real_gps_data(lines: list) -> None:
    """Benchmark robot_pose_ekf's gps_data.bag (IMU acceleration in g, detected)."""
    seq, odoms, fixes = load_bag(SHARED / 'robot_pose_ekf' / 'gps_data.bag', '/imu/data',
                                 '/encoder', '/fix')
    ref = enu(fixes)
    rows = [('raw wheel odometry (/encoder)', score(**odom_track(odoms), ref=ref),
             (odoms[-1].x, odoms[-1].y))]
    units = ''
    for name, kw in [('seed-faithful', {'mode': 'seed'}), ('improved, default', {})]:
        tr, f, _, _ = run_filter(seq, **kw)
        rows.append((name, score(**tr, ref=ref), (f.state[0], f.state[1])))
        units = f.accel_units
    lines += ['## Real robot: robot_pose_ekf gps_data.bag (Husky 2013, 38 s)', '',
              f'IMU acceleration units: `accel_units: auto` -> **{units}** (the median |a| of '
              'the first 10 samples is about 1, so the filter multiplies by g and logs a '
              'warning). No IMU extrinsic is known for this bag: the up axis comes from gravity '
              "(`imu_extrinsic: auto`). robot_pose_ekf's own test expects its final (x, y) at "
              '(1.670, -3.850) +- 0.1 m in its `odom_combined` frame.', '',
              '| estimate | ATE vs GPS (m) | final error (m) | final x, y in odom frame (m) |',
              '|---|---|---|---|']
    for name, sc, (x, y) in rows:
        lines.append(f'| {name} | {fmt(sc["ate"])} | {fmt(sc["final"])} | '
                     f'{x:.3f}, {y:.3f} |')
    lines += ['', 'With 38 s and about 25 m of driving, GPS noise (1.4 m sigma reported) '
              'dominates the ATE of every estimate; the bag mainly checks the unit detection.',
              '']


# ---------------------------------------------------------------------------------------
# speed
# ---------------------------------------------------------------------------------------
def speed(lines: list, seq: list) -> None:
    """Pipeline throughput, full replay throughput and node callback p99."""
    from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
    keys = {'imu': 'imu', 'odom': 'odom'}
    rates, cpu_rates = [], []
    for _ in range(3):
        pipe = FusionPipeline(FusionParams(imu_rpy=HUSKY_IMU_RPY))
        t0, c0 = time.perf_counter(), time.process_time()
        for kind, s in seq:
            pipe.process(keys[kind], s)
        rates.append(len(seq) / (time.perf_counter() - t0))
        cpu_rates.append(len(seq) / (time.process_time() - c0))
    lines += ['## Speed', '', '| measure | value | goal | |', '|---|---|---|---|']
    rate, cpu_rate = float(np.median(rates)), float(np.median(cpu_rates))
    lines.append(f'| pipeline.process(), decoded samples of test1, wall clock (median of 3) | '
                 f'{rate:,.0f} msgs/s | >= 20,000 msgs/s | {"met" if rate >= 2e4 else "MISSED"} |')
    lines.append(f'| same, per CPU second of the process (median of 3) | {cpu_rate:,.0f} msgs/s '
                 f'| >= 20,000 msgs/s | {"met" if cpu_rate >= 2e4 else "MISSED"} |')
    bag = REPO / 'bags' / 'husky_test1'
    if bag.exists():
        try:
            from robot_calib.replay import replay
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                summ = replay([bag], Path(tmp) / 'out', nodes='odometry_fusion',
                              progress=False)
                el = time.perf_counter() - t0
            n = sum(v.get('read', 0) for v in
                    summ['nodes']['odometry_fusion']['inputs'].values())
            lines.append(f'| `robot-calib replay` bags/husky_test1 end to end (read, decode, '
                         f'fuse, write output.mcap and report) | {n / el:,.0f} msgs/s | '
                         f'>= 20,000 msgs/s | {"met" if n / el >= 2e4 else "MISSED"} |')
            outside = max(0.0, 1.0 - (n / el) / rate)
        except Exception as exc:  # noqa: B902 - report, do not fail the benchmark
            lines.append(f'| replay | failed: {exc} | | |')
    res = node_p99(seq)
    if res is not None:
        p99, cpu99 = res
        lines.append(f'| node callback p99, wall clock (in-process rclpy node: decode, fuse, '
                     f'encode, publish; test1 messages) | {p99 * 1e3:.3f} ms | < 1 ms | '
                     f'{"met" if p99 < 1e-3 else "MISSED"} |')
        lines.append(f'| node callback p99, CPU time of the callback thread (same run) | '
                     f'{cpu99 * 1e3:.3f} ms | < 1 ms | {"met" if cpu99 < 1e-3 else "MISSED"} |')
    share = (f' In this run {outside * 100:.0f} % of the end-to-end replay time was spent '
             'outside the pipeline (bag reading and decoding, output writing, report).'
             if 'outside' in locals() else '')
    load = ', '.join(f'{v:.1f}' for v in os.getloadavg())
    lines += ['', 'The machine is shared (2 cores, several jobs at once; load average '
              f'{load} at the end of these measurements): rates are lower '
              'bounds and the wall-clock p99 includes time the callback was preempted; the CPU '
              'time p99 is what the callback itself costs.' + share, '']


def node_p99(seq: list):
    """Return the p99 (s) of the node's message callback over the serialized bag samples."""
    try:
        import rclpy
        from robot_calib import codec
        from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
        from robot_calib.nodes.base import PipelineNode
    except ImportError:
        return None
    rclpy.init(args=['--ros-args', '-p', f'imu_rpy:={HUSKY_IMU_RPY}'])
    try:
        node = PipelineNode(FusionPipeline)
        msgs = []
        for kind, s in seq:
            msgtype, raw = codec.serialize(s)
            msgs.append((kind, msgtype, raw))
        cpu = []
        for kind, msgtype, raw in msgs:
            c0 = time.thread_time()
            node._on_message(kind, msgtype, raw)
            cpu.append(time.thread_time() - c0)
        p99 = node.callback_p99()
        node.destroy_node()
        return p99, float(np.percentile(cpu, 99))
    finally:
        rclpy.try_shutdown()


# ---------------------------------------------------------------------------------------
# simulation
# ---------------------------------------------------------------------------------------
def sim_seed(seed: int, duration: float) -> dict:
    """Run fusion_drive with ``seed``; return the scores of raw odometry, seed and default."""
    from robot_calib.sim import run_scenario
    r = run_scenario('fusion_drive', seed=seed, duration=duration)
    gt = np.array([[s.t, s.x, s.y, s.yaw] for tp, s in r.messages
                   if tp == '/ground_truth/odom'])
    odoms = [s for tp, s in r.messages if tp == '/odom']
    seq = r.inputs()
    out = {'raw': score(**odom_track(odoms), ref=gt)}
    tr, _, _, _ = run_filter(seq, mode='seed')
    out['seed'] = score(**tr, ref=gt)
    tr, f, el, covs = run_filter(seq)
    out['improved'] = score(**tr, ref=gt)
    out['nis'] = f.nis.in_band / max(f.nis.checked, 1)
    out['nis_window'] = f.nis.window_in_band / max(f.nis.window_checked, 1)
    out['nis_mean'] = f.nis.mean if f.nis.updates else float('nan')
    out['rate'] = len(seq) / el
    out['cov_pos'], out['cov_yaw'] = covariance_coverage(tr, covs, gt)
    out['bias_err'] = abs(f.state[IBG] - _true_bias(r.truth, gt[-1, 0]))
    accel = np.array([(s.t, float(s.accel[0])) for k, s in seq if k == 'imu'])
    wheels = np.array([(s.t, s.vx) for s in odoms])
    ratios = [e[3] for e in accel_speed_events(accel, wheels)]
    out['accel_scale'] = float(np.median(ratios)) if ratios else float('nan')
    out['accel_events'] = len(ratios)
    out['yaw_truth'] = odometry_yaw_rate_truth(r, odoms)
    out['yaw_fit'] = dict(f.yaw_rate_fit)
    sd = np.sqrt(np.diag(f.covariance))
    out['yaw_state'] = (f.state[IKW], sd[IKW], f.state[IKV], sd[IKV])
    return out


def odometry_yaw_rate_truth(r, odoms: list, latency: float = 0.0) -> tuple[float, float]:
    """
    Return the odometry's true yaw-rate scale and yaw rate per speed (-, rad/m).

    Least squares of the odometry yaw rate on the true one (``latency`` s before its stamp)
    and the odometry speed, outside the slip episodes (1 s margins): what the simulated
    wheels' radius and track errors make of the odometry.
    """
    gt_t, gt_w = r.sensors['gt_t'], r.sensors['gt_w']
    o = np.array([(s.t, s.vx, s.wz) for s in odoms])
    keep = np.ones(len(o), dtype=bool)
    episodes = np.asarray(r.params.wheels.slip_episodes, dtype=float).reshape(-1, 4)
    for t0, t1, _, _ in episodes:
        keep &= (o[:, 0] < t0 - 1.0) | (o[:, 0] > t1 + 1.0)
    a = np.column_stack((np.interp(o[:, 0] - latency, gt_t, gt_w), o[:, 1]))
    k = np.linalg.lstsq(a[keep], o[keep, 2], rcond=None)[0]
    return float(k[0]), float(k[1])


def _true_bias(truth: dict, t_end: float) -> float:
    """Return the true gyro z bias (rad/s) at the end of the run (bias + drift * t)."""
    b = truth.get('gyro_bias_z')
    if b is None:
        b = truth.get('gyro_bias', [0, 0, 0])[2]
    drift = truth.get('gyro_bias_drift', [0, 0, 0])
    drift = drift[2] if isinstance(drift, (list, tuple)) else float(drift)
    return float(b) + drift * (t_end - truth.get('start_time', 0.0))


def simulation(lines: list, seeds: int, duration: float, jobs: int) -> None:
    """Benchmark fusion_drive over ``seeds`` seeds."""
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        res = list(ex.map(sim_seed, range(seeds), [duration] * seeds))
    raw = np.array([r['raw']['ate'] for r in res])
    seed = np.array([r['seed']['ate'] for r in res])
    imp = np.array([r['improved']['ate'] for r in res])
    nis = np.array([r['nis'] for r in res])
    lines += [f'## Simulation: fusion_drive, {seeds} seeds x {duration:.0f} s', '',
              'Gyro z bias 0.005 rad/s + per-seed turn-on bias (sigma 0.003) drifting 2e-6 '
              'rad/s^2 with a random walk; wheel radius errors +1.0 % / -0.5 %, track width '
              '+4 %; three slip episodes; ground truth from the bag.', '',
              '| seed | ATE raw (m) | ATE seed mode (m) | ATE default (m) | heading err raw / '
              'seed / default (deg) | NIS in band (per update / 20-window) | gyro bias error '
              '(rad/s) |', '|---|---|---|---|---|---|---|']
    for i, r in enumerate(res):
        lines.append(
            f'| {i} | {r["raw"]["ate"]:.2f} | {r["seed"]["ate"]:.2f} | '
            f'{r["improved"]["ate"]:.2f} | {math.degrees(r["raw"]["heading"]):.1f} / '
            f'{math.degrees(r["seed"]["heading"]):.1f} / '
            f'{math.degrees(r["improved"]["heading"]):.1f} | {r["nis"]:.3f} / '
            f'{r["nis_window"]:.3f} | {r["bias_err"]:.5f} |')
    ratio_raw = imp / raw
    ratio_seed = imp / seed
    head = np.array([math.degrees(r['improved']['heading']) for r in res])
    lines += ['', '| goal | measured (median over seeds) | seeds meeting it | |',
              '|---|---|---|---|',
              f'| default ATE <= 50 % of raw odometry | {np.median(ratio_raw) * 100:.1f} % '
              f'(median ATE {np.median(imp):.2f} m vs {np.median(raw):.2f} m) | '
              f'{int(np.sum(ratio_raw <= 0.5))}/{seeds} | '
              f'{"met" if np.median(ratio_raw) <= 0.5 else "MISSED"} |',
              f'| default ATE <= 50 % of seed mode | {np.median(ratio_seed) * 100:.1f} % '
              f'(seed mode median {np.median(seed):.2f} m) | '
              f'{int(np.sum(ratio_seed <= 0.5))}/{seeds} | '
              f'{"met" if np.median(ratio_seed) <= 0.5 else "MISSED"} |',
              f'| NIS inside its 95 % band >= 90 % of updates | {np.median(nis) * 100:.1f} % | '
              f'{int(np.sum(nis >= 0.9))}/{seeds} | '
              f'{"met" if np.median(nis) >= 0.9 else "MISSED"} |', '',
              f'Default final heading error: median {np.median(head):.2f} deg. '
              'Output covariance (odometry frame = true start frame, no alignment): the '
              'position error is inside its 95 % ellipse for '
              f'{np.median([r["cov_pos"] for r in res]) * 100:.0f} % of the outputs and the '
              f'heading error inside 1.96 sigma for '
              f'{np.median([r["cov_yaw"] for r in res]) * 100:.0f} % (medians over seeds). '
              f'Mean per-update NIS (2 dof expected 2): '
              f'{np.median([r["nis_mean"] for r in res]):.2f}. The 20-update moving average '
              'of the NIS is in its (narrower) band '
              f'{np.median([r["nis_window"] for r in res]) * 100:.0f} % '
              'of the time: the innovations are time-correlated (wheel-speed lag and '
              'slip), which the averaged test exposes and the per-update test does not. '
              f'Core rate in simulation: {np.median([r["rate"] for r in res]):,.0f} msgs/s.',
              '', "Wheel-speed scale from the accelerometer (the Husky section's analysis, the "
              'simulated IMU mounted level): per run the median over its speed changes '
              f'({int(np.median([r["accel_events"] for r in res]))} per run, median) of the '
              "accelerometer's velocity change over the wheels' is "
              f'{np.median([r["accel_scale"] for r in res]):.3f} (median over seeds; from '
              f'{min(r["accel_scale"] for r in res):.3f} to '
              f'{max(r["accel_scale"] for r in res):.3f}); the simulated wheels over-read the '
              'speed by 0.25 % (radius errors +1.0 % and -0.5 %), a true ratio of 0.998.', '']
    yaw_rate_calibration_table(lines, res)


def late_seed(seed: int, latency: float, duration: float = 300.0) -> dict:
    """Run fusion_drive with odometry ``latency`` s late, without and with odometry_delay."""
    from robot_calib.sim import run_scenario
    r = run_scenario('fusion_drive', seed=seed, duration=duration,
                     overrides={'latency.odom': latency})
    gt = np.array([[s.t, s.x, s.y, s.yaw] for tp, s in r.messages
                   if tp == '/ground_truth/odom'])
    seq = r.inputs()
    truth = odometry_yaw_rate_truth(r, [s for tp, s in r.messages if tp == '/odom'], latency)
    out = {'seed': seed, 'latency': latency}
    for key, kw in (('blind', {}), ('auto', {'odometry_delay_auto': True}),
                    ('given', {'odometry_delay': latency}),
                    ('over', {'odometry_delay': latency + 0.2}),
                    ('no_search', {'yaw_rate_fit_max_delay': 0.0})):
        if key not in ('blind', 'auto') and latency == 0.0:
            continue
        tr, f, _, _ = run_filter(seq, **kw)
        fit = f.yaw_rate_fit
        out[key] = {'ate': score(**tr, ref=gt)['ate'],
                    'reinit': f.counts.get('reinitialisations', 0),
                    'delay': fit.get('odometry_delay', math.nan),
                    'delay_std': fit.get('odometry_delay_std', math.nan),
                    'scale_z': (fit['yaw_rate_scale'] - truth[0]) / fit['yaw_rate_scale_std']
                    if 'yaw_rate_scale' in fit else math.nan, 'status': fit['status'],
                    'applied': f.estimates['odometry_delay_applied']}
    return out


def late_odometry(lines: list, seeds: int, jobs: int) -> None:
    """Benchmark odometry_delay and the fit's delay on fusion_drive with late odometry."""
    seeds = max(seeds, 1)
    cases = [(seed, lat) for seed in range(seeds) for lat in (0.0, 0.15, 0.3)]
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        res = list(ex.map(late_seed, *zip(*cases)))
    lines += ['## Late wheel odometry, simulated (fusion_drive, odometry stamped late)', '',
              f'{seeds} seeds x 300 s; the odometry stamped t tells the motion of t - latency '
              "(the simulator's `latency.odom`), the IMU is on time. ATE after SE(2) "
              'alignment against ground truth. "not given": the defaults (`odometry_delay` '
              '0); "auto": `odometry_delay_auto`, which applies the delay once the yaw-rate '
              'fit is `ok` (after 8 blocks, 80 s of motion); "given": `odometry_delay` set to '
              'the latency '
              '(`odometry_fusion/delay.py`: the odometry used at the time it describes, the '
              "estimates carried to its stamps with the gyro). The yaw-rate fit's delay and "
              'its scale error over '
              'its std come from the run without `odometry_delay`; "no search": the same run '
              'with `yaw_rate_fit_max_delay: 0`, the fit before this section; "too large": '
              '`odometry_delay` set 0.2 s beyond the latency, where the fit must find the '
              'latency on the other side.', '',
              '| seed | latency (s) | ATE (m): not given / auto / given | delay applied by auto '
              "(s) | re-initialisations: not given / given | fit's delay (s): not given / too "
              'large | scale error / std: searched / no search |',
              '|---|---|---|---|---|---|---|']
    for r in res:
        b = r['blind']
        if r['latency'] == 0.0:
            a = r['auto']
            lines.append(f'| {r["seed"]} | 0 (on time) | {b["ate"]:.2f} / {a["ate"]:.2f} | '
                         f'{a["applied"]:.2f} | {b["reinit"]} | {b["delay"]:.2f} +- '
                         f'{b["delay_std"]:.2f} | {b["scale_z"]:+.1f} |')
            continue
        g, n, o, a = r['given'], r['no_search'], r['over'], r['auto']
        lines.append(f'| {r["seed"]} | {r["latency"]:.2f} | {b["ate"]:.2f} / {a["ate"]:.2f} / '
                     f'{g["ate"]:.2f} | {a["applied"]:.2f} | {b["reinit"]} / {g["reinit"]} | '
                     f'{b["delay"]:.2f} +- '
                     f'{b["delay_std"]:.2f} / {o["delay"]:.2f} +- {o["delay_std"]:.2f} | '
                     f'{b["scale_z"]:+.1f} / {n["scale_z"]:+.1f} |')
    late = [r for r in res if r['latency'] > 0]
    ratio = [r['given']['ate'] / on['blind']['ate'] for r in late for on in res
             if on['seed'] == r['seed'] and on['latency'] == 0.0]
    auto = [r['auto']['ate'] / on['blind']['ate'] for r in late for on in res
            if on['seed'] == r['seed'] and on['latency'] == 0.0]
    found = [abs(r[key]['delay'] - r['latency']) <= max(2 * r[key]['delay_std'], 0.021)
             for r in late for key in ('blind', 'over')]
    lines += ['', "With the delay given, the late runs' ATE over the on-time run's: median "
              f'{np.median(ratio):.2f} (max {max(ratio):.2f}); without it median '
              f'{np.median([r["blind"]["ate"] for r in late]):.2f} m against '
              f'{np.median([r["blind"]["ate"] for r in res if r["latency"] == 0]):.2f} m on '
              f'time, and with the delay applied once found {np.median(auto):.2f} of the on-time '
              f'ATE (median; max {max(auto):.2f}); on time `odometry_delay_auto` applied a '
              f'delay in '
              f'{sum(r["auto"]["applied"] != 0.0 for r in res if r["latency"] == 0)} of '
              f'{seeds} runs. The fit found the latency within 2 std (or one odometry '
              'interval) in '
              f'{sum(found)}/{len(found)} late runs, without the delay given or with too large '
              'a one; the summary then advises the `odometry_delay` to set.', '']


def slope_run(seed: int, compensate: bool, duration: float = 300.0) -> dict:
    """Run bumpy_drive (15 and 8 deg ramps) through the filter; return its speed errors."""
    from robot_calib.sim import run_scenario
    r = run_scenario('bumpy_drive', seed=seed, duration=duration)
    seq = r.inputs()
    run = run_batch(make_estimator(FusionParams(gravity_compensation=compensate)),
                    [s for _, s in seq], keep=from_odometry)
    f, gt = run.result, r.sensors
    t, x, y, v, yaw = np.array([(o.t, o.x, o.y, o.v, o.yaw) for o in run.outputs]).T
    heading = wrap_angle(yaw[-1] - np.interp(t[-1], gt['gt_t'], np.unwrap(gt['gt_yaw'])))
    err = np.abs(v - np.interp(t, gt['gt_t'], gt['gt_v']))
    pos = np.hypot(x - np.interp(t, gt['gt_t'], gt['gt_x']), y - np.interp(t, gt['gt_t'],
                                                                           gt['gt_y']))
    odom = np.array([(s.t, s.x, s.y) for k, s in seq if k == 'odom'])
    raw = np.hypot(odom[:, 1] - np.interp(odom[:, 0], gt['gt_t'], gt['gt_x']),
                   odom[:, 2] - np.interp(odom[:, 0], gt['gt_t'], gt['gt_y']))
    return {'rms': float(np.sqrt(np.mean(err ** 2))), 'max': float(err.max()),
            'raw_pos_max': float(raw.max()), 'heading': math.degrees(abs(float(heading))),
            'off': float(np.mean(err > 0.5)), 'pos_max': float(pos.max()),
            'rejected': f.counts.get('rejected_slip_speed', 0),
            'reinit': f.counts.get('reinitialisations', 0)}


def slopes(lines: list, seeds: int) -> None:
    """Benchmark the gravity compensation on bumpy_drive's ramps (300 s per seed)."""
    seeds = max(seeds, 1)
    lines += ['## Slopes, simulated (bumpy_drive, 15 and 8 deg ramps, bumps, hard braking)', '',
              f'{seeds} seeds x 300 s; the fused speed against the true speed along the '
              'ground, the position against the true horizontal position (the start pose '
              "from the odometry). This scenario's wheels have no errors, so its raw "
              'odometry is exact and the fused position drifts with the gyro (its z bias is '
              'learnt only at standstill): the speed is what is scored, and the heading shows '
              'what the body z rate on tilted ground added.', '',
              '| seed | gravity compensation | speed error RMS (m/s) | max (m/s) | time > 0.5 m/s '
              'off | max position error (m; raw odometry) | final heading error (deg) | wheel '
              'speeds rejected | re-initialisations |', '|---|---|---|---|---|---|---|---|---|']
    for seed in range(seeds):
        for comp in (False, True):
            r = slope_run(seed, comp)
            lines.append(f'| {seed} | {"on (default)" if comp else "off"} | {r["rms"]:.3f} | '
                         f'{r["max"]:.2f} | {r["off"] * 100:.1f} % | {r["pos_max"]:.2f} '
                         f'({r["raw_pos_max"]:.2f}) | {r["heading"]:.1f} | '
                         f'{r["rejected"]} | {r["reinit"]} |')
    lines.append('')


def yaw_rate_calibration_table(lines: list, res: list) -> None:
    """Score the reported odometry yaw-rate calibration against the simulated truth."""
    def z_scores(values):
        return np.array([[(v[0] - r['yaw_truth'][0]) / v[1], (v[2] - r['yaw_truth'][1]) / v[3]]
                         for v, r in zip(values, res)])

    fitted = [r for r in res if 'yaw_rate_scale' in r['yaw_fit']]
    fit_v = [(r['yaw_fit']['yaw_rate_scale'], r['yaw_fit']['yaw_rate_scale_std'],
              r['yaw_fit']['yaw_rate_per_speed'], r['yaw_fit']['yaw_rate_per_speed_std'])
             for r in fitted]
    z_fit = z_scores(fit_v) if fitted else np.zeros((0, 2))
    z_state = z_scores([r['yaw_state'] for r in res])
    ok = sum(r['yaw_fit']['status'] == 'ok' for r in res)
    truth = np.array([r['yaw_truth'] for r in res])

    def row(name, values, z):
        v = np.array(values)
        err = np.abs(v[:, [0, 2]] - truth[:len(v)]) if len(v) else np.zeros((0, 2))
        return (f'| {name} | {np.median(err[:, 0]):.4f} (max {err[:, 0].max():.4f}) | '
                f'{np.median(v[:, 1]):.4f} | {np.sqrt(np.mean(z[:, 0] ** 2)):.1f} '
                f'(max {np.abs(z[:, 0]).max():.1f}) | '
                f'{np.mean(np.abs(z[:, 0]) < 2) * 100:.0f} % | '
                f'{np.median(err[:, 1]):.4f} | {np.sqrt(np.mean(z[:, 1] ** 2)):.1f} '
                f'(max {np.abs(z[:, 1]).max():.1f}) | '
                f'{np.mean(np.abs(z[:, 1]) < 2) * 100:.0f} % |')

    lines += ['### Odometry yaw-rate calibration (`estimates.yaw_rate_scale`, '
              '`yaw_rate_per_speed`)', '',
              "Truth: the simulated odometry's yaw rate regressed on the true yaw rate and the "
              'odometry speed outside the slip episodes (scale '
              f'{np.median(truth[:, 0]):.4f}, per speed {np.median(truth[:, 1]):.4f} rad/m, '
              'medians). Reported: the fit over the recording (instrumental variables, one '
              "offset per 10 s block, block jackknife std). Before: the filter's random-walk "
              'states with their covariance, which the summary reported before (now '
              'internal).', '',
              '| estimate | scale abs. error (median) | scale std (median) | scale z RMS | '
              'scale within 2 std | per-speed abs. error (rad/m) | per-speed z RMS | '
              'per-speed within 2 std |', '|---|---|---|---|---|---|---|---|',
              row(f'fit over the recording ({ok}/{len(res)} ok, {len(fitted)} reported)',
                  fit_v, z_fit) if fitted else '| fit over the recording | none reported |',
              row('filter states (before)', [r['yaw_state'] for r in res], z_state), '']


def main() -> int:
    """Run the benchmark; write docs/bench/4-fusion.md."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--seeds', type=int, default=20)
    ap.add_argument('--duration', type=float, default=600.0)
    ap.add_argument('--jobs', type=int, default=2)
    ap.add_argument('--skip-sim', action='store_true')
    ap.add_argument('--keep-sim', action='store_true',
                    help='reuse the simulation section of the existing table')
    args = ap.parse_args()
    if not SHARED.is_dir():
        print(f'skipping: {SHARED} is absent')
        return 0
    metrics = __doc__.split('Metrics\n-------\n')[1].strip()
    lines = ['# Odometry fusion (issue 4)', '',
             'Generated by `benchmarks/bench_fusion.py` (`--seeds 20 --jobs 2`).', '',
             '**Method (default, `mode: improved`).** Planar EKF, state [x, y, yaw, v, gyro z '
             'bias, forward accel bias, wheel yaw-rate scale, wheel yaw rate per unit speed]; '
             'the IMU (rotated by its mounting: parameter, `/tf_static`, or the gravity '
             'direction) drives the prediction, the wheel speed and yaw rate are scalar updates '
             'gated at chi-square(1) 0.9999. The gyro bias is learnt at standstill, without '
             'moving the pose (`continuous_pose`: odom stays continuous, REP-105); the wheel '
             'yaw rate corrects only its own scale/offset (a Schmidt consider update), because '
             'slip, skid steering and radius mismatch mimic a gyro bias. Noise adaptation: one '
             'bounded scale per channel on its measurement AND process noise, driven to '
             'E[NIS] = 1 (only the total innovation variance is identifiable from a scalar '
             'channel; a multiplicative, clamped update stays positive definite where '
             'Sage-Husa can go negative; a few flops per update). On slopes the up direction '
             'in base_link is tracked (gyro, corrected over 5 s by the accelerometer less the '
             "wheels' acceleration) and gravity taken out of the forward force. The "
             'seed-faithful mode is '
             'seed 004 as written (6-state linear filter, S = P + P_o, K = P S^-1).', '',
             '**How the numbers are computed.**', '', metrics, '']
    husky = real_husky(lines)
    # speed first: the simulated sections' process pools leave the machine busy after them
    speed(lines, husky['seq'])
    real_gps_data(lines)
    slopes(lines, args.seeds // 4)
    late_odometry(lines, args.seeds // 4, args.jobs)
    if args.keep_sim and OUT.exists() and '## Simulation' in OUT.read_text():
        old = OUT.read_text()
        lines += old[old.index('## Simulation'):].rstrip('\n').split('\n') + ['']
    elif not args.skip_sim:
        simulation(lines, args.seeds, args.duration, args.jobs)
    text = '\n'.join(lines) + '\n'
    print(text)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
