# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""``replay --live``: publish a short bag through rclpy in-process and subscribe to it."""

import os
import threading

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from robot_calib import codec, live
from robot_calib.core import types as T
from robot_calib.io import bags


def _write(path, n=50):
    with bags.BagWriter(path) as w:
        w.write('/tf_static', [T.StaticTransform('base_link', 'imu_link', np.zeros(3),
                                                 np.array([1.0, 0, 0, 0]))], 10**9)
        for i in range(n):
            ns = 10**9 + i * 10_000_000  # 100 Hz for 0.5 s
            w.write('/imu/data', T.ImuSample(ns * 1e-9, np.array([0.0, 0.0, 0.01 * i]),
                                             np.array([0.0, 0.0, 9.81]), stamp_ns=ns), ns)
            if i % 5 == 0:
                w.write('/cmd_vel', T.TwistSample(ns * 1e-9, 0.2), ns)
            if i % 10 == 0:
                w.write('/tf', [T.StaticTransform('odom', 'base_link', np.array([0.01 * i, 0, 0]),
                                                  np.array([1.0, 0, 0, 0]), ns * 1e-9, ns)], ns)


def _listen(play_kwargs: dict, subscriptions: dict) -> tuple[dict, dict]:
    """
    Run ``live.play(**play_kwargs)`` in a thread while a listener node records messages.

    ``subscriptions`` maps a name to (message class, topic, QoS); returns (play's
    result, {name: messages received}).
    """
    own = not rclpy.ok()
    if own:  # a domain of its own: other tests on this machine publish /imu too
        rclpy.init(domain_id=100 + os.getpid() % 100)
    node = rclpy.create_node('live_test_listener')
    got = {name: [] for name in subscriptions}
    for name, (cls, topic, qos) in subscriptions.items():
        node.create_subscription(cls, topic, got[name].append, qos)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    result = {}
    errors = []

    def run():
        try:
            result.update(live.play(**play_kwargs))
        except Exception as exc:  # noqa: B902 - reported by the main thread
            errors.append(exc)

    player = threading.Thread(target=run)
    try:
        player.start()
        while player.is_alive():
            executor.spin_once(timeout_sec=0.02)
        for _ in range(50):
            executor.spin_once(timeout_sec=0.02)
    finally:
        player.join(timeout=30)
        executor.remove_node(node)
        node.destroy_node()
        if own:
            rclpy.try_shutdown()
    assert not errors, errors
    return result, got


RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.mark.needs_tf2_msgs
def test_live_publishes_bag_with_clock(tmp_path):
    """Every topic, /tf_static latched and /tf (tf2_msgs, built by `make venv`), and /clock."""
    from geometry_msgs.msg import Twist
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu
    from tf2_msgs.msg import TFMessage
    path = tmp_path / 'bag'
    _write(path)
    imu_topic = f'/live_test_{os.getpid()}/imu'
    subs = {'imu': (Imu, imu_topic, RELIABLE), 'clock': (Clock, '/clock', RELIABLE),
            'cmd': (Twist, '/cmd_vel', RELIABLE), 'tf_static': (TFMessage, '/tf_static', LATCHED),
            'tf': (TFMessage, '/tf', RELIABLE)}
    result, got = _listen({'bags': [path], 'rate': 2.0,
                           'remaps': [f'/imu/data:={imu_topic}'],
                           'wait_for_subscribers': 10.0, 'delay': 0.3}, subs)
    assert result['messages'] == sum(result['topics'].values())
    assert result['topics'] == {'/tf_static': 1, imu_topic: 50, '/cmd_vel': 10, '/tf': 5}
    assert result['skipped'] == {}
    assert result['bag_seconds'] == pytest.approx(0.49)
    # Paced at twice the recorded rate (lower bound only: no upper timing assertion).
    assert result['wall_seconds'] >= 0.49 / 2 * 0.9
    assert len(got['imu']) == 50 and len(got['cmd']) == 10
    (static,) = got['tf_static']
    assert [(t.header.frame_id, t.child_frame_id) for t in static.transforms] == [
        ('base_link', 'imu_link')]
    assert [m.transforms[0].transform.translation.x for m in got['tf']] == pytest.approx(
        [0.0, 0.1, 0.2, 0.3, 0.4])
    # Bytes went through unchanged: decode with the shared conversion layer.
    first = codec.from_msg('sensor_msgs/msg/Imu', got['imu'][7])[0]
    assert first.stamp_ns == 10**9 + 7 * 10_000_000 and first.gyro[2] == pytest.approx(0.07)
    stamps = [c.clock.sec * 10**9 + c.clock.nanosec for c in got['clock']]
    assert stamps == sorted(stamps) and stamps[0] == 10**9 and len(stamps) >= 40


