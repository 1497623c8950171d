# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Simulator tests: the engine against its own ground truth and hand-computed geometry."""

import json
import math

import numpy as np
import pytest

from robot_calib import codec
from robot_calib.core.geometry import wrap_angle
from robot_calib.io.bags import read_messages
from robot_calib.sim import run_scenario, run_setup, SCENARIOS, Setup, SimError, simulate
from robot_calib.sim.engine import encoded_streams, make_params, truth_path
from robot_calib.sim.motion import Plan
from robot_calib.sim.robot import rotation_matrix
from robot_calib.sim.world import Ramp, World
from scan_helpers import box_ranges

IDEAL_IMU = {'imu.gyro_bias': [0.0, 0.0, 0.0], 'imu.gyro_noise': 0.0,
             'imu.gyro_random_walk': 0.0, 'imu.gyro_scale': [0.0, 0.0, 0.0],
             'imu.accel_bias': [0.0, 0.0, 0.0], 'imu.accel_noise': 0.0,
             'imu.accel_scale': [0.0, 0.0, 0.0]}


def run_plan(plan, overrides=None, world=None, start=(1.0, 1.0, 0.0), duration=None):
    """Simulate a plan in a world (default: empty 20 m room) with SimParams defaults."""
    world = world if world is not None else World().add_room(20.0, 20.0, -10.0, -10.0)
    params = make_params(None, overrides)
    return run_setup(Setup(world=world, plan=plan, start=start), params,
                     duration if duration is not None else plan.duration)


@pytest.fixture(scope='module')
def drive30():
    """Return 30 s of the drive scenario with an ideal IMU."""
    return run_scenario('drive', seed=1, duration=30.0, overrides=IDEAL_IMU)


def test_drive_is_registered():
    assert 'drive' in SCENARIOS
    assert SCENARIOS['drive'].description
    assert SCENARIOS['drive'].duration == 120.0


def test_integrated_true_twist_reproduces_true_pose(drive30):
    s = drive30.sensors
    t, v, w = s['gt_t'], s['gt_v'], s['gt_w']
    dt = np.diff(t)
    yaw = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)))
    mid = 0.5 * (yaw[1:] + yaw[:-1])
    ds = 0.5 * (v[1:] + v[:-1]) * dt
    x = np.concatenate(([0.0], np.cumsum(ds * np.cos(mid))))
    y = np.concatenate(([0.0], np.cumsum(ds * np.sin(mid))))
    assert np.max(np.abs(wrap_angle(yaw - s['gt_yaw']))) < 2e-3
    assert np.max(np.hypot(x - s['gt_x'], y - s['gt_y'])) < 0.02
    assert np.ptp(s['gt_x']) > 3.0  # it really drove somewhere


def test_noiseless_gyro_integrates_to_true_yaw(drive30):
    s = drive30.sensors
    t, gz = s['imu_t'], s['gyro'][:, 2]
    yaw = np.concatenate(([0.0], np.cumsum(0.5 * (gz[1:] + gz[:-1]) * np.diff(t))))
    true_yaw = np.interp(t, s['gt_t'], s['gt_yaw'])
    assert np.max(np.abs(yaw - true_yaw)) < 2e-3
    assert np.ptp(true_yaw) > 2.0  # turns happened


def test_gyro_bias_and_scale_show_up():
    over = dict(IDEAL_IMU)
    over.update({'imu.gyro_bias': [0.01, -0.02, 0.03], 'imu.gyro_scale': [0.0, 0.0, 0.1]})
    r = run_plan(Plan().stop(1.0).turn(math.pi, 0.5).stop(1.0), over)
    g = r.sensors['gyro']
    assert np.allclose(g[:50].mean(axis=0), [0.01, -0.02, 0.03], atol=1e-9)
    dt = 1.0 / r.params.imu.rate
    turned = np.sum(g[:, 2] - 0.03) * dt
    assert turned == pytest.approx(1.1 * math.pi, abs=2e-3)
    assert r.truth['gyro_bias'] == [0.01, -0.02, 0.03]


