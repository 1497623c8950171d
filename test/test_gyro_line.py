# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Gyro line calibration: condition 2, the correction formula, phases, guards, bad input."""

import math

import numpy as np
import pytest

from robot_calib.core import types as T
from robot_calib.core.lines import line_from_endpoints
from robot_calib.methods.gyro_line_calibration.improved import ImprovedGyroLine
from robot_calib.methods.gyro_line_calibration.params import GyroLineParams, MatchParams
from robot_calib.methods.gyro_line_calibration.pipeline import GyroLinePipeline
from robot_calib.methods.gyro_line_calibration.seed import (
    condition2, condition2_many, seed_calibrated_angle, seed_heading_correction, SeedGyroLine)
from robot_calib.methods.gyro_line_calibration.variants import make_estimator
from robot_calib.sim import run_scenario

DEG = math.pi / 180.0


def _line(cx, cy, deg, length, t=0.0):
    a = deg * DEG
    u = np.array([math.cos(a), math.sin(a)]) * length / 2
    c = np.array([cx, cy])
    return line_from_endpoints(c - u, c + u, t, 1e-6, 40)


def _rotated(line, deg, about=(0.0, 0.0)):
    a = deg * DEG
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    o = np.asarray(about, float)
    return line_from_endpoints(R @ (line.p1 - o) + o, R @ (line.p2 - o) + o, line.t,
                               line.variance, line.n_cells)


# -- condition 2 and the seed formula (hand-checked) ------------------------------------
def test_condition2_each_tolerance():
    m = MatchParams(length_tolerance=0.5, endpoint_tolerance=0.3, angle_tolerance=5 * DEG)
    ref = _line(0.0, 0.0, 0.0, 2.0)
    assert condition2(ref, _line(0.0, 0.0, 2.0, 2.0), m) == pytest.approx(-2 * DEG)
    assert condition2(ref, _line(0.0, 0.0, 2.0, 1.4), m) is None       # (a) length
    assert condition2(ref, _line(0.4, 0.0, 0.0, 2.0), m) is None       # (b) both endpoints
    assert condition2(ref, _line(0.0, 0.0, 6.0, 2.0), m) is None       # (c) angle
    # start within, end not: (b) needs both
    short = line_from_endpoints((-1.0, 0.0), (0.6, 0.0))
    assert condition2(ref, short, m) is None
    # angles are compared modulo pi: 89.5 deg vs -89.5 deg differ by 1 deg
    v = _line(0.0, 0.0, 89.5, 2.0)
    w = _line(0.0, 0.0, -89.5, 2.0)
    assert condition2(v, w, m) == pytest.approx(-1 * DEG)
    arr = np.array([[*ref.p1, *ref.p2, ref.angle, ref.length], [*v.p1, *v.p2, v.angle, v.length]])
    errs = condition2_many(arr, _line(0.0, 0.0, 2.0, 2.0), m)
    assert errs[0] == pytest.approx(-2 * DEG) and np.isnan(errs[1])


def test_seed_correction_formula():
    # calibrated = w1 * ref + w2 * new; heading += calibrated - new
    assert seed_calibrated_angle(10 * DEG, 12 * DEG, 0.8) == pytest.approx(10.4 * DEG)
    assert seed_heading_correction(10 * DEG, 12 * DEG, 0.8) == pytest.approx(-1.6 * DEG)
    # across the +-90 deg wrap: reference 89.5, line -89.5 (= 90.5)
    assert seed_heading_correction(89.5 * DEG, -89.5 * DEG, 0.7) == pytest.approx(-0.7 * DEG)


