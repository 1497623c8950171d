# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Hostile inputs of round 3 that reach the nodes: twist-only odometry, frames missing from the tree.

Also ``robot-calib ideal`` from a truth with zero, non-unit or missing quaternions,
and scans of 100,000 beams. Simulated bags are rewritten message by message into
the hostile variant and replayed (or derived) next to the clean one; each test
compares what a node makes of both.
"""

import dataclasses
import json
import math
import time

import numpy as np
import pytest

from robot_calib import cli
from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy
from robot_calib.io import bags
from robot_calib.mismatch import read_bag
from robot_calib.sim.engine import simulate
from test_hostile_inputs import _odom_raw, rewrite, run

ODOM_NODES = ['odometry_fusion', 'gyro_line_calibration', 'loop_closure_correction']
ALL_NODES = ODOM_NODES + ['wheel_odometry_calibration', 'tilt_detection']


def twist_only(sample):
    """Return the CDR of an odometry message with its pose and quaternion all zero."""
    return _odom_raw(dataclasses.replace(sample, x=0.0, y=0.0, yaw=0.0), (0.0, 0.0, 0.0, 0.0))


def warnings_of(summary, node):
    """Return the standing input warnings of a node in a replay summary, as one text."""
    return ' | '.join(summary['nodes'][node].get('input_warnings', []))


def end_xy(summary, node):
    """Return the final (x, y) of a node's pose in a replay summary."""
    pose = summary['nodes'][node]['final_pose']
    return np.array([pose['x'], pose['y']] if isinstance(pose, dict) else pose[:2], float)


# -- 3. odometry that fills only its twist ----------------------------------------------------
@pytest.fixture(scope='module')
def drive(tmp_path_factory):
    """Return a 40 s simulated drive bag and its clean replay by the odometry readers."""
    folder = tmp_path_factory.mktemp('drive')
    simulate('drive', folder / 'bag', seed=2, duration=40.0)
    return folder / 'bag', run(folder / 'bag', folder / 'clean', ODOM_NODES)


def test_twist_only_odometry_is_integrated_by_every_node(drive, tmp_path):
    bag, clean = drive
    rewrite(bag, tmp_path / 'bag', lambda topic, s, ns: [
        (topic, twist_only(s) if topic == '/odom' else s, ns)])
    summary = run(tmp_path / 'bag', tmp_path / 'out', ODOM_NODES)
    for node in ODOM_NODES:
        # was: loop closure ended at the origin, the gyro line 2.7 m short, without a word
        assert np.hypot(*(end_xy(summary, node) - end_xy(clean, node))) < 0.1, node
    for node in ODOM_NODES:
        assert 'fills only its twist' in warnings_of(summary, node), node
        assert not warnings_of(clean, node)
    assert np.hypot(*end_xy(clean, 'loop_closure_correction')) > 2.0  # the drive goes places


def test_twist_only_odometry_calibrates_the_wheels(tmp_path):
    simulate('diff_segments', tmp_path / 'bag', seed=1, duration=60.0)
    nodes = ['wheel_odometry_calibration']

    def without_joints(topic, s, ns):     # the odometry is the only wheel source
        return [] if topic == '/joint_states' else [(topic, s, ns)]

    def only_twist(topic, s, ns):
        return [] if topic == '/joint_states' else [
            (topic, twist_only(s) if topic == '/odom' else s, ns)]
    rewrite(tmp_path / 'bag', tmp_path / 'clean', without_joints)
    rewrite(tmp_path / 'bag', tmp_path / 'twist', only_twist)
    clean = run(tmp_path / 'clean', tmp_path / 'clean_out', nodes)
    summary = run(tmp_path / 'twist', tmp_path / 'twist_out', nodes)
    truth = json.loads((tmp_path / 'bag.truth.json').read_text())
    got = summary['nodes'][nodes[0]]['result']
    assert got['segments_used'] > 0.7 * clean['nodes'][nodes[0]]['result']['segments_used']
    assert got['track_width'] == pytest.approx(truth['track_width'], abs=0.005)
    assert 'fills only its twist' in warnings_of(summary, nodes[0])


# -- 4. sensor frames missing from /tf_static -------------------------------------------------
@pytest.fixture(scope='module')
def sideways(tmp_path_factory):
    """Return a 40 s revisiting drive with the IMU on its side and the lidar off centre."""
    folder = tmp_path_factory.mktemp('sideways')
    simulate('revisit', folder / 'bag', seed=3, duration=40.0,
             overrides={'imu.roll': math.pi / 2, 'lidar.yaw': 0.6, 'lidar.x': 0.25,
                        'lidar.y': 0.1})
    return folder / 'bag', run(folder / 'bag', folder / 'clean', ALL_NODES)


