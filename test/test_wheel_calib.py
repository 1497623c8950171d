# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Wheel calibration core: kinematics, solvers on exact synthetic data, seed logic, bad input."""

import math

import numpy as np
import pytest
from robot_calib.core import kinematics as K
from robot_calib.core.estimator import run_batch
from robot_calib.methods.wheel_odometry_calibration import params as P
from robot_calib.methods.wheel_odometry_calibration import solver as S
from robot_calib.methods.wheel_odometry_calibration.improved import ImprovedWheelCalibrator
from robot_calib.methods.wheel_odometry_calibration.stages import SeedSteeredCalibrator
import yaml

DIFF_TRUTH = {'left_wheel_radius': 0.0504, 'right_wheel_radius': 0.0497, 'track_width': 0.306,
              'lidar_x': 0.12, 'lidar_y': -0.03, 'lidar_yaw': 0.05}
STEER_TRUTH = {'steering_offset': 0.02, 'steering_scale': 1.03, 'wheel_radius': 0.1012,
               'wheel_base': 1.01, 'lidar_x': 0.5, 'lidar_y': 0.02, 'lidar_yaw': -0.03}


def _params(drive, **kw):
    diff = drive == 'differential'
    base = {'drive_type': drive, 'wheel_radius': 0.05 if diff else 0.1, 'wheel_base': 1.0,
            'track_width': 0.3, 'lidar_x': 0.1 if diff else 0.5}
    base.update(kw)
    return P.WheelCalibParams(**base)


def _diff_segments(rng, n=120, noise=(0.0, 0.0, 0.0), kind='mixed'):
    segs = []
    for i in range(n):
        k = 10
        if kind == 'straight' or (kind == 'mixed' and i % 3 == 0):
            v = rng.uniform(4.0, 8.0) * (1 if i % 2 else -1) if kind == 'mixed' else 6.0
            steps = np.tile([v, v], (k, 1)) / k
        elif kind == 'spin' or (kind == 'mixed' and i % 3 == 1):
            w = rng.uniform(2.0, 4.0) * (1 if i % 2 else -1)
            steps = np.tile([-w, w], (k, 1)) / k
        else:
            a, b = rng.uniform(2.0, 8.0, 2) * (1 if i % 2 else -1)
            steps = np.tile([a, b], (k, 1)) / k
        segs.append(K.Segment(i, i + 1, steps, np.zeros(3)))
    x = np.array([DIFF_TRUTH[k] for k in P.DIFF_KEYS])
    pred = S.predict('differential', x, S.pad_steps(segs))
    for s, p in zip(segs, pred):
        s.sensor_motion = p + rng.normal(0.0, 1.0, 3) * np.asarray(noise)
    return segs


def _steer_segments(rng, n=150, noise=(0.0, 0.0, 0.0), kind='mixed', truth=STEER_TRUTH):
    segs = []
    for i in range(n):
        k = 8
        if kind == 'straight' or (kind == 'mixed' and i % 2 == 0):
            reading = rng.normal(0.0, 0.005, k)
        elif kind == 'left':
            reading = np.full(k, rng.uniform(0.2, 0.8))
        else:
            reading = np.full(k, rng.uniform(0.2, 0.8) * (1 if i % 4 == 1 else -1))
        dphi = np.full(k, rng.uniform(2.0, 4.0) / k)
        segs.append(K.Segment(i, i + 1, np.column_stack((dphi, reading)), np.zeros(3)))
    x = np.array([truth[k] for k in P.STEER_KEYS])
    pred = S.predict('steered_wheel', x, S.pad_steps(segs))
    for s, p in zip(segs, pred):
        s.sensor_motion = p + rng.normal(0.0, 1.0, 3) * np.asarray(noise)
    return segs


