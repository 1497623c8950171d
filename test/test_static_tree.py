# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Sensor mountings through chains of static transforms (base_link -> mount link -> sensor).

URDFs often put a sensor below a mount or plate link. Before, only a direct
base_link -> sensor transform was taken: the tilt node measured the tilt of an IMU
mounted on its side through a mount link as the robot's (a fall alert 0.02 s into a
level drive), the wheel calibration and the gyro line used the nominal lidar pose,
and loop closure took the last link alone as the mounting.
"""

import dataclasses
import math

import numpy as np
import pytest
from robot_calib.core import frames
from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix
from robot_calib.core.types import ImuSample, ScanSample, StaticTransform


def _tf(parent, child, xyz, rpy):
    return StaticTransform(parent, child, np.array(xyz, dtype=float), quat_from_rpy(*rpy))


MOUNT = _tf('base_link', 'sensor_plate', (0.10, 0.02, 0.30), (0.0, 0.0, 0.4))
LASER = _tf('sensor_plate', 'laser', (0.05, -0.01, 0.02), (0.0, 0.0, -0.1))
IMU_MOUNT = _tf('base_link', 'imu_mount', (0.0, 0.0, 0.1), (math.pi / 2, 0.0, 0.0))
IMU = _tf('imu_mount', 'imu_link', (0.01, 0.0, 0.0), (0.0, 0.0, 0.3))


def _composed(*chain):
    rot, pos = np.eye(3), np.zeros(3)
    for tf in chain:
        pos = pos + rot @ tf.translation
        rot = rot @ quat_to_matrix(tf.rotation)
    return rot, pos


def test_a_chain_is_composed_from_the_base_down():
    tree = frames.StaticTree()
    for tf in (LASER, IMU, MOUNT, IMU_MOUNT):       # children before their parents
        tree.add(tf)
    m = tree.mounting('laser', 'base_link')
    rot, pos = _composed(MOUNT, LASER)
    assert np.allclose(frames.rotation_matrix(m), rot) and np.allclose(m.translation, pos)
    assert frames.planar_pose(m) == pytest.approx((pos[0], pos[1], 0.3))
    assert tree.mounting('sensor_plate', 'base_link') is MOUNT   # a direct link as received
    across = tree.mounting('laser', 'imu_mount')                 # another branch: via the top
    rot_m, pos_m = _composed(IMU_MOUNT)
    assert np.allclose(frames.rotation_matrix(across), rot_m.T @ rot)
    assert np.allclose(across.translation, rot_m.T @ (pos - pos_m))
    assert tree.mounting('wheel', 'base_link') is None
    assert np.allclose(frames.rotation_matrix(tree.mounting('imu_link')),
                       _composed(IMU_MOUNT, IMU)[0])                # from the top of the chain
    assert sorted(tree.leaves()) == ['imu_link', 'laser']
    # base_footprint -> base_link and base_footprint -> imu_link: base_link -> imu_link
    feet = frames.StaticTree()
    for tf in (_tf('base_footprint', 'base_link', (0, 0, 0.05), (0, 0, 0)),
               _tf('base_footprint', 'imu', (0.1, 0, 0.2), (math.pi / 2, 0, 0))):
        feet.add(tf)
    m = feet.mounting('imu', 'base_link')
    assert np.allclose(m.translation, (0.1, 0.0, 0.15))
    assert np.allclose(frames.rotation_matrix(m), quat_to_matrix(quat_from_rpy(math.pi / 2, 0, 0)))
    # base_frame in no transform (a tree whose body is base_footprint): from the top
    assert tree.mounting('sensor_plate', 'robot_body') is MOUNT
    tree.add(_tf('map', 'landmark', (1, 0, 0), (0, 0, 0)))      # a tree of its own
    assert tree.mounting('laser', 'map') is None
    tree.add(_tf('laser', 'sensor_plate', (0, 0, 0), (0, 0, 0)))  # a cycle ends, not loops
    assert tree.mounting('laser', 'base_link') is None


def test_tilt_takes_an_imu_mounted_through_a_chain():
    from robot_calib.methods.tilt_detection.params import TiltParams
    from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
    pipe = TiltPipeline(TiltParams())
    for tf in (IMU, IMU_MOUNT):
        pipe.on_static_transform(tf)
    to_imu = _composed(IMU_MOUNT, IMU)[0].T           # base -> IMU frame
    for i in range(400):                               # level, still, 2 s at 200 Hz
        pipe.process('imu', ImuSample(i * 0.005, to_imu @ [0.0, 0.0, 0.0],
                                      to_imu @ [0.0, 0.0, 9.81], 'imu_link'))
    s = pipe.summary()
    assert s['mounting'] == '/tf_static'
    assert s['alerts'] == 0 and s['final_tilt_deg'] < 1.0


def test_gyro_line_and_wheel_calibration_take_a_lidar_through_a_chain():
    from robot_calib.methods.gyro_line_calibration.variants import make_estimator as gyro_line
    from robot_calib.methods.wheel_odometry_calibration.variants import \
        make_estimator as wheel
    rot, pos = _composed(MOUNT, LASER)
    expected = (pos[0], pos[1], 0.3)
    g = gyro_line()
    for tf in (LASER, IMU, MOUNT, IMU_MOUNT):
        g.set_mounting(tf)
    assert tuple(g.laser_pose) == pytest.approx(expected)
    assert np.allclose(g._imu_rot, _composed(IMU_MOUNT, IMU)[0])
    w = wheel()
    for tf in (LASER, MOUNT):
        w.set_mounting(tf)
    w.update(ScanSample(0.0, -1.0, 0.1, np.ones(21), frame_id='laser'))
    assert tuple(w.front.sensor_pose) == pytest.approx(expected)


def test_loop_closure_takes_a_lidar_through_a_chain():
    from robot_calib.methods.loop_closure_correction.variants import make_estimator
    lc = make_estimator()
    for tf in (LASER, MOUNT):
        lc.set_mounting(tf)
    rot, pos = _composed(MOUNT, LASER)
    assert lc._sensor_pose('laser') == pytest.approx((pos[0], pos[1], 0.3))
    upside = dataclasses.replace(MOUNT, rotation=quat_from_rpy(math.pi, 0.0, 0.4))
    lc.set_mounting(upside)
    lc._sensor_pose('laser')
    assert 'laser' in lc._upside_down


def test_tilt_takes_an_imu_on_another_branch_of_the_tree():
    """base_footprint -> base_link (pitched 90 deg) beside base_footprint -> imu_link (level)."""
    from robot_calib.methods.tilt_detection.params import TiltParams
    from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
    pipe = TiltPipeline(TiltParams())
    pipe.on_static_transform(_tf('base_footprint', 'base_link', (0, 0, 0.1), (0, math.pi / 2, 0)))
    pipe.on_static_transform(_tf('base_footprint', 'imu_link', (0, 0, 0.2), (0, 0, 0)))
    for i in range(400):
        pipe.process('imu', ImuSample(i * 0.005, np.zeros(3), np.array([0.0, 0.0, 9.81]),
                                      'imu_link'))
    # gravity along the footprint's z is along base_link's -x: base_link tilted 90 deg
    assert pipe.summary()['final_tilt_deg'] == pytest.approx(90.0, abs=1.0)