def renamed(topic_name, frame):
    """Return a rewrite that gives the messages of ``topic_name`` the frame ``frame``."""
    def change(topic, sample, ns):
        if topic == topic_name:
            sample = dataclasses.replace(sample, frame_id=frame)
        return [(topic, sample, ns)]
    return change


def test_an_imu_frame_missing_from_the_tree_takes_the_trees_only_imu(sideways, tmp_path):
    bag, clean = sideways
    rewrite(bag, tmp_path / 'bag', renamed('/imu', 'imu'))   # the tree says imu_link
    summary = run(tmp_path / 'bag', tmp_path / 'out', ALL_NODES)
    assert clean['nodes']['tilt_detection']['alerts'] == 0
    assert summary['nodes']['tilt_detection']['alerts'] == 0          # was a fall at 90 deg
    for node in ('odometry_fusion', 'gyro_line_calibration', 'loop_closure_correction'):
        # was: loop closure metres off without a word
        assert np.hypot(*(end_xy(summary, node) - end_xy(clean, node))) < 0.01, node
    for node in ('odometry_fusion', 'gyro_line_calibration', 'loop_closure_correction',
                 'tilt_detection'):
        said = warnings_of(summary, node)
        assert "IMU frame 'imu' is not in /tf_static" in said and "'imu_link'" in said, node
        assert not warnings_of(clean, node)


def test_a_scan_frame_missing_from_the_tree_takes_the_trees_only_lidar(sideways, tmp_path):
    bag, clean = sideways
    rewrite(bag, tmp_path / 'bag', renamed('/scan', 'base_scan'))  # the tree says laser
    nodes = ['gyro_line_calibration', 'loop_closure_correction', 'wheel_odometry_calibration']
    summary = run(tmp_path / 'bag', tmp_path / 'out', nodes)
    for node in nodes[:2]:
        # was: the lidar at base_link, the loop pose 0.6 m off
        assert np.hypot(*(end_xy(summary, node) - end_xy(clean, node))) < 0.01, node
    wheel, wheel_clean = (s['nodes'][nodes[2]]['result'] for s in (summary, clean))
    assert wheel['lidar_x'] == pytest.approx(wheel_clean['lidar_x'], abs=1e-6)
    for node in nodes:
        said = warnings_of(summary, node)
        assert "lidar frame 'base_scan' is not in /tf_static" in said and "'laser'" in said


def test_an_ambiguous_frame_gets_no_mounting_and_says_so(sideways, tmp_path):
    bag, _ = sideways
    with bags.BagSet([bag]) as src, bags.BagWriter(tmp_path / 'bag') as out:
        for stream, time_ns, _, samples in src.decoded():
            if stream.msgtype == 'tf2_msgs/msg/TFMessage':  # a second IMU in the tree
                samples = list(samples) + [dataclasses.replace(samples[0], child='imu2_link')]
            elif stream.topic == '/imu':
                samples = [dataclasses.replace(s, frame_id='imu') for s in samples]
            for sample in (samples if stream.msgtype != 'tf2_msgs/msg/TFMessage' else [samples]):
                out.write(stream.topic, sample, time_ns)
    summary = run(tmp_path / 'bag', tmp_path / 'out', ['tilt_detection', 'odometry_fusion',
                                                       'loop_closure_correction'])
    for node in ('tilt_detection', 'odometry_fusion', 'loop_closure_correction'):
        said = warnings_of(summary, node)
        assert "IMU frame 'imu' is not in /tf_static ('imu_link', 'imu2_link' there): no " \
            'mounting known' in said, (node, said)
    assert summary['nodes']['odometry_fusion']['imu_extrinsic'] != 'tf'   # not a guess


def test_a_node_says_a_frame_missing_from_the_tree_on_diagnostics(ros, monkeypatch):
    rclpy = pytest.importorskip('rclpy')
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import qos_profile_sensor_data
    from robot_calib.codec import serialize
    from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
    from robot_calib.nodes import base
    from ros_helpers import executor_with, spin_until
    from sensor_msgs.msg import Imu
    monkeypatch.setattr(base, 'HEALTH_PERIOD', 0.1)
    node = base.PipelineNode(TiltPipeline)
    peer = rclpy.create_node('frames_peer')
    diags = []
    peer.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 50)
    pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    ex = executor_with(node, peer)
    node.pipeline.process('tf_static', T.StaticTransform(
        'base_link', 'imu_link', np.zeros(3), quat_from_rpy(math.pi / 2, 0.0, 0.0)))
    spin_until(ex, lambda: pub.get_subscription_count())
    stamps = iter(50.0 + 0.01 * i for i in range(100000))

    def warned():
        t = next(stamps)
        _, raw = serialize(T.ImuSample(t, np.zeros(3), np.array([0.0, 9.81, 0.0]), 'imu',
                                       stamp_ns=int(t * 1e9)))
        pub.publish(raw)
        time.sleep(0.002)
        return [s for d in diags for s in d.status if s.name.endswith(': inputs')
                and 'not in /tf_static' in s.message]
    assert spin_until(ex, warned, 2000, 0.01)
    status = warned()[-1]
    level = status.level if isinstance(status.level, int) else ord(status.level)
    assert level == 1 and "'imu_link'" in status.message
    assert node.pipeline.summary()['alerts'] == 0
    node.destroy_node()
    peer.destroy_node()


