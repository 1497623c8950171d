# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Tests of the loop-closure heading correction core (seed 001) and its pipeline."""

import math

import numpy as np
import pytest
from robot_calib.core import types as T
from robot_calib.core.estimator import run_batch
from robot_calib.core.frames import constant_motion, deskew
from robot_calib.core.geometry import se2_apply, se2_inverse, wrap_angle
from robot_calib.core.scan_match import MatchResult
from robot_calib.methods.loop_closure_correction import common, improved, params as lc, seed
from robot_calib.methods.loop_closure_correction.pipeline import LoopClosurePipeline
from robot_calib.methods.loop_closure_correction.report import heading_rmse
from robot_calib.methods.loop_closure_correction.variants import make_estimator
from scipy.spatial import cKDTree


def _room():
    """Return wall segments (K, 4) of a furnished 9 m x 7 m room (m)."""
    segs = [(0, 0, 9, 0), (9, 0, 9, 7), (9, 7, 0, 7), (0, 7, 0, 0)]
    for cx, cy, w, h in ((4.5, 3.5, 1.0, 0.6), (8.2, 6.0, 0.6, 0.8), (1.0, 5.5, 0.5, 0.5),
                         (6.5, 0.5, 0.8, 0.4)):
        x0, x1, y0, y1 = cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2
        segs += [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]
    segs += [(2.5, 6.9, 3.5, 6.2)]
    return np.array(segs, dtype=float)


def _other_room():
    """Return a differently shaped room (a kidnap destination) (m)."""
    return np.array([(-20, -20, -13, -20), (-13, -20, -15, -14), (-15, -14, -20, -14),
                     (-20, -14, -20, -20), (-17, -18, -16.5, -17.2)], dtype=float)


def _ranges(segs, pose, n=360, max_range=12.0, noise=0.005, rng=None):
    """Return ranges (m) of n beams over a full turn from ``pose`` (inf: no return)."""
    x, y, th = pose
    ang = th + np.arange(n) * 2 * math.pi / n
    d = np.column_stack((np.cos(ang), np.sin(ang)))
    a, b = segs[:, :2], segs[:, 2:] - segs[:, :2]
    o = np.array([x, y])
    den = d[:, None, 0] * b[None, :, 1] - d[:, None, 1] * b[None, :, 0]
    ao = a[None] - o[None, None]
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (ao[..., 0] * b[None, :, 1] - ao[..., 1] * b[None, :, 0]) / den
        u = (ao[..., 0] * d[:, None, 1] - ao[..., 1] * d[:, None, 0]) / den
    hit = (t > 0) & (u >= 0) & (u <= 1) & np.isfinite(t)
    r = np.where(hit, t, np.inf).min(axis=1)
    if rng is not None:
        r = r + rng.normal(0.0, noise, r.size)
    r[r > max_range] = np.inf
    return r