def test_seed_phase_logic_first_length_and_time_recalibration():
    p = GyroLineParams(mode='seed')
    p.seed.recalibration_time = 20.0
    p.seed.recalibration_length_ratio = 1.5
    c = SeedGyroLine(p)
    wall = _line(0.0, 0.0, 0.0, 2.0)
    side = _line(1.5, 1.0, 90.0, 1.2)
    assert c._seed_step([wall, side], 0.0) == []             # S1: references
    assert len(c.references) == 2
    c._seed_step([_rotated(wall, 0.5)], 1.0)                 # the same wall: not stored again
    assert len(c.references) == 2
    c.set_phase(True)
    out = c._seed_step([_rotated(wall, 2.0)], 10.0)          # S2: the first line
    assert len(out) == 1 and out[0].kind == 'first'
    assert out[0].delta == pytest.approx(-0.8 * 2.0 * DEG)
    assert c._seed_step([_rotated(wall, 1.0)], 11.0) == []   # neither longer nor later
    longer = _rotated(_line(0.0, 0.0, 0.0, 2.6), 1.0)       # 2.6 m >= 1.5 x 1.6 m? no
    assert c._seed_step([longer], 12.0) == []
    out = c._seed_step([_rotated(_line(0.0, 0.0, 0.0, 2.4), 1.0)], 12.5)
    assert out == []  # 2.4 < 1.5 * 2.0 (the first line is 2 m)
    c.params.match.length_tolerance = 5.0
    c.params.match.endpoint_tolerance = 2.0
    out = c._seed_step([_rotated(_line(0.0, 0.0, 0.0, 3.2), 1.0)], 13.0)
    assert len(out) == 1 and out[0].kind == 'length'
    out = c._seed_step([_rotated(side, 1.0, (1.5, 1.0))], 40.0)
    assert len(out) == 1 and out[0].kind == 'time'
    assert out[0].delta == pytest.approx(-0.8 * DEG)
    out = c._seed_step([_rotated(wall, 0.05)], 70.0)         # below the threshold
    assert out == [] and c.counts['seed_below_threshold'] == 1


# -- improved mode guards (exact geometry) ---------------------------------------------
def _improved_with(refs, pos_sigma=0.05, heading_sigma=0.2 * DEG):
    c = ImprovedGyroLine(GyroLineParams())
    c.initialized = True
    c.P = np.diag([pos_sigma ** 2, pos_sigma ** 2, heading_sigma ** 2, 1e-10, 1e-6])
    for line in refs:
        ref = c._new_reference(line, 0.0, np.diag([(0.05 * DEG) ** 2, 0.01 ** 2]))
        ref.confirmed = True
        c.references.append(ref)
    return c


def test_improved_corrects_with_two_supporting_walls():
    walls = [_line(2.0, 0.0, 0.0, 4.0), _line(0.0, 1.5, 90.0, 3.0), _line(2.0, 3.0, 0.0, 4.0)]
    c = _improved_with(walls, heading_sigma=2.0 * DEG)
    c.x[:2] = (1.0, 1.0)
    seen = [_rotated(w, 0.4, (1.0, 1.0)) for w in walls]    # heading 0.4 deg too far left
    out = c._improved_step(seen, 1.0)
    assert len(out) == 1
    assert out[0].delta == pytest.approx(-0.4 * DEG, abs=0.05 * DEG)
    # a confident heading takes a Kalman-weighted part of the same evidence
    c = _improved_with(walls, heading_sigma=0.2 * DEG)
    c.x[:2] = (1.0, 1.0)
    out = c._improved_step(seen, 1.0)
    assert -0.4 * DEG < out[0].delta < -0.1 * DEG


def test_single_line_needs_support_over_time():
    c = _improved_with([_line(2.0, 0.0, 0.0, 4.0)])
    c.x[:2] = (1.0, 1.0)
    seen = _rotated(_line(2.0, 0.0, 0.0, 4.0), 0.3, (1.0, 1.0))
    assert c._improved_step([seen], 1.0) == []
    assert c.counts['matches_unsupported'] == 1
    assert len(c._improved_step([seen], 1.6)) == 1            # the same wall, agreeing later


def test_parallel_walls_are_ambiguous_when_position_is_uncertain():
    wall = _line(2.0, 0.0, 0.0, 4.0)
    shelf = _line(2.0, 0.6, 0.0, 4.0)                         # a shelf 0.6 m in front of it
    c = _improved_with([wall, shelf], pos_sigma=0.5)
    c.x[:2] = (2.0, 2.0)
    seen = _line(2.0, 0.3, 0.2, 4.0)                          # which one is it?
    assert c._improved_step([seen, seen], 1.0) == []
    assert c.counts['lines_ambiguous'] == 2
    c = _improved_with([wall, shelf], pos_sigma=0.02)         # well localised: the shelf
    c.x[:2] = (2.0, 2.0)
    near = _line(2.0, 0.61, 0.2, 4.0)
    c._improved_step([near], 1.0)
    assert c.counts.get('lines_ambiguous', 0) == 0