# -- kinematics ----------------------------------------------------------------------------
def test_arc_pose_straight_quarter_circle_and_compose_inverse():
    np.testing.assert_allclose(K.arc_pose(2.0, 0.0), [2.0, 0.0, 0.0])
    # a quarter circle of radius 1: arc length pi/2 ends at (1, 1) heading +90 deg
    np.testing.assert_allclose(K.arc_pose(math.pi / 2, math.pi / 2), [1.0, 1.0, math.pi / 2],
                               atol=1e-12)
    a = np.array([0.3, -0.2, 0.7])
    np.testing.assert_allclose(K.compose(a, K.inverse(a)), np.zeros(3), atol=1e-12)
    o = np.array([0.5, 0.1, 0.2])
    lp = np.array([0.3, 0.05, 0.4])
    np.testing.assert_allclose(K.base_motion_from_sensor(K.sensor_motion(o, lp), lp), o,
                               atol=1e-12)


def test_integrate_steps_equals_composing_step_by_step():
    rng = np.random.default_rng(4)
    steps = rng.normal(size=(6, 40, 3)) * [0.05, 0.01, 0.2]
    steps[2, 25:] = 0.0                               # a shorter, zero-padded segment
    expected = np.zeros((6, 3))
    for k in range(steps.shape[1]):
        expected = K.compose(expected, steps[:, k])
    np.testing.assert_allclose(K.integrate_steps(steps), expected, atol=1e-12)
    # a circle of 8 equal arcs comes back to its start, heading one turn on
    arc = K.arc_pose(math.pi / 4, math.pi / 4)
    np.testing.assert_allclose(K.integrate_steps(np.tile(arc, (1, 8, 1))),
                               [[0.0, 0.0, 2 * math.pi]], atol=1e-12)
    assert K.integrate_steps(np.zeros((2, 0, 3))).shape == (2, 3)
    # arcs integrated by their chords: the same motion as arc poses composed one by one
    ds, dth = steps[..., 0], steps[..., 2]
    np.testing.assert_allclose(K.integrate_arcs(ds, dth), K.integrate_steps(K.arc_pose(ds, dth)),
                               atol=1e-12)


@pytest.mark.parametrize('drive', ['differential', 'steered_wheel'])
def test_packed_steps_predict_as_padded(drive):
    """The joint fit's packed steps (no padding) give the padded model's motion, any subset."""
    rng = np.random.default_rng(4)
    segs = [K.Segment(0.0, 1.0, rng.normal(0.0, 0.3, (int(rng.integers(1, 60)), 2)),
                      np.zeros(3)) for _ in range(200)]
    truth = DIFF_TRUTH if drive == 'differential' else STEER_TRUTH
    x = np.array([truth[k] for k in P.keys_of(drive)])
    packed, padded = S.PackedSteps.of(segs), S.pad_steps(segs)
    assert len(packed) == 200
    np.testing.assert_allclose(S.predict(drive, x, packed), S.predict(drive, x, padded),
                               rtol=0, atol=1e-12)
    mask = rng.random(200) < 0.6
    np.testing.assert_allclose(S.predict(drive, x, packed[mask]),
                               S.predict(drive, x, padded[mask]), rtol=0, atol=1e-12)
    # another lidar pose reuses the remembered base motion: still the same model
    x2 = x.copy()
    x2[-3:] += (0.01, -0.02, 0.03)
    assert S.base_motion(drive, x2, packed) is S.base_motion(drive, x, packed)
    np.testing.assert_allclose(S.predict(drive, x2, packed), S.predict(drive, x2, padded),
                               rtol=0, atol=1e-12)
    x3 = x.copy()
    x3[0] *= 1.01
    assert not np.allclose(S.predict(drive, x3, packed), S.predict(drive, x, packed))
    np.testing.assert_allclose(S.predict(drive, x3, packed), S.predict(drive, x3, padded),
                               rtol=0, atol=1e-12)