def test_accelerometer_at_rest_level_and_mounted():
    r = run_plan(Plan().stop(2.0), IDEAL_IMU)
    g = r.params.imu.gravity
    assert np.allclose(r.sensors['accel'], [0.0, 0.0, g], atol=1e-9)
    assert np.allclose(r.sensors['gyro'], 0.0, atol=1e-12)
    over = dict(IDEAL_IMU, **{'imu.roll': 0.1, 'imu.pitch': -0.2, 'imu.yaw': 0.5})
    r = run_plan(Plan().stop(2.0), over)
    expected = rotation_matrix(0.1, -0.2, 0.5).T @ np.array([0.0, 0.0, g])
    assert np.allclose(r.sensors['accel'], expected, atol=1e-9)
    assert abs(expected[0]) > 1.0  # the mounting really rotates gravity


def test_centripetal_acceleration_on_off():
    over = dict(IDEAL_IMU, **{'imu.z': 0.0})
    plan = Plan().twist(0.5, 0.5, 10.0)
    r = run_plan(plan, over)
    a = r.sensors['accel'][r.sensors['imu_t'] > 5.0]
    assert a[:, 1].mean() == pytest.approx(0.25, abs=1e-3)  # v * omega
    assert a[:, 0].mean() == pytest.approx(0.0, abs=1e-3)
    r = run_plan(plan, dict(over, **{'imu.centripetal': 'false'}))
    a = r.sensors['accel'][r.sensors['imu_t'] > 5.0]
    assert a[:, 1].mean() == pytest.approx(0.0, abs=1e-3)


def test_lidar_ranges_match_exact_geometry_in_a_box():
    world = World().add_room(4.0, 2.5)
    over = {'lidar.noise': 0.0, 'lidar.x': 0.2, 'lidar.y': -0.1, 'lidar.yaw': 0.3,
            'lidar.beams': 360, 'lidar.motion_distortion': 'false'}
    r = run_plan(Plan().stop(1.0), over, world, start=(1.0, 1.2, 0.4))
    scan = r.topic('/scan')[0]
    yaw = 0.4
    ox = 1.0 + 0.2 * math.cos(yaw) + 0.1 * math.sin(yaw)
    oy = 1.2 + 0.2 * math.sin(yaw) - 0.1 * math.cos(yaw)
    expected = box_ranges(ox, oy, yaw + 0.3 + scan.angles(), 0.0, 0.0, 4.0, 2.5)
    assert scan.ranges.size == 360
    assert scan.angle_min == pytest.approx(-math.pi)
    assert np.max(np.abs(scan.ranges - expected)) < 1e-4
    assert scan.frame_id == 'laser'


def test_lidar_invalid_beams_like_real_drivers():
    world = World().add_room(4.0, 2.5)
    base = {'lidar.noise': 0.0, 'lidar.x': 0.0, 'lidar.motion_distortion': 'false'}
    r = run_plan(Plan().stop(0.5), dict(base, **{'lidar.range_max': 2.0}), world)
    ranges = r.sensors['ranges'][0]
    exact = box_ranges(1.0, 1.0, r.topic('/scan')[0].angles(), 0.0, 0.0, 4.0, 2.5)
    assert np.all(np.isposinf(ranges[exact > 2.001]))
    assert np.all(np.isfinite(ranges[exact < 1.999]))
    over = dict(base, **{'lidar.range_max': 2.0, 'lidar.no_return': 'nan'})
    r = run_plan(Plan().stop(0.5), over, world)
    assert np.all(np.isnan(r.sensors['ranges'][0][exact > 2.001]))
    r = run_plan(Plan().stop(0.5), dict(base, **{'lidar.range_min': 1.1}), world)
    assert np.all(np.isneginf(r.sensors['ranges'][0][exact < 1.09]))
    r = run_plan(Plan().stop(0.5), dict(base, **{'lidar.dropout': 0.5}), world)
    frac = np.isnan(r.sensors['ranges']).mean()
    assert 0.4 < frac < 0.6


