# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Live nodes that must not stop or lie.

Logging at every severity, gaps, all-rejected input, unknown parameters, an
unwritable output folder and the shutdown path.
"""

import dataclasses
import math
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402, I100
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from robot_calib.core import types as T  # noqa: E402
from robot_calib.core.params import param  # noqa: E402
from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline  # noqa: E402
from robot_calib.methods.tilt_detection.pipeline import TiltPipeline  # noqa: E402
from robot_calib.methods.wheel_odometry_calibration.pipeline import \
    WheelCalibrationPipeline  # noqa: E402
from robot_calib.nodes import base  # noqa: E402
from robot_calib.nodes.base import PipelineNode  # noqa: E402
from robot_calib.nodes.health import NodeLog  # noqa: E402
from robot_calib.pipelines.base import InputSpec, OutputSpec, Pipeline  # noqa: E402
from ros_helpers import executor_with, spin_until  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402


@dataclasses.dataclass
class _Params:
    mode: str = param('improved', '', 'variant', choices=('improved', 'seed'))


class _Chatty(Pipeline):
    """Logs at two severities from the same place for every sample, then echoes it."""

    name = 'chatty'
    params_type = _Params
    inputs = (InputSpec('imu', 'imu', 'imu'),)
    outputs = (OutputSpec('echo', 'chatty/imu', 'imu'),)

    def handle(self, key, sample):
        for level in ('info', 'warn', 'error', 'debug'):
            self.log(level, f'sample at {sample.t:.3f} s logged at {level}')
        return [('echo', T.ImuSample(sample.t, sample.gyro, sample.accel, sample.frame_id,
                                     stamp_ns=sample.stamp_ns))]


def _stamp(msg, t):
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))


def _level(status):
    return status.level if isinstance(status.level, int) else ord(status.level)


def _imu(t, az=9.81, wz=0.0):
    m = Imu()
    _stamp(m, t)
    m.header.frame_id = 'imu_link'
    m.linear_acceleration.z = az
    m.angular_velocity.z = wz
    return m


def test_node_keeps_publishing_when_its_pipeline_logs_at_several_severities(ros):
    node = PipelineNode(_Chatty)
    peer = rclpy.create_node('chatty_peer')
    echoes = []
    peer.create_subscription(Imu, 'chatty/imu', echoes.append, 50)
    pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    ex = executor_with(node, peer)
    spin_until(ex, lambda: pub.get_subscription_count() and
               node._pubs['echo'].get_subscription_count())
    for i in range(20):
        pub.publish(_imu(10.0 + 0.1 * i))
        ex.spin_once(timeout_sec=0.01)
    assert spin_until(ex, lambda: len(echoes) >= 15, 200, 0.01)
    counts = node.pipeline.summary()['inputs']['imu']
    assert counts.get('rejected_processing_error', 0) == 0
    node.destroy_node()
    peer.destroy_node()


def test_log_helper_one_call_site_per_severity_and_throttle_by_key():
    calls = []

    class _Logger:
        def debug(self, m):
            calls.append(('debug', m))

        def info(self, m):
            calls.append(('info', m))

        def warning(self, m):
            calls.append(('warn', m))

        def error(self, m):
            calls.append(('error', m))
    now = [0.0]
    log = NodeLog(_Logger(), clock=lambda: now[0])
    assert log('warn', 'a', throttle_s=5.0) and not log('warn', 'a', throttle_s=5.0)
    assert log('warn', 'b', throttle_s=5.0)  # another message is not silenced by the first
    now[0] = 6.0
    assert log('warn', 'a', throttle_s=5.0)
    log('error', 'c')
    assert [c[0] for c in calls] == ['warn', 'warn', 'warn', 'error']


def test_fusion_node_publishes_again_after_a_two_second_gap(ros):
    node = PipelineNode(FusionPipeline)
    peer = rclpy.create_node('gap_peer')
    fused = []
    peer.create_subscription(Odometry, 'odometry/fused', fused.append, 100)
    imu_pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    odom_pub = peer.create_publisher(Odometry, 'odom', qos_profile_sensor_data)
    ex = executor_with(node, peer)
    spin_until(ex, lambda: imu_pub.get_subscription_count() and odom_pub.get_subscription_count()
               and node._pubs['odom'].get_subscription_count())

    def drive(t0, n):
        for i in range(n):
            t = t0 + 0.01 * i
            imu_pub.publish(_imu(t, wz=0.1))
            if i % 5 == 0:
                od = Odometry()
                _stamp(od, t)
                od.twist.twist.linear.x = 0.4
                od.twist.twist.angular.z = 0.1
                odom_pub.publish(od)
            ex.spin_once(timeout_sec=0.002)
    drive(100.0, 200)
    spin_until(ex, lambda: len(fused) >= 10, 100, 0.01)
    before = len(fused)
    assert before > 0
    drive(104.0, 200)  # two seconds of silence, then the same driving again
    assert spin_until(ex, lambda: any(m.header.stamp.sec >= 104 for m in fused), 200, 0.01)
    last = fused[-1].pose.pose.position
    assert math.isfinite(last.x) and abs(last.x) < 10.0
    node.destroy_node()
    peer.destroy_node()


def _tilt_node_with_diagnostics(monkeypatch, peer_name):
    """Return (node, peer, executor, diagnostics received) with a fast health period."""
    monkeypatch.setattr(base, 'HEALTH_PERIOD', 0.1)
    node = PipelineNode(TiltPipeline)
    peer = rclpy.create_node(peer_name)
    diags = []
    peer.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 50)
    ex = executor_with(node, peer)
    return node, peer, ex, diags


def test_all_rejected_input_is_reported_on_diagnostics(ros, monkeypatch):
    node, peer, ex, diags = _tilt_node_with_diagnostics(monkeypatch, 'nan_peer')
    pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    spin_until(ex, lambda: pub.get_subscription_count())

    stamps = iter(50.0 + 0.01 * i for i in range(100000))

    def error_status():
        pub.publish(_imu(next(stamps), az=float('nan')))
        time.sleep(0.002)  # several health periods pass whatever the machine's load
        return [s for d in diags for s in d.status if s.name.endswith(': inputs') and
                _level(s) == 2]
    assert spin_until(ex, error_status, 2000, 0.01)
    st = error_status()[-1]
    assert 'every imu message rejected' in st.message and 'non_finite' in st.message
    assert st.name.startswith('/tilt_detection')
    node.destroy_node()
    peer.destroy_node()


def test_waiting_node_says_so(ros, monkeypatch):
    node, peer, ex, diags = _tilt_node_with_diagnostics(monkeypatch, 'wait_peer')
    assert spin_until(ex, lambda: any(_level(s) == 1 and 'waiting for imu' in s.message
                                      for d in diags for s in d.status), 200, 0.01)
    node.destroy_node()
    peer.destroy_node()


def test_unknown_parameter_is_warned(ros, monkeypatch):
    said = []

    class _Recording(NodeLog):
        def __call__(self, level, message, throttle_s=0.0, key=None):
            said.append((level, message))
            return True
    monkeypatch.setattr(base, 'NodeLog', _Recording)
    node = PipelineNode(TiltPipeline, parameter_overrides=[Parameter('fall_angel', value=1.0)])
    warned = [m for lv, m in said if lv == 'warn' and 'unknown parameter' in m]
    assert warned and 'fall_angel' in warned[0] and 'fall_angle' in warned[0]
    node.destroy_node()


def test_unwritable_output_dir_refuses_to_start(capsys):
    code = base.run(WheelCalibrationPipeline,
                    ['wheel_odometry_calibration', '--ros-args', '-p',
                     'output_dir:=/proc/robot_calib_cannot_write_here'])
    err = capsys.readouterr().err
    assert code == 2
    assert 'output_dir' in err and len([ln for ln in err.splitlines() if 'error' in ln]) == 1


def test_shutdown_writes_the_artifact_even_when_the_context_is_gone(tmp_path):
    rclpy.init()
    node = PipelineNode(WheelCalibrationPipeline,
                        parameter_overrides=[Parameter('output_dir', value=str(tmp_path))])
    rclpy.try_shutdown()   # as after Ctrl-C or SIGTERM: the context is gone before finish()
    node.finish()
    assert (tmp_path / 'wheel_calibration.yaml').is_file()
    assert 'verdict' in (tmp_path / 'wheel_calibration.yaml').read_text()
    node.destroy_node()


def test_messages_without_a_header_stamp_take_their_receive_time(ros, monkeypatch):
    """A driver that never fills header.stamp: before, all but one IMU message were duplicates."""
    node, peer, ex, _ = _tilt_node_with_diagnostics(monkeypatch, 'unstamped_peer')
    pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
    spin_until(ex, lambda: pub.get_subscription_count())

    def published():
        pub.publish(_imu(0.0))
        time.sleep(0.002)
        return node.restamped >= 30
    assert spin_until(ex, published, 2000, 0.01)
    counts = node.pipeline.summary()['inputs']['imu']
    assert counts['accepted'] >= 30 and not counts.get('rejected_duplicate_stamp')
    node.destroy_node()
    peer.destroy_node()