def test_live_loops_selected_topics_and_keeps_the_clock_running(tmp_path):
    """--loop plays twice, --topics leaves /cmd_vel out, /clock ticks through a 0.6 s gap."""
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu
    path = tmp_path / 'bag'
    with bags.BagWriter(path) as w:
        for ns in (10**9, 16 * 10**8):
            w.write('/imu/data', T.ImuSample(ns * 1e-9, np.zeros(3), np.array([0, 0, 9.81]),
                                             stamp_ns=ns), ns)
            w.write('/cmd_vel', T.TwistSample(ns * 1e-9, 0.2), ns)
    imu_topic = f'/live_loop_{os.getpid()}/imu'
    result, got = _listen({'bags': [path], 'rate': 2.0, 'loops': 2, 'clock_period': 0.05,
                           'remaps': [f'/imu/data:={imu_topic}'], 'topics': [imu_topic],
                           'wait_for_subscribers': 10.0, 'delay': 0.3},
                          {'imu': (Imu, imu_topic, RELIABLE),
                           'clock': (Clock, '/clock', RELIABLE)})
    assert result['topics'] == {imu_topic: 4} and len(got['imu']) == 4
    stamps = [c.clock.sec * 10**9 + c.clock.nanosec for c in got['clock']]
    restart = next(i for i in range(1, len(stamps)) if stamps[i] < stamps[i - 1])
    first_loop = stamps[:restart]
    assert first_loop[0] == 10**9 and 15 * 10**8 < first_loop[-1] <= 16 * 10**8
    between = [s for s in first_loop if 10**9 < s < 16 * 10**8]
    assert len(between) >= 5  # 0.6 s of bag time at a 0.05 s clock period: about 11


def test_live_bad_input(tmp_path):
    path = tmp_path / 'bag'
    _write(path, n=3)
    with pytest.raises(ValueError, match='--remap'):
        live.play([path], remaps=['/nothing:=/x'])
    with pytest.raises(ValueError, match='rate'):
        live.play([path], rate=0.0)
    with pytest.raises(ValueError, match='time window'):
        live.play([path], duration=-1.0)
    with pytest.raises(bags.BagError, match='not in the bag'):
        live.play([path], topics=['/scan'])
    with pytest.raises(ValueError, match='loops'):
        live.play([path], loops=-1)


@pytest.mark.needs_tf2_msgs
def test_live_offers_every_static_transform_to_a_late_subscriber(tmp_path):
    """Several /tf_static messages in the bag all reach a node that subscribes after they went."""
    from tf2_msgs.msg import TFMessage
    from robot_calib.nodes.base import message_class, TF_STATIC_QOS
    path = tmp_path / 'bag'
    with bags.BagWriter(path) as w:
        for k, child in enumerate(('imu_link', 'laser', 'camera_link')):
            w.write('/tf_static', [T.StaticTransform('base_link', child, np.zeros(3),
                                                     np.array([1.0, 0, 0, 0]))], 10**9 + k)
    own = not rclpy.ok()
    if own:
        rclpy.init(domain_id=100 + os.getpid() % 100)
    player_node = rclpy.create_node('late_test_player')
    late = rclpy.create_node('late_test_listener')
    got = []
    try:
        with bags.BagSet([path]) as bagset:
            chosen, skipped = live._choose(bagset, {}, None, message_class)
            player = live._Player(player_node, chosen, clock=False, clock_period=0.01)
            for stream, time_ns, raw in bagset.messages([s for s, _, _ in chosen]):
                player.publish(stream, time_ns, raw, skipped)
        late.create_subscription(TFMessage, '/tf_static', got.append, TF_STATIC_QOS)
        executor = SingleThreadedExecutor()
        executor.add_node(late)
        executor.add_node(player_node)
        for _ in range(200):
            executor.spin_once(timeout_sec=0.02)
            if len(got) == 3:
                break
        executor.shutdown()
    finally:
        late.destroy_node()
        player_node.destroy_node()
        if own:
            rclpy.try_shutdown()
    assert skipped == {} and player.counts == {'/tf_static': 3}
    assert sorted(m.transforms[0].child_frame_id for m in got) == [
        'camera_link', 'imu_link', 'laser']


def test_live_does_not_hand_the_command_line_to_rcl(tmp_path, monkeypatch):
    """rclpy.init() read sys.argv: the CLI's own --remap ran again inside rcl (an audit)."""
    import sys
    import rclpy
    from robot_calib import live
    path = tmp_path / 'bag'
    _write(path, n=5)
    seen = []

    class Stop(Exception):
        pass

    def init(args=None, **kw):
        seen.append(args)
        raise Stop
    monkeypatch.setattr(sys, 'argv', ['robot-calib', 'replay', str(path), '--live',
                                      '--remap', '/odom:=/imu_b', '--remap', '/imu:=/odom'])
    monkeypatch.setattr(rclpy, 'ok', lambda *a, **k: False)
    monkeypatch.setattr(rclpy, 'init', init)
    with pytest.raises(Stop):
        live.play(path)
    assert seen == [[]]