def test_facets_of_a_round_wall_are_ambiguous_when_heading_is_uncertain():
    """
    Two facets of a many-sided round room, 5.6 deg apart and end to end (an audit's room).

    Both gate while the heading is uncertain, at one distance: the line seen
    between them could be either, and taking the nearer in angle corrected the
    heading by a facet's angle (a perfect gyro ended 6 deg off after 3 min).
    """
    a = _line(0.0, 3.5, 0.0, 0.34)
    b = _rotated(_line(0.34, 3.5, 0.0, 0.34), 5.6, (0.17, 3.5))
    c = _improved_with([a, b], heading_sigma=3.0 * DEG)
    seen = _rotated(_line(0.17, 3.5, 0.0, 0.5), 2.0, (0.17, 3.5))
    assert c._improved_step([seen], 1.0) == []
    assert c._improved_step([seen], 1.6) == []               # seen again: still either facet
    assert c.counts['lines_ambiguous'] == 2 and not c.corrections


def test_symmetric_room_never_aliases_by_90_degrees():
    square = [_line(2.0, 0.0, 0.0, 4.0), _line(4.0, 2.0, 90.0, 4.0), _line(2.0, 4.0, 0.0, 4.0),
              _line(0.0, 2.0, 90.0, 4.0)]
    c = _improved_with(square)
    c.x[:2] = (2.0, 2.0)
    seen = [_rotated(w, 88.0, (2.0, 2.0)) for w in square]    # heading lost by 88 deg
    assert c._improved_step(seen, 1.0) == []
    assert c._improved_step(seen, 2.0) == []
    assert not c.corrections


def test_moved_furniture_does_not_bend_the_correction():
    walls = [_line(2.0, 0.0, 0.0, 4.0), _line(0.0, 1.5, 90.0, 3.0), _line(4.0, 1.5, 90.0, 3.0)]
    sofa = _line(2.0, 2.5, 0.0, 1.8)
    c = _improved_with(walls + [sofa], heading_sigma=2.0 * DEG)
    c.x[:2] = (2.0, 1.2)
    seen = [_rotated(w, 0.3, (2.0, 1.2)) for w in walls]
    moved = _rotated(_rotated(sofa, 3.0, (2.0, 2.5)), 0.3, (2.0, 1.2))  # sofa turned 3 deg
    out = c._improved_step(seen + [moved], 1.0)
    assert len(out) == 1
    assert out[0].delta == pytest.approx(-0.3 * DEG, abs=0.08 * DEG)
    assert c.references[3].conflicts + c.counts.get('lines_outside_gate', 0) >= 1


def test_passing_person_never_becomes_a_reference():
    c = _improved_with([])
    legs = _line(1.0, 1.0, 30.0, 0.7)
    c._improved_step([legs], 0.0)
    c._improved_step([legs], 0.1)
    assert len(c.tentative) == 1
    c._improved_step([_line(5.0, 5.0, 0.0, 1.0)], 10.0)       # 10 s later, elsewhere
    assert not c.references and c.counts['tentative_expired'] >= 1


# -- simulated vacuum run --------------------------------------------------------------
def _run(result, params):
    c = make_estimator(params)
    est = []
    for topic, m in result.messages:
        if topic == '/tf_static':
            for tf in m:
                c.set_mounting(tf)
        elif topic in ('/imu', '/odom', '/scan'):
            c.update(m)
            if topic == '/imu':
                est.append((m.t, c.heading))
    est = np.array(est)
    gt = np.interp(est[:, 0], result.sensors['gt_t'], np.unwrap(result.sensors['gt_yaw']))
    err = np.degrees((est[:, 1] - gt + math.pi) % (2 * math.pi) - math.pi)
    return c, err