def test_odom_with_wheel_radius_error_drifts_as_expected():
    over = {'wheels.left_radius_error': 0.02, 'wheels.right_radius_error': 0.02}
    r = run_plan(Plan().stop(0.5).straight(5.0, 0.5).stop(1.0), over)
    s = r.sensors
    odom_d = s['odom_x'][-1]
    true_d = s['gt_x'][-1]
    assert odom_d == pytest.approx(5.0, abs=0.01)  # odom reports the command
    assert true_d / odom_d == pytest.approx(1.02, abs=1e-3)
    assert r.truth['left_wheel_radius'] == pytest.approx(0.05 * 1.02)
    # a track-width error scales the true rotation of a turn in place
    r = run_plan(Plan().turn(2 * math.pi, 1.0).stop(1.0), {'wheels.track_width_error': 0.05})
    s = r.sensors
    assert s['odom_yaw'][-1] == pytest.approx(2 * math.pi, abs=0.01)
    assert s['gt_yaw'][-1] / s['odom_yaw'][-1] == pytest.approx(1 / 1.05, abs=1e-3)


def test_slip_episode_makes_odom_overestimate():
    r = run_plan(Plan().straight(5.0, 0.5).stop(1.0),
                 {'wheels.slip_episodes': [2.0, 6.0, 0.2, 0.2]})
    s = r.sensors
    assert s['gt_x'][-1] == pytest.approx(s['odom_x'][-1] - 0.2 * 0.5 * 4.0, abs=0.02)


def test_steered_wheel_offset_curves_the_true_path():
    over = {'robot.drive_type': 'steered_wheel', 'robot.wheel_base': 1.0,
            'wheels.steering_offset': 0.02}
    r = run_plan(Plan().steer(0.0, 0.5, 10.0).stop(1.0), over)
    s = r.sensors
    # true yaw rate = v sin(offset) / L; odom (reading 0) stays straight
    assert s['gt_yaw'][-1] == pytest.approx(5.0 * math.sin(0.02), abs=5e-3)
    assert abs(s['odom_yaw'][-1]) < 1e-9
    js = r.topic('/joint_states')[-1]
    assert js.names == ('steering_joint', 'traction_joint')
    assert js.get('traction_joint')[0] == pytest.approx(5.0 / 0.05, rel=1e-3)
    assert r.truth['steering_offset'] == 0.02


def test_goto_reaches_waypoint():
    r = run_plan(Plan().goto([(3.0, 2.0), (0.0, 3.0)], speed=0.4), duration=40.0)
    tr = r.true
    assert math.hypot(tr['x'][-1], tr['y'][-1] - 3.0) < 0.06


def test_ramp_pitch_and_gravity_along_the_slope():
    world = World().add_room(20.0, 20.0, -10.0, -10.0)
    world.add_terrain(Ramp(2.0, 0.0, 0.0, length=4.0, height=0.4, descend=False))
    r = run_plan(Plan().straight(6.0, 0.5).stop(1.0), IDEAL_IMU, world, start=(0.0, 0.0, 0.0))
    tr = r.true
    on = (tr['x'] > 3.0) & (tr['x'] < 5.0)
    assert np.allclose(tr['pitch'][on], -math.atan(0.1), atol=1e-6)
    s = r.sensors
    ax = np.interp(tr['t'][on], s['imu_t'], s['accel'][:, 0])
    assert np.median(ax) == pytest.approx(9.80665 * math.sin(math.atan(0.1)), abs=1e-3)
    assert tr['z'][-1] == pytest.approx(0.4, abs=1e-6)


def test_tip_over_scripted():
    r = run_plan(Plan().straight(1.0, 0.5).tip_over(axis='pitch', direction=1, duration=0.5)
                 .stop(2.0), IDEAL_IMU)
    s = r.sensors
    g = r.params.imu.gravity
    assert s['accel'][-1] == pytest.approx([-g, 0.0, 0.0], abs=1e-6)
    assert s['gyro'][:, 1].max() > 2.0
    assert r.truth['tip_overs'][0]['t'] == pytest.approx(2.0, abs=0.06)
    r = run_plan(Plan().stop(0.5).tip_over(axis='roll', direction=-1, mode='free').stop(3.0),
                 IDEAL_IMU)
    assert r.true['roll'][-1] == pytest.approx(-math.pi / 2, abs=1e-6)


