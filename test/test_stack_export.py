# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Calibration results in the form the robot's own stack takes (``DIR/stack/``), end to end.

Through ``robot-calib replay`` on short simulated runs: each YAML loads with
PyYAML and has the keys ros2_control's controllers read, each URDF snippet
parses with xml.etree, each static transform is a Jazzy
``static_transform_publisher`` command, and each file names its node and bag.
"""

import json
import math
import shlex
import xml.etree.ElementTree as ET

import pytest
import yaml

sim = pytest.importorskip('robot_calib.sim')
cli = pytest.importorskip('robot_calib.cli')


def _simulate(tmp_path, name, scenario, duration, *sets):
    bag = tmp_path / name
    args = ['simulate', scenario, '--out', str(bag), '--seed', '1', '--duration', str(duration)]
    for s in sets:
        args += ['--set', s]
    assert cli.main(args) == 0
    return bag, json.loads((tmp_path / f'{name}.truth.json').read_text())


def _replay(bag, out, nodes, *sets):
    args = ['replay', str(bag), '--out', str(out), '--nodes', nodes, '--no-progress']
    for s in sets:
        args += ['--set', s]
    assert cli.main(args) == 0
    return json.loads((out / 'summary.json').read_text())


def _static_tf(path):
    """Return the static_transform_publisher arguments of a script as a dict."""
    text = path.read_text()
    assert text.startswith('#!/bin/sh\n')
    words = shlex.split(text[text.index('\nexec ') + 1:])
    assert words[:5] == ['exec', 'ros2', 'run', 'tf2_ros', 'static_transform_publisher']
    args = dict(zip(words[5::2], words[6::2]))
    assert set(args) == {'--x', '--y', '--z', '--roll', '--pitch', '--yaw', '--frame-id',
                         '--child-frame-id'}
    return args


def _joint(path):
    """Return (parent, child, xyz, rpy) of a URDF fixed-joint snippet."""
    root = ET.fromstring(path.read_text())
    assert root.tag == 'joint' and root.get('type') == 'fixed'
    origin = root.find('origin')
    return (root.find('parent').get('link'), root.find('child').get('link'),
            [float(v) for v in origin.get('xyz').split()],
            [float(v) for v in origin.get('rpy').split()])


def _header_names(path, node, bag):
    head = path.read_text().split('\n', 3)[:3]
    assert any(node in ln and str(bag) in ln for ln in head), head


def test_differential_drive_controller_lidar_and_imu_files(tmp_path):
    bag, truth = _simulate(tmp_path, 'drive', 'drive', 60)
    out = tmp_path / 'out'
    summary = _replay(bag, out, 'wheel_odometry_calibration,odometry_fusion,tilt_detection')
    calib = yaml.safe_load((out / 'wheel_calibration.yaml').read_text())
    assert calib['verdict'] == 'converged'
    stack = out / 'stack'
    ddc = yaml.safe_load((stack / 'diff_drive_controller.yaml').read_text())
    params = ddc['diff_drive_controller']['ros__parameters']
    assert {'wheel_separation', 'wheel_radius', 'left_wheel_radius_multiplier',
            'right_wheel_radius_multiplier'} <= set(params)
    assert params['wheel_separation'] == pytest.approx(calib['track_width'], rel=1e-6)
    assert params['wheel_radius'] * params['left_wheel_radius_multiplier'] == \
        pytest.approx(calib['left_wheel_radius'], rel=1e-6)
    assert params['wheel_radius'] * params['right_wheel_radius_multiplier'] == \
        pytest.approx(calib['right_wheel_radius'], rel=1e-6)
    _header_names(stack / 'diff_drive_controller.yaml', 'wheel_odometry_calibration', bag)
    # the lidar pose: calibrated x, y, yaw; height from the recording's /tf_static
    tf = _static_tf(stack / 'lidar_static_tf.sh')
    assert (tf['--frame-id'], tf['--child-frame-id']) == ('base_link', 'laser')
    assert float(tf['--x']) == pytest.approx(calib['lidar_x'], abs=1e-8)
    assert float(tf['--yaw']) == pytest.approx(calib['lidar_yaw'], abs=1e-8)
    assert float(tf['--z']) == pytest.approx(truth['lidar_z'])
    parent, child, xyz, rpy = _joint(stack / 'lidar_joint.urdf.xml')
    assert (parent, child) == ('base_link', 'laser')
    assert xyz == pytest.approx([float(tf['--x']), float(tf['--y']), float(tf['--z'])])
    assert rpy[2] == pytest.approx(calib['lidar_yaw'], abs=1e-8)
    # fusion's and tilt's IMU mounting, fusion's gyro bias
    for stem, node in (('imu_fusion', 'odometry_fusion'), ('imu_tilt', 'tilt_detection')):
        tf = _static_tf(stack / f'{stem}_static_tf.sh')
        assert (tf['--frame-id'], tf['--child-frame-id']) == ('base_link', 'imu_link')
        assert float(tf['--z']) == pytest.approx(truth['imu_z'])
        _header_names(stack / f'{stem}_joint.urdf.xml', node, bag)
        assert _joint(stack / f'{stem}_joint.urdf.xml')[:2] == ('base_link', 'imu_link')
    bias = yaml.safe_load((stack / 'imu_fusion_gyro_bias.yaml').read_text())['gyro_bias']
    est = summary['nodes']['odometry_fusion']['estimates']
    assert bias['bias'] == pytest.approx(est['gyro_bias'], rel=1e-6)
    assert bias['bias_std'] == pytest.approx(est['gyro_bias_std'], rel=1e-6)
    assert bias['frame_id'] == 'base_link' and bias['axis'] == 'z'
    # listed in summary.json and report.md
    listed = summary['stack']['files']
    assert {f'stack/{p.name}' for p in stack.iterdir()} == set(listed)
    assert listed['stack/diff_drive_controller.yaml'] == 'wheel_odometry_calibration'
    assert 'stack/lidar_static_tf.sh' in summary['artifacts']
    assert '](stack/diff_drive_controller.yaml)' in (out / 'report.md').read_text()


def test_steered_wheel_tricycle_controller_and_steering_transmission(tmp_path):
    bag, truth = _simulate(tmp_path, 'steered', 'drive', 60, 'robot.drive_type=steered_wheel',
                           'wheels.steering_offset=0.02')
    out = tmp_path / 'out'
    summary = _replay(bag, out, 'wheel_odometry_calibration')
    calib = yaml.safe_load((out / 'wheel_calibration.yaml').read_text())
    assert calib['verdict'] == 'converged'
    stack = out / 'stack'
    assert not (stack / 'diff_drive_controller.yaml').exists()
    params = yaml.safe_load((stack / 'tricycle_controller.yaml').read_text())[
        'tricycle_controller']['ros__parameters']
    assert params['wheelbase'] == pytest.approx(calib['wheel_base'], rel=1e-6)
    assert params['wheel_radius'] == pytest.approx(calib['wheel_radius'], rel=1e-6)
    text = (stack / 'tricycle_controller.yaml').read_text()
    assert 'takes no steering offset' in text and 'steering_transmission.urdf.xml' in text
    root = ET.fromstring((stack / 'steering_transmission.urdf.xml').read_text())
    assert root.tag == 'transmission'
    assert root.find('plugin').text == 'transmission_interface/SimpleTransmission'
    joint = root.find('joint')
    assert joint.get('name') == 'steering_joint'
    # SimpleTransmission: joint = actuator / reduction + offset; true = scale * reading + offset
    assert float(joint.find('offset').text) == pytest.approx(calib['steering_offset'], rel=1e-6)
    assert float(joint.find('offset').text) == pytest.approx(truth['steering_offset'], abs=0.002)
    assert 1.0 / float(joint.find('mechanical_reduction').text) == \
        pytest.approx(calib['steering_scale'], rel=1e-6)
    assert {'stack/tricycle_controller.yaml', 'stack/steering_transmission.urdf.xml',
            'stack/lidar_static_tf.sh', 'stack/lidar_joint.urdf.xml'} == \
        set(summary['stack']['files'])


def test_not_converged_writes_no_numbers_and_says_why(tmp_path):
    bag, _ = _simulate(tmp_path, 'short', 'diff_segments', 20)
    out = tmp_path / 'out'
    summary = _replay(bag, out, 'wheel_odometry_calibration')
    calib = yaml.safe_load((out / 'wheel_calibration.yaml').read_text())
    assert calib['verdict'] != 'converged'
    assert not (out / 'stack').exists()
    assert summary['stack']['files'] == {}
    assert any('not converged' in w for w in summary['stack']['withheld'])
    assert 'not written: wheel_odometry_calibration' in (out / 'report.md').read_text()


def test_imu_mounted_rotated_is_exported_as_mounted(tmp_path):
    bag, truth = _simulate(tmp_path, 'rotated', 'fusion_drive', 30, 'imu.roll=3.141592653589793',
                           'imu.yaw=1.5707963267948966')
    out = tmp_path / 'out'
    _replay(bag, out, 'odometry_fusion,tilt_detection')
    for stem in ('imu_fusion', 'imu_tilt'):
        tf = _static_tf(out / 'stack' / f'{stem}_static_tf.sh')
        roll, pitch, yaw = (float(tf[k]) for k in ('--roll', '--pitch', '--yaw'))
        # the same rotation as the truth's (roll pi, yaw pi/2), whatever the Euler branch
        from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix
        got = quat_to_matrix(quat_from_rpy(roll, pitch, yaw))
        want = quat_to_matrix(quat_from_rpy(truth['imu_roll'], truth['imu_pitch'],
                                            truth['imu_yaw']))
        assert abs(got - want).max() < 1e-6
        _, _, _, rpy = _joint(out / 'stack' / f'{stem}_joint.urdf.xml')
        assert rpy == pytest.approx([roll, pitch, yaw])
        assert math.isfinite(float(tf['--z']))


def test_wheel_node_writes_the_stack_files_beside_its_yaml(tmp_path):
    rclpy = pytest.importorskip('rclpy')
    from rclpy.parameter import Parameter
    from robot_calib.methods.wheel_odometry_calibration.pipeline import WheelCalibrationPipeline
    from robot_calib.nodes.base import PipelineNode
    res = sim.run_scenario('drive', seed=1, duration=60.0)
    rclpy.init()
    try:
        node = PipelineNode(WheelCalibrationPipeline, parameter_overrides=[
            Parameter('output_dir', value=str(tmp_path))])
        for topic, sample in res.messages:
            key = topic.lstrip('/')
            if key in ('joint_states', 'scan', 'tf_static'):
                for one in (sample if isinstance(sample, list) else [sample]):
                    node.pipeline.process(key, one)
        node.finish()
        calib = yaml.safe_load((tmp_path / 'wheel_calibration.yaml').read_text())
        assert calib['verdict'] == 'converged'
        text = (tmp_path / 'stack' / 'diff_drive_controller.yaml').read_text()
        assert 'live topics' in text.splitlines()[0] and 'wheel_odometry_calibration' in text
        params = yaml.safe_load(text)['diff_drive_controller']['ros__parameters']
        assert params['wheel_separation'] == pytest.approx(calib['track_width'], rel=1e-6)
        assert _static_tf(tmp_path / 'stack' / 'lidar_static_tf.sh')['--child-frame-id'] == \
            'laser'
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_frame_names_from_the_data_cannot_break_out_of_the_files(tmp_path):
    """A scan frame named like a shell command or XML stays a name in every file."""
    from robot_calib.pipelines import stack_export as SE
    evil = 'laser"/><x a="1$(touch pwned); `id` -->\n# '
    result = {'drive_type': 'differential', 'left_wheel_radius': 0.05, 'right_wheel_radius': 0.05,
              'track_width': 0.3, 'lidar_x': 0.1, 'lidar_y': 0.0, 'lidar_yaw': 0.0,
              'verdict': 'converged'}
    out = SE.wheel_files(result, 'wheel_odometry_calibration', 'bag -->\n$(id)',
                         base_frame='base_link', lidar_frame=evil)
    (tmp_path / 'tf.sh').write_text(out.files['lidar_static_tf.sh'])
    args = _static_tf(tmp_path / 'tf.sh')
    assert args['--child-frame-id'] == evil
    (tmp_path / 'j.xml').write_text(out.files['lidar_joint.urdf.xml'])
    assert _joint(tmp_path / 'j.xml')[1] == evil
    assert yaml.safe_load(out.files['diff_drive_controller.yaml'])['diff_drive_controller']


def test_upside_down_lidar_keeps_its_roll_and_gets_the_calibrated_yaw(tmp_path):
    bag, truth = _simulate(tmp_path, 'ud', 'drive', 60, 'lidar.upside_down=true', 'lidar.yaw=0.05')
    out = tmp_path / 'out'
    _replay(bag, out, 'wheel_odometry_calibration')
    calib = yaml.safe_load((out / 'wheel_calibration.yaml').read_text())
    assert calib['verdict'] == 'converged'
    tf = _static_tf(out / 'stack' / 'lidar_static_tf.sh')
    assert abs(abs(float(tf['--roll'])) - math.pi) < 1e-6 and float(tf['--pitch']) == 0.0
    assert float(tf['--yaw']) == pytest.approx(calib['lidar_yaw'], abs=1e-8)
    assert float(tf['--yaw']) == pytest.approx(truth['lidar_yaw'], abs=0.005)