def test_vacuum_scenario_automatic_mode_beats_uncorrected_gyro():
    bias = 60.0 * DEG / 3600.0   # 60 deg/h: 2 deg uncorrected after 2 minutes
    r = run_scenario('vacuum', seed=0, duration=120.0,
                     overrides={'imu.gyro_bias': [0.0, 0.0, bias]})
    p = GyroLineParams(mode='seed')                          # work phase only: uncorrected
    _, raw = _run(r, p)
    c, err = _run(r, GyroLineParams())
    assert abs(raw[-1]) > 1.5
    assert abs(err[-1]) < 0.5
    assert len(c.corrections) > 10
    assert 0.0 < c.result().gyro_bias < 2.0 * bias     # learning the bias (slowly: 2 minutes only)


def test_standstill_learns_a_gyro_bias_far_beyond_its_prior():
    # 0.01 rad/s (2000 deg/h, 34 times the prior's sigma): the references made in the first
    # seconds are already rotated and every later turn drifts beyond the gates, unless the
    # bias is read while the robot stands still (the vacuum stops for 2 s at its start)
    r = run_scenario('vacuum', seed=1, duration=120.0,
                     overrides={'imu.gyro_bias': [0.0, 0.0, -0.01]})
    off = GyroLineParams()
    off.improved.standstill_update = False
    _, err_off = _run(r, off)
    c, err = _run(r, GyroLineParams())
    assert np.abs(err_off).max() > 3.0
    assert np.abs(err).max() < 1.0
    assert c.counts['standstill_updates'] >= 2
    assert abs(c.result().gyro_bias + 0.01) < 1e-3


def test_a_turn_while_the_odometry_stands_still_is_not_learnt_as_bias():
    pipe = GyroLinePipeline()
    _drive(pipe, 0.0, 2.0, 1.0, odom_moving=False)             # standing still: bias 0 read
    assert pipe.core.counts['standstill_updates'] >= 2
    assert abs(pipe.core.result().gyro_bias) < 1e-6
    # pushed round (0.2 rad/s, below the carried rate) while the wheels do not turn
    _drive(pipe, 2.0, 4.0, 1.0, heading_rate=0.2, odom_moving=False)
    assert pipe.core.counts['standstill_refused_gyro_turning'] >= 10
    assert abs(pipe.core.result().gyro_bias) < 1e-3                # (learnt, it would be 0.2)


def _replay(result, pipe):
    for topic, m in result.messages:
        if topic == '/tf_static':
            for tf in m:
                pipe.on_static_transform(tf)
        elif topic in ('/imu', '/odom', '/scan'):
            pipe.process(topic[1:], m)
    return pipe


@pytest.mark.parametrize('scale', [0.08, -0.08])
def test_walls_contradicting_the_heading_are_reported(scale):
    # an 8 % gyro scale error (the prior says 1 %) turns the heading outside every gate at the
    # first turns; new references then agree with the rotated heading, so corrections go on.
    # The heading is tens of degrees off: the status must not say ok
    r = run_scenario('vacuum', seed=2, duration=90.0,
                     overrides={'imu.gyro_scale': [0.0, 0.0, scale]})
    pipe = _replay(r, GyroLinePipeline())
    _, err = _run(r, GyroLineParams())
    assert np.abs(err).max() > 5.0                               # really lost
    t_end = r.messages[-1][1].t
    status = pipe.status(t_end)
    assert status.level == 1 and 'lost the walls' in status.message
    summary = pipe.method_summary()
    assert summary['walls_verdict'] == 'contradicted'
    assert summary['walls_contradicted_times'] >= 1


def test_walls_agreeing_with_the_heading_are_not_reported():
    r = run_scenario('vacuum', seed=2, duration=90.0,
                     overrides={'imu.gyro_scale': [0.0, 0.0, 0.005]})
    pipe = _replay(r, GyroLinePipeline())
    assert pipe.status(r.messages[-1][1].t).level == 0
    assert pipe.method_summary()['walls_verdict'] == 'consistent'
    assert pipe.core.counts.get('heading_contradicted_by_walls', 0) == 0
    seed = _replay(r, GyroLinePipeline(GyroLineParams(mode='seed')))
    assert seed.method_summary()['walls_verdict'] == 'not_checked'


