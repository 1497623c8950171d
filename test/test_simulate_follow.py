# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
``robot-calib simulate follow``: the simulated robot driven by a recording's commands.

A ``simulate drive`` bag used as the real one is followed on its clock and under
its topic names; renamed topics and stamped commands are found; a bag without
commands is refused in one line; the robot carries drive dynamics that a
follower with the same parameters reproduces exactly.
"""

import json

import numpy as np
import pytest

from robot_calib import cli, sim
from robot_calib.core import types as T
from robot_calib.io.bags import BagWriter, list_topics, read_messages


def _samples(path, topic):
    return [s for m in read_messages([path], topics=[topic]) for s in m.samples]


def _truth_end(path, topic='/ground_truth/odom'):
    s = _samples(path, topic)[-1]
    return np.array([s.x, s.y])


def test_follow_a_simulated_drive_on_its_clock_and_topics(tmp_path, capsys):
    real, out = tmp_path / 'real', tmp_path / 'sim'
    assert cli.main(['simulate', 'drive', '--out', str(real), '--duration', '8',
                     '--set', 'start_time=1000.25']) == 0
    capsys.readouterr()
    assert cli.main(['simulate', 'follow', str(real), '--out', str(out)]) == 0
    said = capsys.readouterr().out
    assert '/cmd_vel' in said and 'Twist' in said
    real_topics, sim_topics = list_topics([real]), list_topics([out])
    for topic in ('/odom', '/imu', '/joint_states', '/cmd_vel', '/ground_truth/odom',
                  '/tf_static'):
        assert sim_topics[topic][0] == real_topics[topic][0]
    assert '/scan' not in sim_topics  # no world to scan
    # the clock: the same stamps, message by message
    for topic in ('/odom', '/imu', '/joint_states'):
        rt = [s.t for s in _samples(real, topic)]
        st = [s.t for s in _samples(out, topic)]
        assert st == pytest.approx(rt, abs=1e-6)
    assert _samples(out, '/odom')[0].t == pytest.approx(1000.25)
    # the commands are the real ones
    rc, sc = _samples(real, '/cmd_vel'), _samples(out, '/cmd_vel')
    assert [(c.t, c.vx, c.wz) for c in sc] == [(c.t, c.vx, c.wz) for c in rc]
    truth = json.loads((tmp_path / 'sim.truth.json').read_text())
    assert truth['command_topic'] == '/cmd_vel'
    assert truth['start_time'] == pytest.approx(1000.25)
    assert truth['scenario'] == 'follow'
    # the simulated robot drove: its true path follows the real one's closely (the drive
    # scenario's wheel errors are the only difference)
    gap = np.linalg.norm(_truth_end(out) - _truth_end(real))
    assert np.linalg.norm(_truth_end(real)) > 1.0 and gap < 0.3


def _renamed_bag(path, stamped=True):
    result = sim.run_scenario('drive', duration=5.0, overrides={'start_time': 50.0})
    names = {'/odom': '/base/odom', '/imu': '/imu/data', '/joint_states': '/wheels/states',
             '/ground_truth/odom': '/vicon/odom', '/cmd_vel': '/nav/cmd'}
    with BagWriter(path) as bag:
        for topic, s in result.messages:
            if topic not in names:
                continue
            if topic == '/cmd_vel' and stamped:
                s = T.StampedTwistSample(s.t, s.vx, 0.0, s.wz)
            if topic == '/imu':
                s = T.ImuSample(s.t, s.gyro, s.accel, 'imu_mount')
            bag.write(names[topic], s)


def test_follow_finds_renamed_topics_and_stamped_commands(tmp_path, capsys):
    real, out = tmp_path / 'real', tmp_path / 'sim'
    _renamed_bag(real)
    assert cli.main(['simulate', 'follow', str(real), '--out', str(out)]) == 0
    assert '/nav/cmd' in capsys.readouterr().out
    topics = list_topics([out])
    assert {'/base/odom', '/imu/data', '/wheels/states', '/vicon/odom', '/nav/cmd'} <= set(topics)
    assert topics['/nav/cmd'][0] == 'geometry_msgs/msg/TwistStamped'
    assert not {'/odom', '/imu', '/joint_states'} & set(topics)
    assert _samples(out, '/imu/data')[0].frame_id == 'imu_mount'
    truth = json.loads((tmp_path / 'sim.truth.json').read_text())
    assert truth['topic_map']['/vicon/odom'] == 'ground_truth'
    assert truth['topic_map']['/base/odom'] == 'odom'
    # the ground-truth topic carries the true motion, the odometry topic the wheel odometry
    real_truth, sim_truth = _samples(real, '/vicon/odom')[-1], _samples(out, '/vicon/odom')[-1]
    assert np.hypot(real_truth.x - sim_truth.x, real_truth.y - sim_truth.y) < 0.1


def test_follow_refuses_a_bag_without_commands(tmp_path, capsys):
    real = tmp_path / 'imu_only'
    with BagWriter(real) as bag:
        for k in range(20):
            bag.write('/imu', T.ImuSample(k * 0.01, np.zeros(3), np.array([0, 0, 9.81])))
    assert cli.main(['simulate', 'follow', str(real), '--out', str(tmp_path / 'sim')]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'no velocity commands' in err
    assert not (tmp_path / 'sim').exists() and not (tmp_path / 'sim.truth.json').exists()


def test_follow_asks_which_of_several_command_topics(tmp_path, capsys):
    real = tmp_path / 'two'
    with BagWriter(real) as bag:
        for k in range(50):
            bag.write('/teleop/twist', T.TwistSample(k * 0.1, 0.2, 0.0, 0.0), int(k * 1e8))
            bag.write('/nav/twist', T.TwistSample(k * 0.1, 0.0, 0.0, 0.5), int(k * 1e8))
    assert cli.main(['simulate', 'follow', str(real), '--out', str(tmp_path / 's1')]) == 2
    assert '--cmd-topic' in capsys.readouterr().err
    assert cli.main(['simulate', 'follow', str(real), '--out', str(tmp_path / 's2'),
                     '--cmd-topic', '/nav/twist']) == 0
    end = _samples(tmp_path / 's2', '/ground_truth/odom')[-1]
    assert end.yaw == pytest.approx(0.5 * 4.9, abs=0.15)  # turned in place, as commanded


def test_the_robot_carries_drive_dynamics_that_a_follower_reproduces(tmp_path):
    drive = ['drive.linear_time_constant=0.4', 'drive.angular_dead_time=0.1',
             'drive.turn_speed_loss=1.0', 'drive.linear_rate_limit=0.8',
             'drive.max_wheel_speed=12']
    real = tmp_path / 'real'
    sets = [a for kv in drive for a in ('--set', kv)]
    assert cli.main(['simulate', 'drive', '--out', str(real), '--duration', '30', *sets]) == 0
    wheels = [a for kv in ('wheels.left_radius_error=0.004', 'wheels.right_radius_error=-0.003',
                           'wheels.track_width_error=0.015') for a in ('--set', kv)]
    for name, extra in (('ideal', []), ('same', sets)):
        assert cli.main(['simulate', 'follow', str(real), '--out', str(tmp_path / name),
                         *wheels, *extra]) == 0
    ideal = np.linalg.norm(_truth_end(tmp_path / 'ideal') - _truth_end(real))
    same = np.linalg.norm(_truth_end(tmp_path / 'same') - _truth_end(real))
    assert ideal > 0.2
    assert same < 1e-6


def test_default_simulation_has_an_ideal_drive(tmp_path):
    a = sim.run_scenario('drive', duration=5.0)
    b = sim.run_scenario('drive', duration=5.0, overrides={'drive.linear_deadband': 1e-12})
    assert a.truth['params']['drive.turn_speed_loss'] == 0.0
    # the dynamic path with nothing in it moves like the plain one
    assert np.abs(a.true['x'] - b.true['x']).max() < 1e-9


def test_follow_refuses_a_recording_with_an_unset_stamp(tmp_path, capsys):
    real = tmp_path / 'zero'
    with BagWriter(real) as bag:
        bag.write('/imu', T.ImuSample(0.0, np.zeros(3), np.array([0, 0, 9.81])), int(1.7e18))
        for k in range(10):
            bag.write('/cmd_vel', T.TwistSample(1.7e9 + k * 0.1, 0.1), int(1.7e18 + k * 1e8))
    assert cli.main(['simulate', 'follow', str(real), '--out', str(tmp_path / 'sim')]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'unset' in err
    assert not (tmp_path / 'sim').exists()


def test_a_steering_joint_makes_the_follower_a_steered_wheel(tmp_path):
    real, out = tmp_path / 'agv', tmp_path / 'sim'
    assert cli.main(['simulate', 'agv_segments', '--out', str(real), '--duration', '10']) == 0
    assert cli.main(['simulate', 'follow', str(real), '--out', str(out)]) == 0
    truth = json.loads((tmp_path / 'sim.truth.json').read_text())
    assert truth['drive_type'] == 'steered_wheel'
    assert _samples(out, '/joint_states')[0].names == ('steering_joint', 'traction_joint')
