# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The ``loop_closure_correction`` node in-process through rclpy, and through replay."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402, I100
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from robot_calib.methods.loop_closure_correction.pipeline import LoopClosurePipeline  # noqa: E402
from robot_calib.nodes.base import PipelineNode  # noqa: E402
from ros_helpers import spin_until, without_input_health  # noqa: E402
from sensor_msgs.msg import Imu, LaserScan  # noqa: E402


def _stamp(msg, t):
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))


def _box_ranges(x, y, n=360, half=3.0):
    """Ranges (m) from (x, y), heading 0, inside a square room of half-size ``half`` (m)."""
    a = np.arange(n) * 2 * math.pi / n
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide='ignore'):
        tx = np.where(c > 0, (half - x) / c, np.where(c < 0, (-half - x) / c, np.inf))
        ty = np.where(s > 0, (half - y) / s, np.where(s < 0, (-half - y) / s, np.inf))
    r = np.minimum(tx, ty)
    r[(a > 0.3) & (a < 0.5)] = np.minimum(r[(a > 0.3) & (a < 0.5)], 1.5)   # a pillar
    return r


def test_node_publishes_corrected_odometry_and_diagnostics(ros):
    node = PipelineNode(LoopClosurePipeline)
    assert node.get_parameter('mode').value == 'improved'
    assert node.get_parameter('detection.candidates').value == 3
    peer = rclpy.create_node('loop_closure_peer')
    got, diags = [], []
    peer.create_subscription(Odometry, 'loop_closure/odom', got.append, 50)
    peer.create_subscription(DiagnosticArray, '/diagnostics', without_input_health(diags.append),
                             50)
    imu_pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    odom_pub = peer.create_publisher(Odometry, 'odom', qos_profile_sensor_data)
    scan_pub = peer.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(peer)
    spin_until(ex, lambda: imu_pub.get_subscription_count() and odom_pub.get_subscription_count()
               and scan_pub.get_subscription_count()
               and node._pubs['odom'].get_subscription_count())
    sent = []
    v = 0.5
    for i in range(40):            # 2 s at 20 Hz, driving forward in a square room
        t = 50.0 + 0.05 * i
        x = -1.0 + v * 0.05 * i
        imu = Imu()
        _stamp(imu, t)
        imu.angular_velocity.z = 0.001
        imu.linear_acceleration.z = 9.81
        imu_pub.publish(imu)
        od = Odometry()
        _stamp(od, t)
        od.header.frame_id = 'odom'
        od.child_frame_id = 'base_link'
        od.pose.pose.position.x = x
        od.pose.pose.orientation.w = 1.0
        od.twist.twist.linear.x = v
        odom_pub.publish(od)
        sent.append(t)
        if i % 2 == 0:
            sc = LaserScan()
            _stamp(sc, t)
            sc.header.frame_id = 'laser'
            sc.angle_min, sc.angle_increment = 0.0, 2 * math.pi / 360
            sc.range_min, sc.range_max = 0.05, 12.0
            sc.ranges = [float(r) for r in _box_ranges(x, 0.2)]
            scan_pub.publish(sc)
        if i == 20:                # a scan with no valid beam: rejected and counted
            bad = LaserScan()
            _stamp(bad, t + 0.01)
            bad.angle_min, bad.angle_increment = 0.0, 0.1
            bad.range_min, bad.range_max = 0.05, 12.0
            bad.ranges = [float('nan')] * 60
            scan_pub.publish(bad)
        for _ in range(3):
            ex.spin_once(timeout_sec=0.01)
    spin_until(ex, lambda: len(got) >= len(sent))
    assert len(got) >= 0.9 * len(sent)
    stamps = {m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in got}
    assert all(any(abs(s - t) < 1e-6 for t in sent) for s in stamps)
    last = got[-1]
    assert last.pose.pose.position.x == pytest.approx(0.95, abs=0.1)   # 1.95 m driven
    assert math.isfinite(last.pose.covariance[0])
    counts = node.pipeline.summary()['inputs']['scan']
    assert counts.get('rejected_few_valid_beams', 0) == 1
    assert node.pipeline.estimator.result().counts['scans_used'] >= 15
    node.destroy_node()
    peer.destroy_node()


@pytest.fixture(scope='module')
def revisit_bag(tmp_path_factory):
    pytest.importorskip('robot_calib.sim')
    from robot_calib.cli import main
    out = tmp_path_factory.mktemp('revisit') / 'revisit'
    assert main(['simulate', 'revisit', '--out', str(out), '--seed', '2',
                 '--duration', '75']) == 0
    return out


def test_replay_of_the_simulated_revisit_scenario(revisit_bag, tmp_path):
    from robot_calib.cli import main
    from robot_calib.io.bags import read_messages
    from robot_calib.methods.loop_closure_correction.report import heading_rmse
    out = tmp_path / 'replay'
    assert main(['replay', str(revisit_bag), '--out', str(out),
                 '--nodes', 'loop_closure_correction']) == 0
    summ = json.loads((out / 'summary.json').read_text())['nodes']['loop_closure_correction']
    assert summ['outputs']['odom'] > 1000
    assert summ['closures_accepted'] >= 1 and summ['closures']
    assert summ['outputs'].get('diagnostics', 0) == len(summ['closures'])
    assert summ['heading_source'] == 'imu'

    def track(bag, topic):
        rows = [(s.t, s.yaw) for m in read_messages([bag], topics=[topic]) for s in m.samples]
        return np.array(rows)
    est = track(out / 'output.mcap', '/loop_closure/odom')
    gt = track(revisit_bag, '/ground_truth/odom')
    truth = json.loads(Path(str(revisit_bag) + '.truth.json').read_text())
    gt[:, 1] -= truth['start_pose'][2] if isinstance(truth['start_pose'], list) else 0.0
    rmse = heading_rmse(est[:, 0], est[:, 1], gt[:, 0], gt[:, 1])
    assert rmse < math.radians(1.0)
    # the seed-faithful mode runs through the same replay
    out2 = tmp_path / 'seed'
    assert main(['replay', str(revisit_bag), '--out', str(out2), '--nodes',
                 'loop_closure_correction', '--set',
                 'loop_closure_correction.mode=seed']) == 0
    summ2 = json.loads((out2 / 'summary.json').read_text())['nodes']['loop_closure_correction']
    assert summ2['params']['mode'] == 'seed'