def _drive(laps=2, bias=0.004, seed=0, world=None, kidnap_step=None):
    """
    Simulate a robot driving a rectangle in the room: truth, imu, odom and scan samples.

    The gyro has a constant bias (rad/s); odometry distance is exact, odometry yaw
    is ignored by the corrector once the IMU arrives. With ``kidnap_step`` the robot
    is picked up before that plan step, carried into another room (wheels still,
    6 s) and set down there, where it drives on.
    """
    rng = np.random.default_rng(seed)
    world = world if world is not None else (lambda t: _room())
    corners = [(2.0, 1.5), (7.0, 1.5), (7.0, 5.5), (2.0, 5.5)]
    v, w = 0.5, 0.6
    # piecewise plan of (duration, v, w)
    plan = []
    for _ in range(laps):
        for i in range(4):
            a, b = corners[i], corners[(i + 1) % 4]
            plan.append((math.hypot(b[0] - a[0], b[1] - a[1]) / v, v, 0.0))
            plan.append((math.pi / 2 / w, 0.0, w))
    kidnap_at = None
    if kidnap_step is not None:
        kidnap_at = sum(p[0] for p in plan[:kidnap_step]) + 0.01
        plan.insert(kidnap_step, (6.0, 0.0, 0.0))
    dt = 0.02
    x, y, th = 2.0, 1.5, 0.0
    t = 0.0
    msgs, truth = [], []
    odo = np.zeros(3)
    k = 0
    for dur, vv, ww in plan:
        for _ in range(int(round(dur / dt))):
            t += dt
            k += 1
            x += vv * dt * math.cos(th + 0.5 * ww * dt)
            y += vv * dt * math.sin(th + 0.5 * ww * dt)
            th = wrap_angle(th + ww * dt)
            if kidnap_at is not None and abs(t - kidnap_at) < dt / 2:
                x, y = -17.0, -16.0                       # carried away, wheels still
            odo[0] += vv * dt * math.cos(odo[2] + 0.5 * ww * dt)
            odo[1] += vv * dt * math.sin(odo[2] + 0.5 * ww * dt)
            odo[2] = wrap_angle(odo[2] + ww * dt * 1.02)
            truth.append((t, x, y, th))
            gz = ww + bias + rng.normal(0, 1e-3)
            msgs.append(('imu', T.ImuSample(t, np.array([0.0, 0.0, gz]),
                                            np.array([0.0, 0.0, 9.81]))))
            if k % 2 == 0:
                msgs.append(('odom', T.OdomSample(t, odo[0], odo[1], odo[2], vx=vv, wz=ww)))
            if k % 5 == 0:
                segs = world(t)
                if kidnap_at is not None and t > kidnap_at:
                    segs = _other_room()
                r = _ranges(segs, (x, y, th), rng=rng)
                msgs.append(('scan', T.ScanSample(t, 0.0, 2 * math.pi / 360, r,
                                                  range_max=12.0)))
    return msgs, np.array(truth)


def _run(msgs, params=None):
    pipe = LoopClosurePipeline(params)
    odom, diags = [], []
    for key, s in msgs:
        for out_key, out in pipe.process(key, s):
            (odom if out_key == 'odom' else diags).append(out)
    return pipe, odom, diags


def _batch(msgs, params=None):
    """Run a variant over ``msgs``: its result and the corrected poses at the odometry times."""
    est = make_estimator(params)
    ts, poses = [], []

    def samples():
        for _, s in msgs:
            yield s
            if isinstance(s, T.OdomSample):
                ts.append(s.t)
                poses.append(est.result().pose)
    run = run_batch(est, samples())
    return run.result, np.array(ts), np.array(poses).reshape(-1, 3)


def _rmse(odom, truth):
    t = np.array([o.t for o in odom])
    yaw = np.array([o.yaw for o in odom])
    # the truth starts at heading 0, as the corrector does; the frames are shifted by (2, 1.5)
    return heading_rmse(t, yaw, truth[:, 0], truth[:, 3])


@pytest.fixture(scope='module')
def loop_run():
    msgs, truth = _drive(laps=2, bias=0.004)
    return msgs, truth, _run(msgs)


def test_closures_correct_heading_against_ground_truth(loop_run):
    msgs, truth, (pipe, odom, diags) = loop_run
    s = pipe.method_summary()
    assert s['closures_accepted'] >= 3
    raw, raw_t, raw_poses = _batch(
        msgs, lc.LoopClosureParams(detection=lc.DetectionParams(max_radius=0.0,
                                                                base_radius=0.0,
                                                                radius_gain=0.0),
                                   motion=lc.MotionParams(estimate_gyro_bias=False)))
    assert raw.summary()['closures_accepted'] == 0
    yaw_raw = raw_poses[:, 2]
    rmse_raw = heading_rmse(raw_t, yaw_raw, truth[:, 0], truth[:, 3])
    rmse = _rmse(odom, truth)
    assert rmse_raw > math.radians(2.0)        # 0.004 rad/s over 80 s of driving
    assert rmse < 0.3 * rmse_raw
    # every accepted closure moved the pose towards the truth (start at (2, 1.5), yaw 0)
    for r in pipe.estimator.result().closures:
        if not r.accepted:
            continue
        i = np.searchsorted(truth[:, 0], r.t)
        true_pose = np.array([truth[i, 1] - 2.0, truth[i, 2] - 1.5, truth[i, 3]])
        assert abs(wrap_angle(r.pose_after[2] - true_pose[2])) < math.radians(1.0)
        assert np.hypot(*(r.pose_after[:2] - true_pose[:2])) < 0.15
    # the gyro bias was learned from the scans
    assert s['gyro_bias'] == pytest.approx(0.004, abs=0.001)