def test_same_seed_same_output_other_seed_other_noise():
    a = run_scenario('drive', seed=3, duration=4.0)
    b = run_scenario('drive', seed=3, duration=4.0)
    c = run_scenario('drive', seed=4, duration=4.0)
    for key in ('gyro', 'accel', 'ranges', 'js_vel', 'odom_x'):
        assert np.array_equal(a.sensors[key], b.sensors[key], equal_nan=True)
    assert not np.array_equal(a.sensors['gyro'], c.sensors['gyro'])
    assert not np.array_equal(a.sensors['ranges'], c.sensors['ranges'], equal_nan=True)
    # one sensor's settings do not change another sensor's noise stream
    d = run_scenario('drive', seed=3, duration=4.0, overrides={'lidar.noise': 0.05})
    assert np.array_equal(a.sensors['gyro'], d.sensors['gyro'])


def test_bad_requests_raise_one_line_sim_errors():
    cases = [{'name': 'nope'}, {'overrides': {'imu.nope': '1'}},
             {'overrides': {'imu.rate': 'fast'}}, {'overrides': {'imu.gyro_bias': '1,2'}},
             {'overrides': {'lidar.beams': '-3'}}, {'overrides': {'imu.gyro_noise': 'nan'}},
             {'overrides': ['imu.rate']}, {'duration': -1.0}, {'seed': -2},
             {'overrides': {'wheels.slip_episodes': '1,2,3'}},
             {'overrides': {'wheels.slip_episodes': 'a,b,c,d'}},
             {'overrides': {'robot.drive_type': 'hovercraft'}}]
    for case in cases:
        kwargs = {'name': 'drive', 'duration': 1.0}
        kwargs.update(case)
        with pytest.raises(SimError) as info:
            run_scenario(**kwargs)
        assert '\n' not in str(info.value) and str(info.value)
    assert issubclass(SimError, ValueError)


def test_overrides_as_set_strings():
    r = run_scenario('drive', duration=1.0, overrides=['imu.rate=100', 'lidar.beams=90'])
    assert r.truth['topics']['/imu'] == 101
    assert r.sensors['ranges'].shape == (11, 90)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3', 'mcap-zstd'])
def test_bag_round_trip_and_truth_json(tmp_path, storage):
    out = tmp_path / 'sim'
    truth = simulate('drive', out, seed=5, duration=3.0, storage=storage.split('-')[0],
                     compress=storage.endswith('zstd'))
    saved = json.loads(truth_path(out).read_text())
    assert saved == truth
    for key in ('scenario', 'seed', 'duration', 'gyro_bias', 'wheel_radius', 'track_width',
                'left_wheel_radius', 'right_wheel_radius', 'wheel_base', 'steering_offset',
                'lidar_x', 'lidar_y', 'lidar_yaw', 'imu_roll', 'imu_pitch', 'imu_yaw'):
        assert key in saved
    assert saved['scenario'] == 'drive' and saved['seed'] == 5 and saved['duration'] == 3.0
    assert saved['gyro_bias'] == [0.002, -0.0015, 0.003]
    assert saved['left_wheel_radius'] == pytest.approx(0.05 * 1.004)
    assert saved['track_width'] == pytest.approx(0.30 * 1.015)
    read = {}
    for m in read_messages([out]):
        read.setdefault(m.topic, []).append(m)
    assert {t: len(v) for t, v in read.items()} == saved['topics']
    mem = run_scenario('drive', seed=5, duration=3.0)
    imu_mem = mem.topic('/imu')
    imu_bag = [m.samples[0] for m in read['/imu']]
    assert np.allclose([s.gyro for s in imu_bag], [s.gyro for s in imu_mem])
    assert imu_bag[0].frame_id == 'imu_link'
    tfs = read['/tf_static'][0].samples
    pairs = {(tf.parent, tf.child) for tf in tfs}
    assert pairs == {('base_link', 'imu_link'), ('base_link', 'laser')}
    odom = read['/odom'][-1].samples[0]
    assert (odom.frame_id, odom.child_frame_id) == ('odom', 'base_link')
    times = [m.time_ns for t in read for m in read[t]]
    assert min(times) == 0
    with pytest.raises(SimError):
        simulate('drive', out, duration=1.0)  # exists already