def test_correction_totals_count_every_correction_while_few_are_kept(monkeypatch):
    """The summary's total and the plot's trace cover the whole run, not the kept window."""
    from robot_calib.methods.gyro_line_calibration import variant_base as base
    monkeypatch.setattr(base, 'KEPT_CORRECTIONS', 4)
    r = run_scenario('vacuum', seed=0, duration=120.0,
                     overrides={'imu.gyro_bias': [0.0, 0.0, 60.0 * DEG / 3600.0]})
    pipe = GyroLinePipeline()
    made = []
    for topic, m in r.messages:
        if topic == '/tf_static':
            for tf in m:
                pipe.core.set_mounting(tf)
        elif topic in ('/imu', '/odom', '/scan'):
            out = pipe.core.update(m)
            if topic == '/scan':
                made += list(out or ())
    core = pipe.core
    assert len(made) > 10 and list(core.corrections) == made[-4:]
    deltas = np.array([c.delta for c in made])
    summary = pipe.method_summary()
    assert summary['corrections'] == len(made) and summary['corrections_kept'] == 4
    assert summary['correction_total_deg'] == pytest.approx(np.degrees(deltas.sum()), abs=1e-9)
    assert summary['correction_abs_max_deg'] == pytest.approx(np.degrees(np.abs(deltas).max()))
    trace = np.array(list(core.correction_trace))
    assert core.correction_trace.count == len(made) and trace[0, 0] == made[0].t
    assert trace[-1, 1] == pytest.approx(deltas.sum(), abs=1e-12)


# -- bad input through the pipeline ----------------------------------------------------
def _scan(t, ranges, n=None):
    r = np.asarray(ranges, float)
    return T.ScanSample(t, -math.pi, 2 * math.pi / max(r.size, 1), r, 0.05, 8.0)


def _room_ranges(x, y, yaw, n=360):
    from robot_calib.sim.world import World
    world = World().add_room(5.0, 4.0)
    a = -math.pi + 2 * math.pi / n * np.arange(n)
    return world.raycast(x, y, yaw + a)


def test_bad_scans_are_rejected_and_counted():
    pipe = GyroLinePipeline()
    pipe.process('odom', T.OdomSample(0.0, 1.0, 1.0, 0.0))
    good = _room_ranges(1.0, 1.0, 0.0)
    assert pipe.process('scan', _scan(0.1, good)) == []
    nan = good.copy()
    nan[::3] = np.nan
    nan[1::3] = np.inf
    nan[2::7] = 50.0                                          # out of range
    pipe.process('scan', _scan(0.2, nan))
    pipe.process('scan', _scan(0.3, np.full(360, np.nan)))
    pipe.process('scan', _scan(0.4, np.zeros(0)))
    pipe.process('scan', _scan(0.5, _room_ranges(1.0, 1.0, 0.0, 180)))
    pipe.process('scan', T.ScanSample(0.6, float('nan'), 0.01, good))
    s = pipe.summary()['inputs']['scan']
    assert s['rejected_too_few_valid_beams'] == 1
    assert s['rejected_empty_scan'] == 1
    assert s['rejected_beam_count_changed'] == 1
    assert s['rejected_non_finite'] == 1
    assert s.get('rejected', 0) == 4
    assert not pipe.core.corrections


def _drive(pipe, t0, t1, x0, heading_rate=0.0, odom_moving=True, ranges=None, x_off=0.0):
    """Feed 100 Hz IMU, 50 Hz odometry and 10 Hz scans of a straight drive along x."""
    out = []
    for k in range(int(round((t1 - t0) * 100))):
        t = t0 + k * 0.01
        x = x0 + (0.2 * (t - t0) if odom_moving else 0.0)
        out += pipe.process('imu', T.ImuSample(t, np.array([0, 0, heading_rate]),
                                               np.array([0, 0, 9.81])))
        if k % 2 == 0:
            out += pipe.process('odom', T.OdomSample(t, x, 1.0, 0.0, 0.2 if odom_moving else 0))
        if k % 10 == 5:
            r = ranges if ranges is not None else _room_ranges(x + x_off, 1.0, 0.0)
            out += pipe.process('scan', _scan(t, r))
    return out