def test_diagnostics_report_each_closure(loop_run):
    _, _, (pipe, odom, diags) = loop_run
    assert len(diags) == len(pipe.estimator.result().closures) > 0
    st = diags[0].statuses[0]
    keys = dict(st.values)
    for name in ('keyframes_tried', 'scores', 'correction_yaw', 'latency_ms', 'reason'):
        assert name in keys
    accepted = [d for d in diags if d.statuses[0].level == 0]
    assert accepted and float(dict(accepted[0].statuses[0].values)['latency_ms']) > 0
    summ = pipe.summary()
    assert summ['closures'] and {'keyframes_tried', 'scores', 'correction',
                                 'latency_ms'} <= set(summ['closures'][0])
    assert summ['outputs']['odom'] == len(odom)
    # output stamps are the input odometry stamps
    assert all(o.stamp_ns == round(o.t * 1e9) for o in odom[:10])


def test_seed_mode_runs_and_uses_centroid_heading(loop_run):
    msgs, truth, _ = loop_run
    pipe, odom, _ = _run(msgs, lc.LoopClosureParams(mode='seed'))
    s = pipe.method_summary()
    assert s['closures_accepted'] >= 1
    assert s['gyro_bias'] == 0.0                # the seed learns no bias
    assert np.all(np.isfinite([o.yaw for o in odom]))


def test_score_counts_inliers_and_outliers():
    cur = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    tree = cKDTree(cur)
    kf = np.array([[0.0, 0.05], [1.0, -0.05], [2.0, 0.5], [10.0, 0.0]])
    score, inl, out = common.score_candidate(kf, np.zeros(3), tree, 0.1, 1.0)
    assert (inl, out) == (2, 2) and score == pytest.approx(0.0)
    score, inl, out = common.score_candidate(kf, np.zeros(3), tree, 0.1, 0.5)
    assert score == pytest.approx((2 - 0.5 * 2) / 4)
    # shifting the keyframe by the candidate pose changes the count
    score, inl, _ = common.score_candidate(kf[:3] - [0, 0.5], np.array([0.0, 0.5, 0.0]), tree,
                                           0.1, 1.0)
    assert inl == 2


def test_centroid_heading_recovers_exact_heading():
    rng = np.random.default_rng(1)
    kf_pose = np.array([1.0, 2.0, 0.3])
    cur_pose = np.array([1.5, 2.4, 1.1])
    world = rng.uniform(-4, 4, (50, 2)) + [6, 6]
    kf_pts = se2_apply(se2_inverse(kf_pose), world)
    cur_pts = se2_apply(se2_inverse(cur_pose), world)
    th = seed.centroid_heading(kf_pose, kf_pts, cur_pose[:2], cur_pts)
    assert th == pytest.approx(1.1, abs=1e-9)


def _cand(kid, pose, score, degenerate=False, converged=True):
    m = MatchResult(pose=np.zeros(3), covariance=np.eye(3) * 1e-6, degenerate=degenerate,
                    converged=converged, inlier_ratio=0.9, min_eigenvalue=0.2)
    return common.Candidate(kid, 0.9, m, np.asarray(pose, float), score, 90, 10)


