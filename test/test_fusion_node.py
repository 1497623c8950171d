# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The ``odometry_fusion`` node in-process through rclpy: topics, stamps, diagnostics, params."""

import math

import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402, I100
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline  # noqa: E402
from robot_calib.nodes.base import PipelineNode  # noqa: E402
from ros_helpers import spin_until, without_input_health  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402


def _stamp(msg, t):
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))


def test_node_fuses_imu_and_odom_and_publishes_diagnostics(ros):
    node = PipelineNode(FusionPipeline)
    assert node.get_parameter('mode').value == 'improved'
    assert node.get_parameter('track_width').value == pytest.approx(0.5)
    peer = rclpy.create_node('fusion_peer')
    fused, diags = [], []
    peer.create_subscription(Odometry, 'odometry/fused', fused.append, 50)
    peer.create_subscription(DiagnosticArray, '/diagnostics', without_input_health(diags.append),
                             50)
    imu_pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    odom_pub = peer.create_publisher(Odometry, 'odom', qos_profile_sensor_data)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(peer)
    # wait for discovery both ways
    spin_until(ex, lambda: imu_pub.get_subscription_count() and odom_pub.get_subscription_count()
               and node._pubs['odom'].get_subscription_count())
    v, w = 0.5, 0.2
    sent_odom = []
    for i in range(300):  # 100 Hz IMU, 20 Hz odometry, 3 s, driving an arc
        t = 100.0 + i * 0.01
        imu = Imu()
        _stamp(imu, t)
        imu.header.frame_id = 'imu_link'
        imu.angular_velocity.z = w
        imu.linear_acceleration.z = 9.81
        imu_pub.publish(imu)
        if i % 5 == 0:
            od = Odometry()
            _stamp(od, t)
            od.twist.twist.linear.x = v
            od.twist.twist.angular.z = w
            odom_pub.publish(od)
            sent_odom.append((od.header.stamp.sec, od.header.stamp.nanosec))
        ex.spin_once(timeout_sec=0.002)
    spin_until(ex, lambda: len(fused) >= 50 and diags, 200, 0.01)
    assert len(fused) >= 50, len(fused)
    stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in fused}
    assert stamps <= set(sent_odom)  # each output carries the stamp of its input
    last = fused[-1]
    assert last.header.frame_id == 'odom' and last.child_frame_id == 'base_link'
    assert last.twist.twist.linear.x == pytest.approx(v, abs=0.05)
    assert last.twist.twist.angular.z == pytest.approx(w, abs=0.05)
    q = last.pose.pose.orientation
    yaw = 2 * math.atan2(q.z, q.w)
    t_last = last.header.stamp.sec + last.header.stamp.nanosec * 1e-9
    assert yaw == pytest.approx(w * (t_last - 100.0), abs=0.05)
    assert last.pose.covariance[0] > 0 and last.pose.covariance[35] > 0
    assert diags, 'no /diagnostics'
    status = diags[-1].status[0]
    keys = {kv.key for kv in status.values}
    assert status.name == 'odometry_fusion: filter'
    assert {'nis_avg', 'nis_in_band_fraction', 'gyro_bias', 'noise_scale_speed'} <= keys
    assert node.callback_seconds
    node.destroy_node()
    peer.destroy_node()


def test_node_survives_bad_messages(ros):
    node = PipelineNode(FusionPipeline)
    node._on_message('imu', 'sensor_msgs/msg/Imu', b'\x00\x01garbage')
    imu = Imu()
    _stamp(imu, 5.0)
    imu.angular_velocity.x = float('nan')
    from rclpy.serialization import serialize_message
    node._on_message('imu', 'sensor_msgs/msg/Imu', serialize_message(imu))
    counts = node.pipeline.summary()['inputs']['imu']
    assert counts['rejected_undecodable'] == 1 and counts['rejected_non_finite'] == 1
    node.destroy_node()


def test_node_rejects_a_bad_parameter(ros):
    from rclpy.parameter import Parameter
    from robot_calib.core.params import ParamError
    with pytest.raises(ParamError, match='mode'):
        PipelineNode(FusionPipeline, parameter_overrides=[
            Parameter('mode', Parameter.Type.STRING, 'fancy')])