def test_odometry_reset_and_time_jump_are_distrusted():
    pipe = GyroLinePipeline()
    _drive(pipe, 0.0, 3.0, 1.0)
    pose = pipe.core.pose.copy()
    pipe.process('odom', T.OdomSample(3.01, 0.0, 0.0, 0.0))      # the odometry restarted
    assert pipe.core.counts['odom_resets'] == 1
    assert np.allclose(pipe.core.pose[:2], pose[:2], atol=0.01)
    assert not pipe.core.trusted(3.02)
    n = len(pipe.core.corrections)
    pipe.process('imu', T.ImuSample(10.0, np.zeros(3), np.array([0, 0, 9.81])))  # 7 s gap
    assert pipe.core.counts['imu_time_jumps'] == 1
    assert not pipe.core.trusted(10.5)
    assert len(pipe.core.corrections) == n
    diag = pipe.status(10.5)
    assert diag.level == 1
    assert dict(diag.values)['events.odom_resets'] == '1'


def test_carried_robot_gives_no_correction():
    pipe = GyroLinePipeline()
    _drive(pipe, 0.0, 4.0, 1.0)                              # references made
    n = len(pipe.core.corrections)
    # picked up and turned: wheels stopped, gyro turning; scans change meanwhile
    _drive(pipe, 4.0, 6.0, 1.8, heading_rate=0.5, odom_moving=False, x_off=0.5)
    assert pipe.core.counts['untrusted_carried'] >= 1
    assert len(pipe.core.corrections) == n
    # carried straight without turning: scans change while everything says stopped
    pipe2 = GyroLinePipeline()
    _drive(pipe2, 0.0, 4.0, 1.0)
    m = len(pipe2.core.corrections)
    for k in range(20):
        t = 4.0 + 0.1 * k
        pipe2.process('odom', T.OdomSample(t, 1.8, 1.0, 0.0))
        pipe2.process('imu', T.ImuSample(t + 0.05, np.zeros(3), np.array([0, 0, 9.81])))
        pipe2.process('scan', _scan(t + 0.06, _room_ranges(1.8 + 0.15 * k, 1.0, 0.0)))
    assert pipe2.core.counts['untrusted_carried'] >= 1
    assert len(pipe2.core.corrections) == m


def test_pipeline_publishes_corrected_odometry_with_input_stamp():
    pipe = GyroLinePipeline()
    outs = _drive(pipe, 0.0, 2.0, 1.0)
    odoms = [s for k, s in outs if k == 'odom']
    diags = [s for k, s in outs if k == 'diagnostics']
    assert len(odoms) == 100 and diags
    assert odoms[-1].stamp_ns == -1 and odoms[-1].t == pytest.approx(1.98)
    assert odoms[-1].frame_id == 'map' and np.all(np.isfinite(odoms[-1].pose_cov))
    summary = pipe.summary()
    assert summary['mode'] == 'improved' and 'events' in summary


def test_gyro_z_of_an_identity_mounting_equals_the_matrix_product():
    core = make_estimator()
    rot = core._imu_rot
    for g in ([0.1, -0.2, 0.3], [0.0, 0.0, -0.0], [-0.0, 1.0, 0.0], [np.inf, 0.0, 0.2],
              [np.nan, 1.0, 0.5], [1e-300, -2.0, -7.5]):
        want = float((rot @ np.asarray(g, dtype=float))[2])
        got = core._gyro_z(np.asarray(g, dtype=float))
        assert got == want or (math.isnan(got) and math.isnan(want))
        assert math.copysign(1.0, got) == math.copysign(1.0, want)