def test_choice_and_refusals():
    sp = lc.ScoringParams()

    def refusal(best, cands, here):
        return improved.refusal(best, cands, here, 0.2, 0.05, sp)
    here = np.zeros(3)
    best = _cand(1, [0.05, 0.0, 0.01], 0.8)
    agree = _cand(2, [0.08, 0.02, 0.012], 0.78)            # same hypothesis: supports it
    assert refusal(best, [best, agree], here) == ''
    rival = _cand(3, [1.0, 0.0, 0.01], 0.75)                 # a different place, as good
    assert refusal(best, [best, rival], here) == 'ambiguous'
    weak_rival = _cand(3, [1.0, 0.0, 0.01], 0.5)
    assert refusal(best, [best, weak_rival], here) == ''
    assert refusal(_cand(1, [0.05, 0, 0], 0.1), [], here) == 'low_score'
    assert refusal(_cand(1, [0.05, 0, 0], 0.8, degenerate=True), [], here) == 'degenerate'
    assert refusal(_cand(1, [0.05, 0, 0], 0.8, converged=False), [], here) == \
        'not_converged'
    assert refusal(_cand(1, [3.0, 0, 0], 0.8), [], here) == 'implausible_correction'
    assert refusal(_cand(1, [0.0, 0, 1.0], 0.8), [], here) == 'implausible_correction'
    # the seed takes the best whatever the rival or the Hessian says
    assert seed.refusal(_cand(1, [0.05, 0, 0], 0.8, degenerate=True), sp) == ''


def test_kidnapped_robot_restarts_the_map_and_makes_no_wrong_closure():
    msgs, truth = _drive(laps=2, bias=0.0, kidnap_step=7, seed=3)
    pipe, odom, diags = _run(msgs)
    s = pipe.method_summary()
    assert s['counts'].get('kidnaps', 0) >= 1
    assert any(d.statuses[0].level == 2 for d in diags)
    # after the kidnap the old map is gone: closures only within the new map, small fixes
    reports = pipe.estimator.result().closures
    kidnap_t = min(r.t for r in reports if r.reason == 'kidnap_suspected')
    carried = 2 * (5.0 / 0.5) + 2 * (4.0 / 0.5) + 3 * (math.pi / 2 / 0.6)
    assert carried < kidnap_t < carried + 6.0     # detected while still being carried
    later = [r for r in reports if r.accepted and r.t > kidnap_t]
    assert all(np.hypot(*r.correction[:2]) < 0.2 for r in later)
    assert s['segments'] >= 2


def test_moved_furniture_never_gives_a_wrong_correction():
    rng = np.random.default_rng(5)

    def world(t):
        segs = _room()
        if t > 40.0:   # the furniture (not the walls) is moved for the second lap
            segs = segs.copy()
            segs[4:] += np.tile(rng.uniform(-0.8, 0.8, 2), 2)
        return segs
    msgs, truth = _drive(laps=2, bias=0.003, world=world, seed=4)
    pipe, odom, diags = _run(msgs)
    for r in pipe.estimator.result().closures:
        if r.accepted:
            i = np.searchsorted(truth[:, 0], r.t)
            assert abs(wrap_angle(r.pose_after[2] - truth[i, 3])) < math.radians(1.5)
    counts = pipe.method_summary()['counts']
    assert counts.get('closure_attempts', 0) >= 1


def test_scans_with_few_valid_beams_are_rejected_and_counted():
    pipe = LoopClosurePipeline()
    pipe.process('odom', T.OdomSample(0.0, 0.0, 0.0, 0.0))
    r = np.full(360, np.nan)
    r[:10] = 2.0
    r[10:20] = np.inf
    out = pipe.process('scan', T.ScanSample(0.1, 0.0, 2 * math.pi / 360, r))
    assert out == []
    bad_geometry = T.ScanSample(0.2, math.nan, 0.01, np.ones(360))
    assert pipe.process('scan', bad_geometry) == []
    counts = pipe.summary()['inputs']['scan']
    assert counts['rejected_few_valid_beams'] == 1 and counts['rejected_non_finite'] == 1
    assert pipe.estimator.result().counts['scans_used'] == 0