def test_fast_encoder_is_byte_identical_to_rosbags():
    r = run_scenario('drive', seed=2, duration=2.0)
    for topic, msgtype, ns, data in encoded_streams(r):
        ref = [codec.serialize(s)[1] for tp, s in r.messages if tp == topic]
        assert len(ref) == len(data)
        assert all(a == b for a, b in zip(ref, data)), topic


def test_messages_in_time_order(drive30):
    times = [s.t if not isinstance(s, list) else s[0].t for _, s in drive30.messages]
    assert all(b >= a for a, b in zip(times, times[1:]))
    counts = {}
    for topic, _ in drive30.messages:
        counts[topic] = counts.get(topic, 0) + 1
    assert counts == drive30.truth['topics']
    assert counts['/imu'] == 30 * 200 + 1 and counts['/scan'] == 30 * 10 + 1


def test_fan_ray_casting_equals_brute_force():
    rng = np.random.default_rng(1)
    world = World().add_room(10.0, 8.0)
    for _ in range(20):
        world.add_circle(rng.uniform(1, 9), rng.uniform(1, 7), rng.uniform(0.05, 0.4), 12)
    world.add_box(5.0, 4.0, 2.0, 0.1, yaw=0.7)
    n_s, n_b = 60, 180
    tt = np.arange(n_b) / n_b * 0.1
    ox = rng.uniform(1, 9, n_s)[:, None] + rng.normal(0, 1.0, n_s)[:, None] * tt
    oy = rng.uniform(1, 7, n_s)[:, None] + rng.normal(0, 1.0, n_s)[:, None] * tt
    ang = (rng.uniform(-np.pi, np.pi, n_s)[:, None] + np.arange(n_b) * 2 * np.pi / n_b
           + rng.normal(0, 3.0, n_s)[:, None] * tt)
    brute = world.raycast(ox, oy, ang)
    fan = world.raycast_fan(ox, oy, ang)
    assert np.array_equal(np.isfinite(brute), np.isfinite(fan))
    ok = np.isfinite(brute)
    assert ok.mean() > 0.9
    assert np.max(np.abs(brute[ok] - fan[ok])) < 1e-4


def test_follow_wall_keeps_its_distance():
    world = World().add_room(6.0, 4.0).add_box(3.0, 2.0, 1.0, 1.0)
    plan = Plan().follow_wall(60.0, side='right', distance=0.4, speed=0.3)
    r = run_plan(plan, world=world, start=(1.0, 0.4, 0.0))
    tr = r.true
    d = np.array([world.nearest_distance(x, y) for x, y in zip(tr['x'][::100], tr['y'][::100])])
    assert 0.15 < d.min() and d.max() < 0.65
    assert np.median(d) == pytest.approx(0.4, abs=0.03)
    assert np.ptp(tr['x']) > 4.5 and np.ptp(tr['y']) > 2.5  # it went round the room