def test_calibrated_odometry_poses_are_the_composed_arcs():
    """The re-deskew's odometry (running sums) is the arcs composed one by one."""
    from robot_calib.methods.wheel_odometry_calibration.wheels import integrate, WheelHistory
    rng = np.random.default_rng(5)
    x = np.array([DIFF_TRUTH[k] for k in P.DIFF_KEYS])
    hist = WheelHistory('differential', x, 0.5)
    a = b = 0.0
    for i in range(3000):
        a, b = a + rng.normal(0.2, 0.1), b + rng.normal(0.2, 0.1)
        hist.add(0.02 * i, a, b)
    steps = np.diff(np.column_stack((hist.a, hist.b)), axis=0)
    arcs = K.arc_pose(*K.diff_arc(steps[:, 0], steps[:, 1], *x[:3]))
    expected = [np.zeros(3)]
    for arc in arcs:
        expected.append(K.compose(expected[-1], arc))
    poses = integrate('differential', hist.a, hist.b, x)
    assert poses.shape == (3000, 3)
    np.testing.assert_allclose(poses, np.array(expected), rtol=0, atol=1e-10)


def test_steered_and_diff_arc_by_hand():
    # steered wheel at 30 deg, 1 rad of a 0.1 m wheel, wheel base 0.5:
    ds, dth = K.steered_arc(1.0, 0.5236 - 0.01, 0.1, 0.5, offset=0.01)
    assert ds == pytest.approx(0.1 * math.cos(0.5236))
    assert dth == pytest.approx(0.1 * math.sin(0.5236) / 0.5)
    # differential: right wheel faster turns left
    ds, dth = K.diff_arc(1.0, 2.0, 0.05, 0.05, 0.3)
    assert ds == pytest.approx(0.075) and dth == pytest.approx(0.05 / 0.3)


# -- solvers on exact synthetic data -------------------------------------------------------
def test_censi_closed_form_exact():
    segs = _diff_segments(np.random.default_rng(1))
    x = S.censi_closed_form(segs)
    np.testing.assert_allclose(x, [DIFF_TRUTH[k] for k in P.DIFF_KEYS], atol=1e-9)


def test_joint_fit_differential_recovers_truth_with_honest_std():
    rng = np.random.default_rng(2)
    segs = _diff_segments(rng, n=300, noise=(0.002, 0.002, 0.001))
    res = S.calibrate('differential', segs, _params('differential'))
    assert res.verdict == 'converged', res.verdict
    for k in P.DIFF_KEYS:
        assert abs(res.values[k] - DIFF_TRUTH[k]) < 4 * res.stds[k], k
        assert res.stds[k] > 0
    assert res.segments_used >= 290


def test_joint_fit_steered_recovers_truth_from_far_nominal():
    rng = np.random.default_rng(3)
    segs = _steer_segments(rng, noise=(0.001, 0.001, 0.0003))
    # nominal far from the truth: scale 0.5 instead of 1.03, no lidar yaw knowledge
    p = _params('steered_wheel', steering_scale=0.5)
    res = S.calibrate('steered_wheel', segs, p)
    assert res.verdict == 'converged', res.verdict
    for k in P.STEER_KEYS:
        assert abs(res.values[k] - STEER_TRUTH[k]) < 4 * res.stds[k], k


def test_slip_in_one_segment_is_rejected():
    rng = np.random.default_rng(4)
    segs = _diff_segments(rng, n=150, noise=(0.001, 0.001, 0.0005))
    segs[9].sensor_motion = segs[9].sensor_motion * np.array([0.6, 0.6, 1.0])  # wheel slip
    res = S.calibrate('differential', segs, _params('differential'))
    assert res.details['outliers'] >= 1
    assert res.verdict == 'converged'
    assert abs(res.values['left_wheel_radius'] - DIFF_TRUTH['left_wheel_radius']) < 1e-4


# -- degenerate drives: never a confident wrong answer ------------------------------------
def test_steered_no_turns_is_not_converged():
    segs = _steer_segments(np.random.default_rng(5), kind='straight',
                           noise=(0.001, 0.001, 0.0003))
    res = S.calibrate('steered_wheel', segs, _params('steered_wheel'))
    assert res.verdict != 'converged'
    assert 'turn both ways' in res.verdict
    assert res.stds['steering_scale'] > 0.01  # scale unobservable: large, honest std


def test_steered_one_way_turns_asks_for_both_ways():
    segs = _steer_segments(np.random.default_rng(6), kind='left', noise=(0.001, 0.001, 0.0003))
    res = S.calibrate('steered_wheel', segs, _params('steered_wheel'))
    assert 'turn both ways' in res.verdict