def test_corridor_closure_is_refused_as_degenerate():
    """Driving up and down a featureless corridor: the along-corridor fix is refused."""
    corridor = np.array([(-40, -1, 40, -1), (-40, 1, 40, 1)], dtype=float)
    c = improved.ImprovedLoopClosure()
    rng = np.random.default_rng(2)
    t = 0.0
    x = 0.0
    for leg in (1, -1, 1):
        for _ in range(60):          # 6 m per leg at 0.5 m/s, 10 Hz
            t += 0.1
            x += 0.05 * leg
            c.update(T.OdomSample(t, x, 0.0, 0.0))
            r = _ranges(corridor, (x, 0.0, 0.0), rng=rng)
            c.update(T.ScanSample(t, 0.0, 2 * math.pi / 360, r))
    reports = c.result().closures
    reasons = [r.reason for r in reports]
    assert 'degenerate' in reasons or 'no_similar_keyframe' in reasons
    assert not any(r.accepted for r in reports)


def test_memory_is_bounded_by_the_grid():
    params = lc.LoopClosureParams(keyframes=lc.KeyframeParams(max_per_cell=2, cell_size=5.0))
    msgs, _ = _drive(laps=3, bias=0.0, seed=6)
    res = run_batch(make_estimator(params), [s for _, s in msgs]).result
    assert res.summary()['keyframes'] <= 2 * 4          # the rectangle spans 4 cells of 5 m
    assert res.summary()['counts']['keyframes_skipped_full'] > 0


def test_voxel_thin_and_deskew():
    pts = np.array([[0.0, 0.0], [0.01, 0.01], [0.5, 0.5], [0.51, 0.5]])
    assert len(common.voxel_thin(pts, 0.1)) == 2
    p = np.array([[1.0, 0.0]])
    out = deskew(p, constant_motion(1.0, math.pi / 2)(np.array([0.1])))
    th = math.pi / 20
    np.testing.assert_allclose(out, [[math.cos(th) + 0.1, math.sin(th)]])


def test_pose_graph_baseline_closes_a_loop():
    from robot_calib.core.geometry import se2_between, se2_compose
    from robot_calib.methods.loop_closure_correction import pose_graph as pg
    # a square of 4 x 4 m driven with a heading error of 2 deg per side
    truth = [np.array([0.0, 0.0, 0.0])]
    for k in range(8):
        step = np.array([2.0, 0.0, math.pi / 2 if k % 2 == 1 else 0.0])
        truth.append(se2_compose(truth[-1], step))
    truth = np.array(truth)
    odo = [se2_between(truth[k], truth[k + 1]) + [0.0, 0.0, math.radians(2.0)]
           for k in range(8)]
    init = [truth[0]]
    for z in odo:
        init.append(se2_compose(init[-1], z))
    init = np.array(init)
    edges = [pg.Edge(k, k + 1, odo[k], 0.05, 0.05) for k in range(8)]
    edges.append(pg.Edge(0, 8, se2_between(truth[0], truth[8]), 0.01, 0.002))
    out, info = pg.optimise(init, edges)
    assert info['nodes'] == 9 and info['edges'] == 9 and info['nfev'] >= 1
    err_before = np.hypot(*(init[8, :2] - truth[8, :2]))
    err_after = np.hypot(*(out[8, :2] - truth[8, :2]))
    assert err_before > 0.3 and err_after < 0.05
    assert abs(wrap_angle(out[8, 2] - truth[8, 2])) < math.radians(0.5)
    np.testing.assert_allclose(out[0], truth[0])          # the first node stays fixed


def test_variants_are_estimators_with_a_frozen_result():
    import dataclasses
    from robot_calib.core.estimator import Estimator
    msgs, _ = _drive(laps=1, bias=0.0, seed=7)
    for mode in ('seed', 'improved'):
        est = make_estimator(lc.LoopClosureParams(mode=mode))
        assert isinstance(est, Estimator) and est.result().mode == mode
        run = run_batch(est, [s for _, s in msgs])
        assert run.outputs and run.outputs == list(run.result.closures)
        with pytest.raises(dataclasses.FrozenInstanceError):
            run.result.gyro_bias = 1.0
        est.reset()
        assert est.result().keyframes == 0 and est.result().closures == ()
