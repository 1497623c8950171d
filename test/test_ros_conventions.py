# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""ROS 2 conventions of the nodes, in-process through rclpy: parameter files under a namespace."""

import math
import os
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parent.parent


def _node_in(namespace: str, params_file: Path):
    """Create a tilt_detection node in ``namespace`` with ``--params-file``; return (node, ctx)."""
    import rclpy
    from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
    from robot_calib.nodes.base import PipelineNode
    ctx = rclpy.Context()
    rclpy.init(args=['--ros-args', '--params-file', str(params_file)], context=ctx)
    return PipelineNode(TiltPipeline, namespace=namespace, context=ctx), ctx


@pytest.mark.parametrize('namespace', ['', 'robot1'])
def test_shipped_key_form_reaches_a_namespaced_node(tmp_path, namespace):
    """A ``/**/tilt_detection`` key (the shipped YAML's form) sets the node in any namespace."""
    params = tmp_path / 'p.yaml'
    params.write_text('/**/tilt_detection:\n  ros__parameters:\n    fall_angle: 1.1\n')
    node, ctx = _node_in(namespace, params)
    try:
        assert node.get_fully_qualified_name() == f'/{namespace}/tilt_detection'.replace('//', '/')
        assert node.get_parameter('fall_angle').value == pytest.approx(1.1)
        assert node.pipeline.params.fall_angle == pytest.approx(1.1)
    finally:
        node.destroy_node()
        ctx.try_shutdown()


def test_shipped_config_uses_namespace_wildcard_keys():
    """Every node section of the shipped YAML is keyed ``/**/<executable>``."""
    from robot_calib import methods
    tree = yaml.safe_load((REPO / 'config' / 'robot_calib.yaml').read_text())
    assert sorted(tree) == sorted(f'/**/{name}' for name in methods.names())


def test_replay_reads_namespaced_and_wildcard_keys(tmp_path):
    """robot-calib replay --params maps keys to nodes as rcl does."""
    from robot_calib.replay.config import load_params_file, node_of_key
    assert node_of_key('/**/tilt_detection') == 'tilt_detection'
    assert node_of_key('/robot1/tilt_detection') == 'tilt_detection'
    assert node_of_key('tilt_detection') == 'tilt_detection'
    assert node_of_key('/**') == '/**'
    params = tmp_path / 'p.yaml'
    params.write_text('/**:\n  ros__parameters:\n    output_dir: x\n'
                      '/**/tilt_detection:\n  ros__parameters:\n    fall_angle: 1.0\n'
                      '/robot1/tilt_detection:\n  ros__parameters:\n    clear_duration: 2.0\n')
    # output_dir is the live node's (where it writes): nothing to set offline
    assert load_params_file(params) == {'/**': {},
                                        'tilt_detection': {'fall_angle': 1.0,
                                                           'clear_duration': 2.0}}