def test_diff_only_spinning_says_straight_segments_missing():
    segs = _diff_segments(np.random.default_rng(7), kind='spin', noise=(0.001, 0.001, 0.0005))
    res = S.calibrate('differential', segs, _params('differential'))
    assert res.verdict != 'converged'
    assert 'straight' in res.verdict


def test_too_little_data():
    segs = _diff_segments(np.random.default_rng(8), n=6)
    res = S.calibrate('differential', segs, _params('differential'))
    assert res.verdict.lower().startswith('too little data')
    res = S.calibrate('differential', [], _params('differential'))
    assert res.verdict.startswith('Too little data')
    assert res.segments_used == 0


# -- seed 003 gate / counter ---------------------------------------------------------------
def _stage(offset_true, comp_reading=0.0, travel_rad=30.0, params=None, scene_noise=0.0):
    """Return a straight stage: constant reading, the scene rotation the true offset gives."""
    p = params
    k = 20
    steps = np.column_stack((np.full(k, travel_rad / k), np.full(k, comp_reading)))
    x = np.array([offset_true, p.steering_scale, p.wheel_radius, p.wheel_base,
                  p.lidar_x, p.lidar_y, p.lidar_yaw])
    sm = S.predict('steered_wheel', x, steps[None])[0]
    sm[2] += scene_noise
    return K.Segment(0.0, 1.0, steps, sm)


def test_seed_stage_offset_solves_rotation_equation():
    p = _params('steered_wheel', mode='seed')
    cal = SeedSteeredCalibrator(p)
    seg = _stage(0.0123, comp_reading=-0.004, params=p)
    assert cal.stage_offset(seg) == pytest.approx(0.0123, abs=1e-9)


def test_seed_gate_counter_reset_and_convergence():
    p = _params('steered_wheel', mode='seed')
    p.seed.consecutive_stages = 3
    p.seed.offset_threshold = 0.001
    cal = SeedSteeredCalibrator(p)
    true_off = 0.02
    r0 = cal.update(_stage(true_off, params=p))
    # first stage: compensation 0, residual = the whole offset: gate closed
    assert not r0.accepted and r0.counter == 0 and r0.compensation == 0.0
    assert cal.compensation == pytest.approx(true_off)
    r1 = cal.update(_stage(true_off, params=p))
    assert r1.accepted and r1.counter == 1
    # a disturbed stage (bad match) clears the candidate set and resets the counter
    r2 = cal.update(_stage(true_off, params=p, scene_noise=0.01))
    assert not r2.accepted and r2.counter == 0 and not cal.candidates
    cal.update(_stage(true_off, params=p))  # compensation from the bad stage: rejected again
    for _ in range(3):
        cal.update(_stage(true_off, params=p))
    assert cal.offset == pytest.approx(true_off, abs=1e-9)
    assert cal.radius == pytest.approx(p.wheel_radius, rel=1e-6)
    assert cal.stages_needed == len(cal.records)
    res = cal.result()
    assert res.verdict == 'converged' and res.segments_used == 3


def test_seed_radius_from_scene_displacement():
    p = _params('steered_wheel', mode='seed')
    p.seed.consecutive_stages = 2
    truth = P.WheelCalibParams(**{**p.__dict__, 'wheel_radius': 0.1015})
    cal = SeedSteeredCalibrator(p)
    for _ in range(4):
        cal.update(_stage(0.0, params=truth))
    assert cal.radius == pytest.approx(0.1015, rel=1e-6)


def test_seed_without_stages_says_what_is_missing():
    res = SeedSteeredCalibrator(_params('steered_wheel', mode='seed')).run([])
    assert res.verdict != 'converged' and 'straight' in res.verdict
    assert math.isnan(res.stds['wheel_base'])


