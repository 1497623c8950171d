# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The generic node in-process through rclpy: conversion layer, QoS, parameters, bad input."""

import dataclasses

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from robot_calib.core import types as T  # noqa: E402
from robot_calib.core.params import param, ParamError  # noqa: E402
from robot_calib.nodes.base import LATCHED_QOS, PipelineNode  # noqa: E402
from robot_calib.pipelines.base import InputSpec, OutputSpec, Pipeline  # noqa: E402
from ros_helpers import spin_until  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402


@dataclasses.dataclass
class _Params:
    mode: str = param('improved', '', 'variant', choices=('improved', 'seed'))
    limit: float = param(20.0, 'm/s^2', 'acceleration above which an alert is raised',
                         minimum=0.0)


class _Alerting(Pipeline):
    name = 'alerting'
    params_type = _Params
    inputs = (InputSpec('imu', 'imu', 'imu'),)
    outputs = (OutputSpec('echo', 'alerting/imu', 'imu'),
               OutputSpec('alert', 'alerting/alert', 'bool', 'latched'))

    def handle(self, key, sample):
        out = [('echo', T.ImuSample(sample.t, sample.gyro, sample.accel, sample.frame_id,
                                    stamp_ns=sample.stamp_ns))]
        if abs(sample.accel[2]) > self.params.limit:
            out.append(('alert', T.BoolSample(sample.t, True, sample.stamp_ns)))
        return out


def test_node_converts_publishes_and_latches(ros):
    node = PipelineNode(_Alerting)
    peer = rclpy.create_node('peer')
    echoes, alerts = [], []
    peer.create_subscription(Imu, 'alerting/imu', echoes.append, 10)
    pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.add_node(peer)
    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 345
    msg.header.frame_id = 'imu_link'
    msg.linear_acceleration.z = 30.0

    def publish_until_received():
        pub.publish(msg)
        return bool(echoes)
    assert spin_until(executor, publish_until_received)
    assert echoes[0].header.stamp.sec == 12 and echoes[0].header.stamp.nanosec == 345
    assert echoes[0].linear_acceleration.z == 30.0
    late = rclpy.create_node('late')
    late.create_subscription(Bool, 'alerting/alert', alerts.append, LATCHED_QOS)
    executor.add_node(late)
    assert spin_until(executor, lambda: bool(alerts))
    assert alerts[0].data is True
    node.destroy_node()
    peer.destroy_node()
    late.destroy_node()


def test_node_counts_undecodable_messages_and_keeps_running(ros):
    node = PipelineNode(_Alerting)
    node._on_message('imu', 'sensor_msgs/msg/Imu', b'\x00\x01garbage')
    assert node.undecodable == 1
    assert node.pipeline.summary()['inputs']['imu']['rejected_undecodable'] == 1
    node.destroy_node()


def test_node_parameters_come_from_the_dataclass_and_are_validated(ros):
    node = PipelineNode(_Alerting)
    assert node.get_parameter('limit').value == 20.0
    assert node.get_parameter('mode').value == 'improved'
    descriptor = node.describe_parameter('limit')
    assert 'm/s^2' in descriptor.description
    node.destroy_node()
    with pytest.raises(ParamError, match='not one of'):
        PipelineNode(_Alerting, parameter_overrides=[Parameter('mode', value='fancy')])
    with pytest.raises(ParamError, match='below the minimum'):
        PipelineNode(_Alerting, parameter_overrides=[Parameter('limit', value=-1.0)])
