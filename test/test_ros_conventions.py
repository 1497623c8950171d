# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""ROS 2 conventions of the nodes, in-process through rclpy: parameter files under a namespace."""

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
    assert load_params_file(params) == {'/**': {'output_dir': 'x'},
                                        'tilt_detection': {'fall_angle': 1.0,
                                                           'clear_duration': 2.0}}