# -- result format -------------------------------------------------------------------------
def test_yaml_is_the_contract_format():
    segs = _steer_segments(np.random.default_rng(9), noise=(0.001, 0.001, 0.0003))
    res = S.calibrate('steered_wheel', segs, _params('steered_wheel'))
    d = yaml.safe_load(res.to_yaml())
    assert list(d)[0] == 'drive_type' and d['drive_type'] == 'steered_wheel'
    for k in P.STEER_KEYS:
        assert isinstance(d[k], float) and isinstance(d[k + '_std'], float)
    assert d['segments_used'] == res.segments_used and d['verdict'] == res.verdict
    assert list(d)[-2:] == ['segments_used', 'verdict']
    seed = SeedSteeredCalibrator(_params('steered_wheel', mode='seed')).result()
    d = yaml.safe_load(seed.to_yaml())
    assert math.isnan(d['wheel_base_std'])


# -- streaming front end with an exact matcher --------------------------------------------
class _TruthWorld:
    """A robot whose true sensor poses are known: an exact (or failing) matcher."""

    def __init__(self, drive, truth, fail_every=0):
        self.drive, self.truth, self.fail_every = drive, truth, fail_every
        self.poses = {}
        self.calls = 0

    def prepare(self, points):
        return points

    def matcher(self, source, target, guess):
        self.calls += 1
        if self.fail_every and self.calls % self.fail_every:
            return None
        a, b = self.poses[id(target)], self.poses[id(source)]
        return K.compose(K.inverse(a), b), {}


