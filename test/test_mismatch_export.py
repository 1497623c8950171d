# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The findings as settings: ``sim_params.yaml`` and ``suggestions.yaml`` beside findings.json.

``mismatch`` writes both, naming the recordings; ``simulate follow --params`` takes
the parameter file; a simulation corrected with the findings (real = f(sim), so the
simulation applies f) drifts less from the real robot than the ideal one, and the
report shows the trajectories of all three.
"""

import json

import numpy as np
import pytest
from robot_calib import cli
from robot_calib.io.bags import read_messages
from robot_calib.mismatch import export
import yaml

DRIVE = ('drive.linear_time_constant=0.4', 'drive.turn_speed_loss=1.0')
NO_WHEEL_ERRORS = ('wheels.left_radius_error=0', 'wheels.right_radius_error=0',
                   'wheels.track_width_error=0')


def _sets(items):
    return [a for kv in items for a in ('--set', kv)]


def _end(path, topic='/ground_truth/odom'):
    s = [s for m in read_messages([path], topics=[topic]) for s in m.samples][-1]
    return np.array([s.x, s.y])


def _findings(sim, real, rows):
    return {'verdict': 'mismatch', 'inputs': {'sim': str(sim), 'real': str(real)},
            'findings': [{'channel': ch, 'effect': e, 'parameters': p, 'window': None,
                          'confidence': 0.9, 'explanation': ''} for e, ch, p in rows]}


@pytest.fixture(scope='module')
def pair(tmp_path_factory):
    """Return a real bag whose robot lags and slows in turns, and its ideal follower."""
    d = tmp_path_factory.mktemp('pair')
    real, ideal = d / 'real', d / 'ideal'
    assert cli.main(['simulate', 'drive', '--out', str(real), '--duration', '40', '--seed', '2',
                     *_sets(DRIVE + NO_WHEEL_ERRORS)]) == 0
    assert cli.main(['simulate', 'follow', str(real), '--out', str(ideal)]) == 0
    return d, real, ideal


def test_mismatch_writes_settings_that_follow_takes(pair, capsys):
    d, real, ideal = pair
    out = d / 'mm'
    assert cli.main(['mismatch', '--sim', str(ideal), '--real', str(real), '--out',
                     str(out)]) == 0
    capsys.readouterr()
    params = yaml.safe_load((out / 'sim_params.yaml').read_text())
    assert params['source'] == {'sim': str(ideal), 'real': str(real)}
    assert isinstance(params['sim'], dict)
    text = (out / 'sim_params.yaml').read_text()
    assert str(real) in text and str(ideal) in text
    found = json.loads((out / 'findings.json').read_text())
    # every named drive lag is carried into the simulator's drive, on its own axis
    lags = [f for f in found['findings'] if f['effect'] == 'drive_lag' and not f['window']]
    assert lags
    for axis in ('linear', 'angular'):
        taus = [f['parameters']['tau'] for f in lags
                if f['channel'].endswith('angular.z') == (axis == 'angular')]
        if taus:  # one odometry topic per axis is carried (ground truth first)
            assert params['sim']['drive'][f'{axis}_time_constant'] >= min(taus) - 1e-9
    corrected = d / 'corrected'
    assert cli.main(['simulate', 'follow', str(real), '--out', str(corrected), '--params',
                     str(out / 'sim_params.yaml')]) == 0
    truth = json.loads((d / 'corrected.truth.json').read_text())
    for group, values in params['sim'].items():
        for key, value in values.items():
            assert truth['params'][f'{group}.{key}'] == pytest.approx(value)
    sug = yaml.safe_load((out / 'suggestions.yaml').read_text())
    ros = sug['diff_drive_controller']['ros__parameters']
    for key in ('wheel_separation_multiplier', 'left_wheel_radius_multiplier',
                'right_wheel_radius_multiplier'):
        assert isinstance(ros[key], (int, float))
    for axis, comp in (('linear', 'x'), ('angular', 'z')):
        for key in ('max_velocity', 'max_acceleration', 'has_acceleration_limits'):
            assert key in ros[axis][comp]
    assert sug['source']['real'] == str(real)
    assert '<imu>' in sug['gazebo_imu_sdf'] and '<mean>' in sug['gazebo_imu_sdf']
    # the report's trajectories, with the corrected simulation beside the ideal one
    out2 = d / 'mm2'
    assert cli.main(['mismatch', '--sim', str(ideal), '--real', str(real), '--out', str(out2),
                     '--corrected', str(corrected)]) == 0
    said = capsys.readouterr().out
    assert 'corrected vs real' in said
    report = (out2 / 'report.md').read_text()
    assert '## Trajectories' in report and 'trajectories.png' in report
    assert (out2 / 'trajectories.png').is_file()
    traj = json.loads((out2 / 'findings.json').read_text())['trajectory']
    assert traj['topic'] == '/ground_truth/odom'
    assert traj['corrected_drift']['rms_m'] <= traj['sim_drift']['rms_m']


def test_corrected_simulation_drifts_less(pair, tmp_path):
    d, real, ideal = pair
    rows = [('drive_lag', '/odom.twist.twist.linear.x', {'tau': 0.4}),
            ('turn_speed_loss', '/odom.twist.twist.linear.x', {'coefficient': 1.0})]
    export.write(tmp_path, _findings(ideal, real, rows), str(ideal))
    params = yaml.safe_load((tmp_path / 'sim_params.yaml').read_text())
    assert params['sim']['drive'] == {'linear_time_constant': 0.4, 'turn_speed_loss': 1.0}
    corrected = tmp_path / 'corrected'
    assert cli.main(['simulate', 'follow', str(real), '--out', str(corrected), '--params',
                     str(tmp_path / 'sim_params.yaml')]) == 0
    before = np.linalg.norm(_end(ideal) - _end(real))
    after = np.linalg.norm(_end(corrected) - _end(real))
    assert before > 0.3
    assert after < 0.05 * before


def test_findings_map_to_the_simulator_as_real_equals_f_of_sim(pair, tmp_path):
    d, real, ideal = pair
    rows = [('wheel_radius_scale', '/odom.twist.twist.linear.x', {'scale': 0.05}),
            ('track_width_scale', '/odom.twist.twist.angular.z', {'scale': 0.1}),
            ('gyro_bias', '/imu.angular_velocity.z', {'bias': 0.01}),
            ('drive_rate_limit', '/odom.twist.twist.linear.x', {'limit': 0.7}),
            ('wheel_speed_limit', '/odom.twist.twist.linear.x',
             {'limit': 0.3, 'half_track': 0.15}),
            ('gyro_cross_axis', '/imu.angular_velocity.x', {'coefficient': 0.02})]
    export.write(tmp_path, _findings(ideal, real, rows), str(ideal))
    params = yaml.safe_load((tmp_path / 'sim_params.yaml').read_text())['sim']
    assert params['drive']['linear_gain'] == pytest.approx(0.05)
    assert params['drive']['angular_gain'] == pytest.approx(1 / 1.1 - 1)
    assert params['drive']['linear_rate_limit'] == pytest.approx(0.7)
    # the faster wheel's rim speed 0.3 m/s is 6 rad/s of the simulated robot's 0.05 m radius
    assert params['drive']['max_wheel_speed'] == pytest.approx(0.3 / 0.05)
    assert params['imu']['gyro_bias'] == pytest.approx([0.0, 0.0, 0.01])
    assert 'gyro_cross_axis' in (tmp_path / 'sim_params.yaml').read_text().split('\nsim:')[1]
    ros = yaml.safe_load((tmp_path / 'suggestions.yaml').read_text())[
        'diff_drive_controller']['ros__parameters']
    # the simulated controller must drive 1.05 x and turn 1 / 1.1 x per command
    assert ros['left_wheel_radius_multiplier'] == pytest.approx(1 / 1.05, rel=1e-5)
    assert ros['wheel_separation_multiplier'] == pytest.approx(1 / 1.1 / 1.05, rel=1e-5)
    assert ros['linear']['x']['max_acceleration'] == pytest.approx(0.7)
    assert np.isnan(ros['angular']['z']['max_acceleration'])
    assert ros['linear']['x']['max_velocity'] == pytest.approx(0.3)
    assert ros['angular']['z']['max_velocity'] == pytest.approx(0.3 / 0.15)
    # the corrected simulation's odometry reads what the real one would: speed x 1.05
    scaled = tmp_path / 'scaled'
    assert cli.main(['simulate', 'follow', str(real), '--out', str(scaled),
                     '--set', 'drive.linear_gain=0.05']) == 0
    path = [np.hypot(*_end(p, '/odom')) for p in (ideal, scaled)]
    odom = {p: [s for m in read_messages([p], topics=['/odom']) for s in m.samples]
            for p in (ideal, scaled)}
    dist = [sum(np.hypot(b.x - a.x, b.y - a.y) for a, b in zip(o, o[1:]))
            for o in odom.values()]
    assert dist[1] / dist[0] == pytest.approx(1.05, rel=0.01)
    assert path[0] > 0


def test_an_effect_seen_on_several_channels_is_applied_once(tmp_path):
    rows = [('wheel_speed_limit', '/odom.twist.twist.linear.x',
             {'limit': 0.3, 'half_track': 0.15}),
            ('wheel_speed_limit', '/ground_truth/odom.twist.twist.linear.x',
             {'limit': 0.29, 'half_track': None}),
            ('drive_lag', '/odom.twist.twist.angular.z', {'tau': 0.3, 'damping': 0.5}),
            ('drive_lag', '/ground_truth/odom.twist.twist.angular.z', {'tau': 0.31}),
            ('drive_lag', '/joint_states.velocity.left_wheel_joint', {'tau': 0.4}),
            ('gyro_bias', '/imu.angular_velocity.z', {'bias': 0.01}),
            ('gyro_bias', '/imu2.angular_velocity.z', {'bias': 0.011})]
    export.write(tmp_path, _findings('sim', 'real', rows))
    params = yaml.safe_load((tmp_path / 'sim_params.yaml').read_text())['sim']
    # the turn-rate lag from an angular channel, the forward lag from the wheel joint
    assert params['drive']['angular_time_constant'] == pytest.approx(0.3)
    assert params['drive']['angular_damping'] == pytest.approx(0.5)  # a second order
    # one cap, the one whose half track is known: 0.3 m/s on the 0.05 m wheels
    assert params['drive']['max_wheel_speed'] == pytest.approx(6.0)
    assert params['drive']['linear_time_constant'] == pytest.approx(0.4)
    assert params['imu']['gyro_bias'][2] == pytest.approx(0.01)


def test_a_wheel_rate_cap_exports_in_rad_s_and_yields_to_the_odometry_cap(tmp_path):
    """A cap found on the wheel joints: drive.max_wheel_speed as it is; an odometry one first."""
    joint = ('wheel_speed_limit', '/joint_states.velocity.left_wheel_joint',
             {'limit': 5.0, 'half_track': None})
    export.write(tmp_path, _findings('sim', 'real', [joint]))
    params = yaml.safe_load((tmp_path / 'sim_params.yaml').read_text())['sim']
    assert params['drive']['max_wheel_speed'] == pytest.approx(5.0)  # no division by a radius
    text = (tmp_path / 'suggestions.yaml').read_text()
    ros = yaml.safe_load(text)['diff_drive_controller']['ros__parameters']
    assert ros['linear']['x']['has_velocity_limits'] is False  # no m/s without the radius
    assert 'cap on the wheel rates' in text
    # beside an odometry cap with its half track the odometry's is exported; beside a top
    # speed met driving straight (half track unknown) the wheels'
    odom = ('wheel_speed_limit', '/odom.twist.twist.linear.x', {'limit': 0.2, 'half_track': 0.1})
    top = ('wheel_speed_limit', '/odom.twist.twist.linear.x', {'limit': 0.2, 'half_track': None})
    for rows, want in (([joint, odom], 0.2 / 0.05), ([odom, joint], 0.2 / 0.05),
                       ([joint, top], 5.0), ([top, joint], 5.0)):
        export.write(tmp_path, _findings('sim', 'real', rows))
        params = yaml.safe_load((tmp_path / 'sim_params.yaml').read_text())['sim']
        assert params['drive']['max_wheel_speed'] == pytest.approx(want), rows


def test_a_top_speed_met_driving_straight_is_not_a_simulated_wheel_cap(tmp_path):
    """Half track unknown: not the simulator's cap (it would slow turns); a velocity limit."""
    top = ('wheel_speed_limit', '/odom.twist.twist.linear.x', {'limit': 0.2, 'half_track': None})
    export.write(tmp_path, _findings('sim', 'real', [top]))
    text = (tmp_path / 'sim_params.yaml').read_text()
    params = yaml.safe_load(text)['sim']
    assert 'max_wheel_speed' not in params.get('drive', {})
    assert 'top speed met driving straight' in text  # listed as not applied, with the reason
    ros = yaml.safe_load((tmp_path / 'suggestions.yaml').read_text())[
        'diff_drive_controller']['ros__parameters']
    assert ros['linear']['x']['has_velocity_limits'] is True
    assert ros['linear']['x']['max_velocity'] == pytest.approx(0.2)


def test_a_wheel_joint_limit_is_not_a_body_limit(tmp_path):
    """A rate limit or deadband of one wheel (rad/s^2, rad/s) is not the body's (m/s^2, m/s)."""
    rows = [('drive_rate_limit', '/joint_states.velocity.left_wheel_joint', {'limit': 9.0}),
            ('drive_deadband', '/joint_states.velocity.left_wheel_joint', {'band': 0.5}),
            ('drive_lag', '/joint_states.velocity.left_wheel_joint', {'tau': 0.3})]
    export.write(tmp_path, _findings('sim', 'real', rows))
    text = (tmp_path / 'sim_params.yaml').read_text()
    drive = yaml.safe_load(text)['sim']['drive']
    assert not any(k.endswith(('_rate_limit', '_deadband')) for k in drive), drive
    assert drive['linear_time_constant'] == pytest.approx(0.3)  # a time is the same on both
    assert text.count("one wheel's own limit") == 2
