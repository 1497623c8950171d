# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The drive type of wheel calibration is told by the joints, and never guessed with confidence."""

import json

import pytest
from robot_calib.methods.wheel_odometry_calibration import drive_detect as D
from robot_calib.methods.wheel_odometry_calibration.params import WheelCalibParams
from robot_calib.methods.wheel_odometry_calibration.pipeline import WheelCalibrationPipeline
from test_wheel_calib_nodes import _feed, _sim
import yaml

CONFIGURED = D.JointNames('left_wheel_joint', 'right_wheel_joint', 'traction_joint',
                          'steering_joint')


@pytest.mark.parametrize('names, drive, joints', [
    (('left_wheel_joint', 'right_wheel_joint'), 'differential',
     ('left_wheel_joint', 'right_wheel_joint')),
    (('steering_joint', 'traction_joint', 'arm_1'), 'steered_wheel',
     ('traction_joint', 'steering_joint')),
    (('wheel_left_joint', 'wheel_right_joint', 'caster_wheel_joint'), 'differential',
     ('wheel_left_joint', 'wheel_right_joint')),
    (('front_steer', 'front_wheel', 'rear_left_wheel', 'rear_right_wheel'), 'steered_wheel',
     ('front_wheel', 'front_steer')),
    (('LeftWheel', 'RightWheel'), 'differential', ('LeftWheel', 'RightWheel')),
])
def test_drive_told_by_joint_names(names, drive, joints):
    found, why = D.detect(names, CONFIGURED)
    assert found is not None, why
    assert (found.drive_type, found.joints) == (drive, joints)


@pytest.mark.parametrize('names, reason', [
    (('shoulder', 'elbow'), 'no wheel joints'),
    (('left_wheel_joint',), 'not exactly one left and one right'),
    (('steer_a', 'steer_b', 'drive'), 'several steering joints'),
    (('steering', 'left_wheel', 'right_wheel'), 'not exactly one traction joint'),
    (('left_wheel_joint', 'right_wheel_joint', 'steering_joint', 'traction_joint'),
     'both drive types'),
])
def test_undecidable_joints_say_why(names, reason):
    found, why = D.detect(names, CONFIGURED)
    assert found is None and reason in why


def test_default_parameters_calibrate_a_steered_robot_as_steered(tmp_path):
    """The case of the report: an AGV replayed with default parameters (drive_type auto)."""
    cli = pytest.importorskip('robot_calib.cli')
    sim = pytest.importorskip('robot_calib.sim')
    bag = tmp_path / 'agv'
    truth = sim.simulate('agv_segments', bag, seed=1, duration=60.0)
    out = tmp_path / 'out'
    assert cli.main(['replay', str(bag), '--out', str(out), '--nodes',
                     'wheel_odometry_calibration', '--no-progress']) == 0
    d = yaml.safe_load((out / 'wheel_calibration.yaml').read_text())
    assert d['drive_type'] == 'steered_wheel'
    node = json.loads((out / 'summary.json').read_text())['nodes']['wheel_odometry_calibration']
    assert node['drive_type_source'] == 'configured joint names'
    assert node['inputs']['joint_states'].get('rejected_missing_joints', 0) == 0
    if d['verdict'] == 'converged':
        assert abs(d['steering_offset'] - truth['steering_offset']) < 4 * d['steering_offset_std']


def test_configured_drive_contradicted_by_the_joints_never_converges():
    res = _sim('diff_segments', 60.0)
    # the differential robot's joints, the steered drive configured
    pipe = WheelCalibrationPipeline(WheelCalibParams(drive_type='steered_wheel'))
    _feed(pipe, res.messages, topics=('joint_states', 'odom', 'scan', 'tf_static'))
    assert pipe.result.segments, 'the odometry fallback produced no segments'
    verdict = pipe.result.verdict
    assert verdict != 'converged'
    assert 'looks differential' in verdict and 'set drive_type' in verdict
    # the same drive with the right (detected) drive type: joints used, drive not in question
    pipe = WheelCalibrationPipeline(WheelCalibParams(wheel_radius=0.05, track_width=0.3))
    _feed(pipe, res.messages, topics=('joint_states', 'odom', 'scan', 'tf_static'))
    assert pipe.result.drive_type == 'differential'
    assert pipe.summary()['inputs']['joint_states']['accepted'] > 100
    assert 'drive' not in pipe.result.verdict


def test_odometry_alone_cannot_tell_the_drive():
    res = _sim('diff_segments', 40.0)
    pipe = WheelCalibrationPipeline(WheelCalibParams(wheel_radius=0.05, track_width=0.3))
    _feed(pipe, res.messages, topics=('odom', 'scan', 'tf_static'))
    assert pipe.result.segments > 5
    assert pipe.result.verdict.startswith('Drive type unknown')
    # told explicitly, the same odometry is calibrated
    pipe = WheelCalibrationPipeline(WheelCalibParams(drive_type='differential'))
    _feed(pipe, res.messages, topics=('odom', 'scan', 'tf_static'))
    assert 'drive type' not in pipe.result.verdict.lower()