def _stream(drive, truth, wrap_steering=False, wrap_traction=False, fail_every=0, t_end=120.0):
    """Yield wheel samples and scans of a drive with straights and turns both ways."""
    from robot_calib.core import types as T
    world = _TruthWorld(drive, truth, fail_every)
    keys = P.keys_of(drive)
    x = np.array([truth[k] for k in keys])
    dt = 0.02
    pose = np.zeros(3)
    a = b = 0.0
    samples = []
    for i in range(int(t_end / dt)):
        t = i * dt
        phase = int(t // 10.0) % 4
        if drive == 'differential':
            wl, wr = [(6.0, 6.0), (2.0, 6.0), (6.0, 6.0), (6.0, 2.0)][phase]
            da, db = wl * dt, wr * dt
            step = np.array([[da, db]])
            a, b = a + da, b + db
            names, pos = ('left_wheel_joint', 'right_wheel_joint'), (a, b)
        else:
            reading = [0.0, 0.5, 0.0, -0.5][phase] - 0.02
            da = 3.0 * dt
            # the front end integrates a step with the mean of its end readings
            step = np.array([[da, 0.5 * (b + reading) if i else reading]])
            a, b = a + da, reading
            names, pos = ('traction_joint', 'steering_joint'), (a, b)
        pose = K.compose(pose, S.base_motion(drive, x, step[None])[0])
        pa, pb = pos
        if wrap_traction:
            pa = math.remainder(pa, 2 * math.pi)
        if wrap_steering:
            pb = pb % (2 * math.pi)
        samples.append(T.JointStateSample(t, names, np.array([pa, pb]), np.full(2, np.nan)))
        if i % 5 == 0:
            ranges = np.full(8, 2.0)
            scan = T.ScanSample(t, 0.0, 0.7, ranges)
            world.poses[id(scan)] = K.compose(pose, x[-3:])
            samples.append(scan)
    return world, samples


@pytest.mark.parametrize('drive', ['differential', 'steered_wheel'])
def test_front_end_exact_stream(drive):
    truth = DIFF_TRUTH if drive == 'differential' else STEER_TRUTH
    world, samples = _stream(drive, truth)
    p = _params(drive)
    cal = ImprovedWheelCalibrator(p, matcher=world.matcher, prepare=world.prepare,
                                  periodic=False)
    cal.front.deskewed_points = lambda scan: scan  # the fake matcher needs the scan identity
    res = run_batch(cal, samples).result
    for k in P.keys_of(drive):
        assert res.values[k] == pytest.approx(truth[k], abs=1e-5), k
    if drive == 'steered_wheel':
        assert res.counts['stages'] >= 3


@pytest.mark.parametrize('drive', ['differential', 'steered_wheel'])
def test_long_drive_keeps_bounded_segments_and_wheel_data(drive):
    """Past max_segments every other segment goes; the rest still span the whole drive."""
    from robot_calib.methods.wheel_odometry_calibration import wheels as W
    truth = DIFF_TRUTH if drive == 'differential' else STEER_TRUTH
    world, samples = _stream(drive, truth, t_end=480.0)
    cal = ImprovedWheelCalibrator(_params(drive, max_segments=40), matcher=world.matcher,
                                  prepare=world.prepare, periodic=False)
    cal.front.deskewed_points = lambda scan: scan
    run = run_batch(cal, samples)
    front, res = cal.front, run.result
    for k in P.keys_of(drive):
        assert res.values[k] == pytest.approx(truth[k], abs=1e-5), k
    kept = front.segments
    assert 20 < len(kept) <= 40 and front.stride >= 4 and front.stride & (front.stride - 1) == 0
    assert res.counts['segments_thinned'] == front.segments_cut - len(kept)
    assert kept[0].t0 < 5.0 and kept[-1].t1 > 480.0 - 3 * front.stride
    gaps = np.diff([seg.t0 for seg in kept])
    assert gaps.max() < 3.0 * np.median(gaps)                    # evenly thinned
    notes = [m for u in run.outputs for _, m in u.notes if 'max_segments' in m]
    assert len(notes) == int(math.log2(front.stride))           # one note per doubling
    # the wheel history keeps the recent part only: 24000 samples went in
    assert res.counts['wheel_samples'] == 24000
    assert len(front.wheels.t) < 2 * W.TRIM_MIN_SAMPLES + W.TRIM_MARGIN / 0.02


def test_redeskew_from_the_wheel_window_equals_the_whole_drive():
    """A scan's motion integrated from its own window equals the whole drive's integration."""
    from robot_calib.core import types as T
    from robot_calib.methods.wheel_odometry_calibration import wheels as W
    rng = np.random.default_rng(8)
    x_nom = np.array([0.05, 0.05, 0.3, 0.1, -0.02, 0.04])
    x = x_nom * np.array([1.01, 0.99, 1.02, 1.0, 1.0, 1.0])
    hist = W.WheelHistory('differential', x_nom, 0.5)
    a = b = 0.0
    for i in range(6000):
        a, b = a + rng.normal(0.3, 0.1), b + rng.normal(0.32, 0.1)
        hist.add(0.01 * i, a, b)
    whole = W.integrate('differential', hist.a, hist.b, x)
    dt = np.arange(360) * (0.1 / 360)
    for stamp in rng.uniform(1.0, 59.0, 10):
        scan = T.ScanSample(stamp, -math.pi, 2 * math.pi / 360, np.ones(360),
                            time_increment=0.1 / 360, scan_time=0.1)
        win = hist.window(scan)
        assert len(win.t) < 15
        local = W.motion(scan, win.t, W.integrate('differential', win.a, win.b, x), x[-3:])
        want = W.motion(scan, np.array(hist.t), whole, x[-3:])
        assert np.allclose(local(dt), want(dt), rtol=0.0, atol=1e-12)
        assert np.ptp(want(dt)[:, 0]) > 1e-3
    assert hist.trim_before(30.0) == 0                  # fewer than TRIM_MIN_SAMPLES to drop
    kept_pose, last = hist.pose[5899], (hist.t[-1], hist.a[-1], hist.b[-1])
    dropped = hist.trim_before(59.0 + W.TRIM_MARGIN)    # keeps one sample before 59 s
    assert dropped == 5899 and hist.t[0] < 59.0 <= hist.t[1]
    assert len(hist.pose) == len(hist.t) == len(hist.a) == len(hist.b) == 101
    assert np.array_equal(hist.pose[0], kept_pose) and (hist.t[-1], hist.a[-1], hist.b[-1]) == last


def test_front_end_steering_encoder_wraps_and_traction_wraps():
    world, samples = _stream('steered_wheel', STEER_TRUTH, wrap_steering=True,
                             wrap_traction=True)
    cal = ImprovedWheelCalibrator(_params('steered_wheel'), matcher=world.matcher,
                                  prepare=world.prepare, periodic=False)
    cal.front.deskewed_points = lambda scan: scan
    res = run_batch(cal, samples).result
    assert res.counts['encoder_unwraps'] > 0
    assert res.values['steering_offset'] == pytest.approx(STEER_TRUTH['steering_offset'],
                                                          abs=1e-5)


def test_front_end_failed_matches_give_a_clear_verdict():
    world, samples = _stream('differential', DIFF_TRUTH, fail_every=3)
    cal = ImprovedWheelCalibrator(_params('differential'), matcher=world.matcher,
                                  prepare=world.prepare, periodic=False)
    cal.front.deskewed_points = lambda scan: scan
    res = run_batch(cal, samples).result
    assert 'failed to match' in res.verdict


def test_front_end_without_wheel_data():
    from robot_calib.core import types as T
    cal = ImprovedWheelCalibrator(_params('differential'), periodic=False)
    res = run_batch(cal, [T.ScanSample(0.1 * i, 0.0, 0.1, np.full(10, 2.0))
                          for i in range(20)]).result
    assert 'no wheel data' in res.verdict.lower() and res.segments_used == 0


# -- real data (small slices) --------------------------------------------------------------
def test_censi_reproduces_the_authors(shared_data):
    from robot_calib.io.datasets import censi
    folder = shared_data / 'censi_calibration'
    segs = censi.load_tuples(folder / 'l90_0.tuple')
    ref = censi.load_results(folder / 'l90_0_results.json')
    out = S.censi_calibrate(segs)
    got = dict(zip(P.DIFF_KEYS, out['x']))
    for k in ('left_wheel_radius', 'right_wheel_radius'):
        assert abs(got[k] - ref[k]) < 0.05e-3  # diameter within 0.1 mm
    assert abs(got['track_width'] - ref['track_width']) < 0.3e-3
    assert abs(got['lidar_yaw'] - ref['lidar_yaw']) < math.radians(0.1)
    p = _params('differential', wheel_radius=0.02, track_width=0.09)
    res = S.calibrate('differential', segs, p)
    assert abs(res.values['track_width'] - ref['track_width']) < 0.3e-3
    assert res.stds['track_width'] < 1e-3


def test_tricycle_first_half_calibration_beats_nominal(shared_data):
    from robot_calib.io.datasets import tricycle
    data = tricycle.load(shared_data / 'tricycle' / 'dataset.txt')
    n = len(data.t)
    half = n // 2
    p = P.WheelCalibParams(drive_type='steered_wheel', **data.nominal)
    res = S.calibrate('steered_wheel', tricycle.segments(data, 0, half, 20), p)

    def mean_error(values):
        pred = tricycle.dead_reckon(data, values, half, n - 1)
        return float(np.mean(np.hypot(*(pred[:, :2] - data.tracker_pose[half:, :2]).T)))
    before, after = mean_error(data.nominal), mean_error(res.values)
    assert before > 2.0 and after < 0.5 < before


def test_seed_mode_differential_is_censi_faithful():
    segs = _diff_segments(np.random.default_rng(10), n=200, noise=(0.001, 0.001, 0.0005))
    res = S.censi_result(segs, _params('differential', mode='seed'))
    for k in P.DIFF_KEYS:
        assert abs(res.values[k] - DIFF_TRUTH[k]) < 5 * res.stds[k], k
    assert res.segments_used < 200  # the authors' trimming drops ~1 % per pass


def test_relative_pose_of_single_poses_as_floats_equals_the_array_form():
    rng = np.random.default_rng(8)
    for a, b in zip(rng.uniform(-5, 5, (500, 3)), rng.uniform(-5, 5, (500, 3))):
        assert np.allclose(K.between_scalar(a.tolist(), b.tolist()),
                           K.compose(K.inverse(a), b), rtol=0, atol=1e-12)


@pytest.mark.parametrize('drive', ['differential', 'steered_wheel'])
def test_sensor_motion_during_a_scan_is_the_composed_odometry(drive):
    """The expanded deskew motion equals l^-1 (+) a(t0)^-1 (+) a(t) (+) l from kinematics."""
    from robot_calib.core import types as T
    from robot_calib.methods.wheel_odometry_calibration.wheels import WheelHistory
    rng = np.random.default_rng(3)
    x_nom = (np.array([0.05, 0.05, 0.3, 0.1, -0.02, 0.04]) if drive == 'differential'
             else np.array([0.02, 1.0, 0.1, 0.5, 0.3, 0.05, 0.1]))
    hist = WheelHistory(drive, x_nom, 0.5)
    t, a, b = 0.0, 0.0, 0.0
    for _ in range(600):
        t += 0.01
        a += rng.normal(0.3, 0.1)
        b = b + rng.normal(0.32, 0.1) if drive == 'differential' else rng.normal(0.0, 0.4)
        hist.add(t, a, b)
    lidar = x_nom[-3:]
    dt = np.arange(360) * (0.1 / 360)
    for stamp in rng.uniform(0.5, 5.5, 20):
        scan = T.ScanSample(stamp, -math.pi, 2 * math.pi / 360, np.ones(360),
                            time_increment=0.1 / 360, scan_time=0.1)
        poses = np.asarray(hist.pose[:])
        at = np.column_stack([np.interp(stamp + dt, hist.t, poses[:, j]) for j in range(3)])
        a0 = np.array([np.interp(stamp, hist.t, poses[:, j]) for j in range(3)])
        want = K.sensor_motion(K.compose(np.broadcast_to(K.inverse(a0), at.shape), at), lidar)
        got = hist.sensor_motion_during(scan, lidar)(dt)
        assert np.allclose(got, want, rtol=0.0, atol=1e-13)
        assert np.ptp(got[:, 0]) > 1e-3                # the robot moved during the scan


def test_returns_near_the_lidar_limit_do_not_shorten_the_calibration():
    """
    A 4 m lidar: near range_max only returns whose noise fell short survive.

    Far walls then read closer, and every scan-matched length came out short: with
    ``range_margin`` 0 (the code before it) seeds 0 and 3 gave the radii and the
    track 0.8-2.2 std low; the default margin leaves out the last 5 % of the range.
    """
    from robot_calib.sim import run_scenario
    nominal = {'drive_type': 'differential', 'wheel_radius': 0.05, 'track_width': 0.3,
               'lidar_x': 0.1}
    keys = ('left_wheel_radius', 'right_wheel_radius', 'track_width')
    z = {}
    for seed in (0, 3):
        sim = run_scenario('diff_segments', seed=seed, overrides={'lidar.range_max': 4.0})
        samples = [s for tp, s in sim.messages if tp.lstrip('/') in ('joint_states', 'scan')]
        for margin in (0.0, P.WheelCalibParams().range_margin):
            cal = ImprovedWheelCalibrator(P.WheelCalibParams(range_margin=margin, **nominal),
                                          periodic=False)
            res = run_batch(cal, samples).result
            assert res.converged
            z[seed, margin] = [(res.values[k] - sim.truth[k]) / res.stds[k] for k in keys]
    without = np.array([v for (_, m), v in z.items() if m == 0.0])
    default = np.array([v for (_, m), v in z.items() if m > 0.0])
    assert without.mean() < -0.8
    assert np.abs(default).max() < 1.0


def test_the_range_limit_is_the_margin_below_the_scan_range_max():
    from robot_calib.core import types as T
    from robot_calib.methods.wheel_odometry_calibration.segmenter import DriveSegmenter
    seg = DriveSegmenter(P.WheelCalibParams(range_margin=0.1), max_range=30.0)
    scan = T.ScanSample(0.0, -1.0, 0.1, np.ones(21), range_max=4.0)
    assert seg.range_limit(scan) == pytest.approx(3.6)
    assert seg.range_limit(T.ScanSample(0.0, -1.0, 0.1, np.ones(21), range_max=0.0)) == 30.0
    assert seg.range_limit(T.ScanSample(0.0, -1.0, 0.1, np.ones(21), range_max=100.0)) == 30.0
