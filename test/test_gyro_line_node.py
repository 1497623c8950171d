# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The ``gyro_line_calibration`` node in-process through rclpy, and replay through the CLI."""

import json
import math

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402, I100
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from robot_calib.methods.gyro_line_calibration.pipeline import GyroLinePipeline  # noqa: E402
from robot_calib.nodes.base import PipelineNode  # noqa: E402
from robot_calib.sim.world import World  # noqa: E402
from ros_helpers import spin_until, without_input_health  # noqa: E402
from sensor_msgs.msg import Imu, LaserScan  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402


def _stamp(msg, t):
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))


def test_node_publishes_corrected_odometry_and_diagnostics(ros):
    from rclpy.parameter import Parameter
    node = PipelineNode(GyroLinePipeline, parameter_overrides=[
        Parameter('mode', Parameter.Type.STRING, 'seed')])
    assert node.get_parameter('mode').value == 'seed'
    assert node.get_parameter('seed.w1').value == pytest.approx(0.8)
    peer = rclpy.create_node('gyro_line_peer')
    out, diags = [], []
    peer.create_subscription(Odometry, 'gyro_line/odom', out.append, 100)
    peer.create_subscription(DiagnosticArray, '/diagnostics', without_input_health(diags.append),
                             50)
    imu_pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    odom_pub = peer.create_publisher(Odometry, 'odom', qos_profile_sensor_data)
    scan_pub = peer.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
    phase_pub = peer.create_publisher(Bool, 'gyro_line/edge_following', 10)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(peer)
    spin_until(ex, lambda: imu_pub.get_subscription_count() and scan_pub.get_subscription_count()
               and phase_pub.get_subscription_count()
               and node._pubs['odom'].get_subscription_count(), 200, 0.01)
    world = World().add_room(5.0, 4.0)
    angles = -math.pi + np.arange(360) * math.pi / 180
    sent = []
    bias = 0.02  # rad/s: 1.1 deg/s, the heading is visibly off within a second
    for i in range(300):  # 3 s: 100 Hz IMU, 50 Hz odometry, 10 Hz scans; standing still
        t = 50.0 + i * 0.01
        imu = Imu()
        _stamp(imu, t)
        imu.angular_velocity.z = bias if i >= 150 else 0.0
        imu.linear_acceleration.z = 9.81
        imu_pub.publish(imu)
        if i % 2 == 0:
            od = Odometry()
            _stamp(od, t)
            od.header.frame_id = 'odom'
            od.child_frame_id = 'base_link'
            od.pose.pose.position.x = 1.0
            od.pose.pose.position.y = 1.5
            od.pose.pose.orientation.w = 1.0
            odom_pub.publish(od)
            sent.append((od.header.stamp.sec, od.header.stamp.nanosec))
        if i % 10 == 5:
            sc = LaserScan()
            _stamp(sc, t)
            sc.header.frame_id = 'laser'
            sc.angle_min = -math.pi
            sc.angle_increment = math.pi / 180
            sc.range_min, sc.range_max = 0.05, 8.0
            sc.ranges = world.raycast(1.0, 1.5, angles).astype(np.float32).tolist()
            scan_pub.publish(sc)
        if i == 200:
            phase_pub.publish(Bool(data=True))   # the cleaning pass is over
        ex.spin_once(timeout_sec=0.003)
    spin_until(ex, lambda: len(out) >= 140 and len(diags) >= 2, 200, 0.01)
    assert len(out) >= 50   # best-effort sensor QoS may drop a few under load
    stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in out}
    assert stamps <= set(sent)  # each output carries the stamp of its input odometry
    assert out[-1].header.frame_id == 'map' and out[-1].child_frame_id == 'base_link'
    status = diags[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.name == 'gyro_line_calibration: heading'
    assert {'corrections', 'last_correction_deg', 'references', 'heading_sigma_deg',
            'gyro_bias_deg_per_h', 'phase'} <= set(values)
    core = node.pipeline.core
    assert core.edge_following and values['phase'] == 'edge_following'
    assert len(core.references) >= 4
    # the drift between 1.5 s and 2 s (about 0.5 deg) was corrected after the phase switch
    assert core.corrections and core.corrections[0].delta < 0.0
    node.destroy_node()
    peer.destroy_node()


def test_node_survives_garbage(ros):
    node = PipelineNode(GyroLinePipeline)
    node._on_message('scan', 'sensor_msgs/msg/LaserScan', b'\x00\x01garbage')
    counts = node.pipeline.summary()['inputs']['scan']
    assert counts['rejected_undecodable'] == 1
    node.destroy_node()


def test_replay_of_the_vacuum_scenario_through_the_cli(tmp_path):
    from robot_calib.cli import main
    bag = tmp_path / 'vac'
    assert main(['simulate', 'vacuum', '--out', str(bag), '--seed', '3', '--duration', '40',
                 '--set', 'imu.gyro_bias=[0,0,0.001]']) == 0
    truth = json.loads((tmp_path / 'vac.truth.json').read_text())
    assert truth['layout'] == 'slanted' and truth['walls']
    out = tmp_path / 'out'
    assert main(['replay', str(bag), '--out', str(out), '--nodes', 'gyro_line_calibration',
                 '--set', 'gyro_line_calibration.improved.min_support=2']) == 0
    summary = json.loads((out / 'summary.json').read_text())
    node = summary['nodes']['gyro_line_calibration']
    assert node['corrections'] > 5
    assert node['references'] >= 4
    assert summary['output']['topics']['/gyro_line/odom'] > 1000
    from robot_calib.io.bags import read_messages
    last = None
    for m in read_messages([out / 'output.mcap'], topics=['/gyro_line/odom']):
        last = m
    gt = None
    for m in read_messages([bag], topics=['/ground_truth/odom']):
        gt = m
    est_yaw = last.samples[0].yaw
    true_yaw = gt.samples[0].yaw - truth['start_pose'][2]
    err = math.degrees((est_yaw - true_yaw + math.pi) % (2 * math.pi) - math.pi)
    assert abs(err) < 0.5   # uncorrected: 0.001 rad/s * 40 s = 2.3 deg