# -- 5. ideal sensors from a damaged truth ----------------------------------------------------
@pytest.fixture(scope='module')
def truth(tmp_path_factory):
    """Return a 30 s drive's ground truth alone (1501 poses) and its ideal recording."""
    folder = tmp_path_factory.mktemp('truth')
    simulate('drive', folder / 'sim', seed=4, duration=30.0)
    rewrite(folder / 'sim', folder / 'bag', lambda topic, s, ns: [
        (topic, s, ns)] if topic == '/ground_truth/odom' else [])
    assert cli.main(['ideal', str(folder / 'bag'), '--out', str(folder / 'ideal'),
                     '--set', 'drive_type=differential']) == 0
    return folder / 'bag', read_bag(folder / 'ideal')


CHANNELS = (('/imu', 'angular_velocity.z'), ('/imu', 'linear_acceleration.x'),
            ('/odom', 'twist.twist.angular.z'), ('/joint_states', 'velocity.left_wheel_joint'))


def _quaternion(sample):
    """Return the (x, y, z, w) quaternion of an odometry sample's attitude."""
    w, x, y, z = quat_from_rpy(sample.roll, sample.pitch, sample.yaw)
    return x, y, z, w


DAMAGE = {
    'five_zero': lambda s, i: _odom_raw(s, (0.0,) * 4) if i in (100, 400, 700, 1000, 1300)
    else s,
    'doubled': lambda s, i: _odom_raw(s, tuple(2.0 * v for v in _quaternion(s))),
    'gap': lambda s, i: None if 12.0 <= s.t < 14.0 else s,
}


@pytest.mark.parametrize('damage', sorted(DAMAGE))
def test_ideal_from_a_damaged_truth_matches_the_clean_one(truth, tmp_path, capsys, damage):
    bag, clean = truth
    index = iter(range(10**6))

    def change(topic, s, ns):
        new = DAMAGE[damage](s, next(index))
        return [] if new is None else [(topic, new, ns)]
    rewrite(bag, tmp_path / 'bag', change)
    assert cli.main(['ideal', str(tmp_path / 'bag'), '--out', str(tmp_path / 'ideal'),
                     '--set', 'drive_type=differential']) == 0
    got = read_bag(tmp_path / 'ideal')
    for topic, field in CHANNELS:
        ta, va = clean[topic].t, clean[topic].fields[field]
        tb, vb = got[topic].t, got[topic].fields[field]
        assert set(np.round(tb, 6)) <= set(np.round(ta, 6))    # nothing made up in the gaps
        _, ia, ib = np.intersect1d(np.round(ta, 6), np.round(tb, 6), return_indices=True)
        assert ib.size > 1300
        # was: yaw rates 42 rad/s, wheel rates 105 rad/s and 0.77 m/s^2 spikes off
        assert np.max(np.abs(va[ia] - vb[ib])) < 1e-6, (topic, field)
    assert {'five_zero': '5 poses dropped', 'doubled': '1501 quaternions normalised',
            'gap': '1 gaps'}[damage] in capsys.readouterr().out


# -- 6. scans of 100,000 beams ----------------------------------------------------------------
def test_dense_scans_are_thinned_and_said(tmp_path):
    simulate('drive', tmp_path / 'bag', seed=2, duration=4.0)
    dense = 100_000

    def densify(topic, s, ns):      # every beam repeated: the same scan, 100,000 beams
        if topic == '/scan':
            k = -(-dense // s.ranges.size)
            s = dataclasses.replace(s, ranges=np.repeat(s.ranges, k)[:dense],
                                    angle_increment=s.angle_increment * s.ranges.size / dense,
                                    time_increment=s.time_increment * s.ranges.size / dense,
                                    intensities=None)
        return [(topic, s, ns)]
    rewrite(tmp_path / 'bag', tmp_path / 'dense', densify)
    nodes = ['gyro_line_calibration', 'loop_closure_correction', 'wheel_odometry_calibration']
    summary = run(tmp_path / 'dense', tmp_path / 'out', nodes)
    for node in nodes:
        counts = summary['nodes'][node]['inputs']['scan']
        assert counts['thinned'] == counts['read'] > 30
        assert 'scans of 100000 beams thinned to 4000' in warnings_of(summary, node)
    clean = run(tmp_path / 'bag', tmp_path / 'clean', nodes)
    for node in nodes:
        assert 'thinned' not in clean['nodes'][node]['inputs']['scan']
        assert 'input_warnings' not in clean['nodes'][node]