def test_tipped_lidar_sees_the_floor():
    world = World().add_room(20.0, 20.0, -10.0, -10.0)
    over = {'lidar.noise': 0.0, 'lidar.x': 0.0, 'lidar.z': 0.2, 'lidar.motion_distortion': 'false'}
    r = run_plan(Plan().stop(1.0).tip_over(axis='pitch', direction=1, angle=0.3, duration=0.2)
                 .stop(1.0), over, world, start=(0.0, 0.0, 0.0))
    scan = r.sensors['ranges'][-1]
    # pitched 0.3 rad nose down about the front caster (0.6 m ahead): the forward beam
    # meets the floor; the backward beam points up and meets the wall at 10 m / cos(0.3)
    z = r.true['pos'][-1, 2] + 0.2 * math.cos(0.3)
    assert scan[180] == pytest.approx(z / math.sin(0.3), abs=1e-6)
    behind = 10.0 + r.true['pos'][-1, 0] + 0.2 * math.sin(0.3)
    assert scan[0] == pytest.approx(behind / math.cos(0.3), abs=1e-6)


def test_repeated_closed_loop_steps_run_again():
    lap = Plan().stop(1.0).goto([(2.0, 0.0)], speed=0.5).goto([(0.0, 0.0)], speed=0.5)
    r = run_plan(Plan().repeat(lap, until=60.0), start=(0.0, 0.0, 0.0), duration=40.0)
    tr = r.true
    late = tr['t'] > 20.0
    assert tr['x'][late].max() > 1.9  # the second lap's goto drove out again
    assert 'drive' in SCENARIOS
    drive = run_scenario('drive', duration=200.0)
    assert np.mean(np.abs(drive.true['v'][drive.true['t'] > 100.0]) > 0.05) > 0.4


def test_gyro_drift_warmup_and_latency():
    over = dict(IDEAL_IMU, **{'imu.gyro_bias': [0.0, 0.0, 0.01],
                              'imu.gyro_bias_drift': [0.0, 0.0, 1e-4],
                              'imu.gyro_warmup': [0.0, 0.0, 0.02], 'imu.gyro_warmup_tau': 5.0})
    r = run_plan(Plan().stop(20.0), over)
    t, gz = r.sensors['imu_t'], r.sensors['gyro'][:, 2]
    assert np.allclose(gz, 0.01 + 1e-4 * t + 0.02 * np.exp(-t / 5.0), atol=1e-12)
    plan = Plan().stop(1.0).turn(math.pi, 1.0).stop(1.0)
    a = run_plan(plan, IDEAL_IMU)
    b = run_plan(plan, dict(IDEAL_IMU, **{'latency.imu': 0.05, 'latency.scan': 0.1}))
    ga = a.sensors['gyro'][:, 2]
    gb = b.sensors['gyro'][:, 2]
    # stamped t, measured at t - latency: b(t) = a(t - 0.05), 10 IMU periods later
    assert np.allclose(gb[10:], ga[:-10], atol=1e-9)
    assert np.ptp(ga) > 0.9
    assert np.array_equal(a.sensors['imu_t'], b.sensors['imu_t'])


def test_route_goes_around_furniture_not_through_it():
    from robot_calib.sim.rooms import _segment_free, free, make_room, route
    room = make_room('rect', np.random.default_rng(0))
    sofa = room.obstacles[0]
    lo, hi = sofa.min(axis=0), sofa.max(axis=0)
    mid_y = 0.5 * (lo[1] + hi[1])
    a, b = (hi[0] + 0.4, mid_y), (lo[0] + 0.3, lo[1] - 0.4)  # beside it, in front of it
    assert free(room, [a[0], b[0]], [a[1], b[1]], 0.2).all()
    assert not _segment_free(room, a, b, 0.2)
    way = route(room, a, b, 0.2)
    assert way is not None and way[-1] == b and len(way) >= 2
    for p, q in zip([a] + way[:-1], way):
        assert _segment_free(room, p, q, 0.2)
    assert route(room, a, (lo[0] + 0.1, mid_y), 0.2) is None  # inside the sofa: unreachable


def test_vacuum_robot_never_drives_through_furniture():
    from robot_calib.sim.rooms import inside
    r = run_scenario('vacuum', seed=0, duration=600.0)  # passes change at ~200 s
    s = r.sensors
    x0, y0, _ = r.truth['start_pose']
    for ob in r.truth['obstacles']:
        assert not inside(np.array(ob), s['gt_x'] + x0, s['gt_y'] + y0).any()