def test_scan_points_mounting_and_motion_equal_a_per_beam_deskew():
    from robot_calib.core import frames
    rng = np.random.default_rng(2)
    ranges = rng.uniform(0.1, 8.0, 500)
    ranges[::7] = np.inf
    s = T.ScanSample(0.0, -2.0, 0.008, ranges, time_increment=1e-4)
    pose, motion = (0.2, -0.1, 0.7), frames.constant_motion(0.5, 0.3)
    pts, idx = frames.scan_points(s, pose, 6.0, motion)
    idx2, r, ang = s.beams(6.0)
    ref = frames.deskew(np.column_stack((r * np.cos(ang), r * np.sin(ang))),
                        np.tile(pose, (r.size, 1)))
    ref = frames.deskew(ref, motion(s.beam_times(idx2)))
    assert np.array_equal(idx, idx2)
    assert np.allclose(pts, ref, rtol=0.0, atol=1e-12)
    ref = motion.apply(frames.deskew(np.column_stack((r * np.cos(ang), r * np.sin(ang))),
                                     np.tile(pose, (r.size, 1))), s.beam_times(idx2))
    assert np.array_equal(pts, ref)   # the same operations, to the bit


def test_condition2_near_is_condition2_many_on_the_candidates():
    from robot_calib.methods.gyro_line_calibration.seed import condition2_near
    m = MatchParams()
    rng = np.random.default_rng(3)
    refs = [_line(*rng.uniform(-3.0, 3.0, 2), rng.uniform(-90.0, 90.0), rng.uniform(0.6, 3.0))
            for _ in range(300)]
    arr = np.array([[*r.p1, *r.p2, r.angle, r.length] for r in refs])
    mids = np.array([r.midpoint for r in refs]).T
    found = 0
    for r in refs[:100]:  # the references themselves, moved a little: most match something
        new = _line(*(r.midpoint + rng.normal(0.0, 0.2, 2)), math.degrees(r.angle)
                    + rng.normal(0.0, 3.0), r.length + rng.normal(0.0, 0.3))
        full = condition2_many(arr, new, m)
        idx, errs = condition2_near(arr, mids, new, m)
        assert np.array_equal(full[idx], errs, equal_nan=True)  # same values, bit for bit
        rest = np.setdiff1d(np.arange(len(refs)), idx)
        assert np.all(np.isnan(full[rest]))  # nothing that passes is left out
        found += int(np.isfinite(errs).sum())
    assert found > 50


def test_covariance_steps_on_lists_equal_the_numpy_rows_and_columns():
    est = ImprovedGyroLine(GyroLineParams())
    rng = np.random.default_rng(5)
    for _ in range(50):
        M = rng.normal(size=(5, 5))
        P0 = M @ M.T
        a, w, q = rng.uniform(0.0, 0.1), rng.normal(), rng.uniform(0.0, 1e-6)
        want = P0.copy()  # F P F^T, F = I - a e2 e3^T - w e2 e4^T, then the process noise
        want[2, :] -= a * want[3, :] + w * want[4, :]
        want[:, 2] -= a * want[:, 3] + w * want[:, 4]
        want[2, 2] += q
        want[3, 3] += est.params.improved.bias_walk ** 2 * a
        est.P = P0.copy()
        est._acc_dt, est._acc_wdt, est._acc_q = a, w, q
        assert np.array_equal(est._flushed_covariance(), want)
        est._flush_gyro()
        assert np.array_equal(est.P, want) and est._acc_dt == 0.0
        # an odometry step: F = I - dy e0 e2^T + dx e1 e2^T, then position noise
        d, dist = (rng.normal(), rng.normal(), 0.0), rng.uniform(0.0, 0.1)
        x0 = est.x.copy()
        th = x0[2]
        dx = math.cos(th) * d[0] - math.sin(th) * d[1]
        dy = math.sin(th) * d[0] + math.cos(th) * d[1]
        f = np.array([-dy, dx])
        want[:2, :] += np.multiply.outer(f, want[2, :])
        want[:, :2] += np.multiply.outer(want[:, 2], f)
        want[0, 0] += est.params.improved.odom_noise ** 2 * dist
        want[1, 1] += est.params.improved.odom_noise ** 2 * dist
        rows = est.P.tolist()
        est._move(d, dist, rows)
        assert np.array_equal(np.array(rows), want)
        assert est.x[0] == x0[0] + dx and est.x[1] == x0[1] + dy