def _tilt_node(context_args=(), **overrides):
    import rclpy
    from rclpy.parameter import Parameter
    from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
    from robot_calib.nodes.base import PipelineNode
    ctx = rclpy.Context()
    rclpy.init(args=list(context_args), context=ctx)
    node = PipelineNode(TiltPipeline, context=ctx, namespace=f'stop{os.getpid()}',
                        parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
    return node, ctx


def _cmd_vel_types(node) -> list:
    return [types for topic, types in node.get_publisher_names_and_types_by_node(
        node.get_name(), node.get_namespace()) if topic.endswith('/cmd_vel')]


@pytest.mark.parametrize('overrides,expected', [
    ({}, []),
    ({'stop_on_alert': True}, [['geometry_msgs/msg/TwistStamped']]),
    ({'stop_on_alert': True, 'stop_message': 'Twist'}, [['geometry_msgs/msg/Twist']]),
])
def test_tilt_advertises_cmd_vel_only_when_it_may_stop_the_robot(overrides, expected):
    """No cmd_vel publisher unless stop_on_alert; TwistStamped by default (Jazzy controllers)."""
    node, ctx = _tilt_node(**overrides)
    try:
        assert _cmd_vel_types(node) == expected
    finally:
        node.destroy_node()
        ctx.try_shutdown()


def test_tilt_stop_command_is_a_stamped_twist_on_the_wire():
    """A fall with stop_on_alert gives zero TwistStamped commands in base_link, stamped."""
    import numpy as np
    from robot_calib import codec
    from robot_calib.core import types as T
    from robot_calib.methods.tilt_detection.params import TiltParams
    from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
    pipe = TiltPipeline(TiltParams(stop_on_alert=True))
    outs = []
    for k in range(200):
        outs += pipe.process('imu', T.ImuSample(k * 0.005, np.zeros(3),
                                                np.array([0.0, 0.0, -9.80665]), 'imu_link'))
    stops = [s for key, s in outs if key == 'cmd_vel_stamped']
    assert stops and not [s for key, s in outs if key == 'cmd_vel']
    msgtype, raw = codec.serialize(stops[0])
    assert msgtype == 'geometry_msgs/msg/TwistStamped'
    msg = codec.typestore().deserialize_cdr(raw, msgtype)
    assert msg.header.frame_id == 'base_link' and msg.twist.linear.x == 0.0
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stops[0].stamp_ns
    back = codec.deserialize(msgtype, raw)[0]  # and a cmd_vel input reads it back
    assert isinstance(back, T.TwistSample) and codec.accepts('cmd_vel', msgtype)


def test_input_health_compares_each_input_rate_with_its_kind():
    """An IMU read at 3 Hz over the period warns against its 20 Hz floor; 200 Hz is OK."""
    from robot_calib.nodes.health import input_health, MIN_RATE_HZ, OK, WARN
    before = {'imu': {'read': 100, 'accepted': 100}}
    slow = {'imu': {'read': 103, 'accepted': 103}}
    level, message, values = input_health(slow, before, {'imu': 0.1}, ['imu'], 5.0, 1.0,
                                          {'imu': 'imu'})
    assert level == WARN and 'imu at 3.0 Hz, expected at least 20 Hz' in message
    assert ('imu.rate_hz', '3.0') in values
    assert ('imu.expected_min_hz', f'{MIN_RATE_HZ["imu"]:.1f}') in values
    fast = {'imu': {'read': 300, 'accepted': 300}}
    level, message, _ = input_health(fast, before, {'imu': 0.01}, ['imu'], 5.0, 1.0,
                                     {'imu': 'imu'})
    assert level == OK and message == 'inputs OK'
    # the first period after the input starts measures nothing yet
    _, _, values = input_health(slow, {}, {'imu': 0.1}, ['imu'], 5.0, 1.0, {'imu': 'imu'})
    assert not [k for k, _ in values if k.endswith('rate_hz')]


def _tilted(pipe, angle, t0, seconds=1.0):
    """Feed ``seconds`` of an IMU tilted by ``angle`` (rad) about x; return the alert changes."""
    import numpy as np
    from robot_calib.core import types as T
    g = 9.80665
    acc = np.array([0.0, g * math.sin(angle), g * math.cos(angle)])
    outs = []
    for k in range(int(seconds / 0.005)):
        outs += pipe.process('imu', T.ImuSample(t0 + k * 0.005, np.zeros(3), acc, 'imu_link'))
    return [s.value for key, s in outs if key == 'fall_alert']


def test_live_parameters_apply_or_are_refused_with_a_reason():
    """fall_angle set live changes the next decision; bad values and read-only ones are refused."""
    from rclpy.parameter import Parameter
    node, ctx = _tilt_node()
    try:
        assert not node.describe_parameter('fall_angle').read_only
        assert node.describe_parameter('fall_angle').floating_point_range[0].from_value == 0.0
        assert node.describe_parameter('mode').read_only
        assert node.describe_parameter('output_dir').read_only
        ok = node.set_parameters([Parameter('fall_angle', value=1.3)])[0]
        assert ok.successful and node.pipeline.params.fall_angle == pytest.approx(1.3)
        assert _tilted(node.pipeline, math.radians(60), 0.0) == [False]  # 60 deg < 1.3 rad
        for name, value in (('fall_angle', -5.0), ('fall_angle', 'steep'),
                            ('clear_angle', 1.4), ('mode', 'seed'), ('output_dir', '/')):
            refused = node.set_parameters([Parameter(name, value=value)])[0]
            assert not refused.successful and refused.reason, (name, value)
        assert node.pipeline.params.fall_angle == pytest.approx(1.3)
        assert node.get_parameter('fall_angle').value == pytest.approx(1.3)
        assert node.pipeline.params.mode == 'improved'
        ok = node.set_parameters([Parameter('fall_angle', value=0.5)])[0]
        assert ok.successful and _tilted(node.pipeline, math.radians(60), 2.0)[-1] is True
    finally:
        node.destroy_node()
        ctx.try_shutdown()
