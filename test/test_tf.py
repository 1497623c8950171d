# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
TF as REP-105 users expect it: /tf broadcasts, /tf_static mountings, tf2_msgs on the wire.

``odometry_fusion`` broadcasts ``odom -> base_link`` with ``publish_tf``;
``loop_closure_correction`` and ``gyro_line_calibration`` publish their corrected
pose in ``map`` and, with ``publish_tf``, the correction ``map -> odom``; the
live nodes take mountings from ``/tf_static`` (transient local, joined late).
tf2_msgs is built into the virtual environment by ``make venv``
(tools/build_tf2_msgs.sh): the tests marked needs_tf2_msgs fail without it, or skip
where it cannot be built (no cmake or C/C++ compiler).
"""

import numpy as np
import pytest

from robot_calib.core import frames, types as T
from robot_calib.core.geometry import se2_compose, yaw_from_quat
from robot_calib.methods.gyro_line_calibration.params import GyroLineParams
from robot_calib.methods.gyro_line_calibration.pipeline import GyroLinePipeline
from robot_calib.methods.loop_closure_correction.params import LoopClosureParams
from robot_calib.methods.loop_closure_correction.pipeline import LoopClosurePipeline
from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
from robot_calib.methods.tilt_detection.pipeline import TiltPipeline

JAZZY_TFMESSAGE_HASH = 'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087'
"""Type hash of tf2_msgs/msg/TFMessage on ROS 2 Jazzy (what ``ros2 topic info -v`` shows)."""
G = 9.80665


def _imu(t, wz=0.0, acc=(0.0, 0.0, G), frame='imu_link'):
    return T.ImuSample(t, np.array([0.0, 0.0, wz]), np.array(acc, dtype=float), frame,
                       stamp_ns=int(round(t * 1e9)))


def _odom(t, x, y=0.0, yaw=0.0, v=0.5, wz=0.0):
    return T.OdomSample(t, x, y, yaw, v, 0.0, wz, 'odom', 'base_link',
                        stamp_ns=int(round(t * 1e9)))


def _drive(pipe, seconds=4.0, gyro_z=0.05):
    """Drive straight by the wheels while the gyro turns: the corrected pose leaves odom."""
    outs, odoms = [], {}
    for i in range(int(seconds * 100)):
        t = 10.0 + i * 0.01
        outs += pipe.process('imu', _imu(t, wz=gyro_z))
        if i % 5 == 0:
            od = _odom(t, 0.5 * (t - 10.0))
            odoms[od.stamp_ns] = od
            outs += pipe.process('odom', od)
    return outs, odoms


def _serialized(sample):
    from robot_calib import codec
    return codec.serialize(sample)[1]


# -- the core: planar pose -> transform, corrected pose -> map -> odom -----------------------
def test_pose_transform_and_map_to_odom():
    tf = frames.pose_transform('odom', 'base_link', (1.0, -2.0, 0.5), 3.0, 7)
    assert (tf.parent, tf.child, tf.t, tf.stamp_ns) == ('odom', 'base_link', 3.0, 7)
    np.testing.assert_allclose(tf.translation, [1.0, -2.0, 0.0])
    assert yaw_from_quat(tf.rotation) == pytest.approx(0.5)
    assert tf.rotation[1] == tf.rotation[2] == 0.0
    corrected, odom = np.array([2.0, 1.0, 0.3]), np.array([1.5, 0.2, -0.1])
    correction = frames.map_to_odom(corrected, odom)
    np.testing.assert_allclose(se2_compose(correction, odom), corrected, atol=1e-12)
    np.testing.assert_allclose(frames.map_to_odom(odom, odom), np.zeros(3), atol=1e-12)


# -- pipelines: what goes on /tf (replay writes the same into output.mcap) --------------------
def test_fusion_pipeline_broadcasts_odom_to_base_link_only_with_publish_tf():
    from robot_calib.methods.odometry_fusion.params import FusionParams
    outs, _ = _drive(FusionPipeline(FusionParams(publish_tf=True)), seconds=2.0, gyro_z=0.1)
    fused = [s for k, s in outs if k == 'odom']
    tfs = [s for k, s in outs if k == 'tf']
    assert fused and len(tfs) == len(fused)
    for pose, (tf,) in zip(fused, tfs):
        assert (tf.parent, tf.child) == ('odom', 'base_link')
        assert tf.stamp_ns == pose.stamp_ns
        np.testing.assert_allclose(tf.translation, [pose.x, pose.y, 0.0])
        assert yaw_from_quat(tf.rotation) == pytest.approx(pose.yaw)
    outs, _ = _drive(FusionPipeline(), seconds=2.0)
    assert not [k for k, _ in outs if k == 'tf']
    assert 'tf' not in [o.key for o in FusionPipeline().active_outputs()]


@pytest.mark.parametrize('pipeline_cls,params_cls', [
    (LoopClosurePipeline, LoopClosureParams), (GyroLinePipeline, GyroLineParams)])
def test_corrected_pose_is_in_map_and_map_to_odom_joins_it_to_the_odometry(pipeline_cls,
                                                                           params_cls):
    """Map -> odom (on /tf) composed with the odometry input is the corrected pose (in map)."""
    outs, odoms = _drive(pipeline_cls(params_cls(publish_tf=True)))
    corrected = [s for k, s in outs if k == 'odom']
    tfs = [s for k, s in outs if k == 'tf']
    assert corrected and len(tfs) == len(corrected)
    for pose, (tf,) in zip(corrected, tfs):
        assert pose.frame_id == 'map' and pose.child_frame_id == 'base_link'
        assert (tf.parent, tf.child, tf.stamp_ns) == ('map', 'odom', pose.stamp_ns)
        od = odoms[pose.stamp_ns]
        chain = se2_compose(frames.planar_pose(tf), (od.x, od.y, od.yaw))
        np.testing.assert_allclose(chain, [pose.x, pose.y, pose.yaw], atol=1e-9)
    # the gyro turned while the wheels went straight: the correction is not the identity
    assert abs(frames.planar_pose(tfs[-1][0])[2]) > 0.05
    outs, _ = _drive(pipeline_cls(), seconds=1.0)
    assert [s.frame_id for k, s in outs if k == 'odom'][-1] == 'map'
    assert not [k for k, _ in outs if k == 'tf']


def test_no_correction_when_map_and_odom_are_one_frame():
    logged = []
    pipe = LoopClosurePipeline(LoopClosureParams(publish_tf=True, map_frame='odom'),
                               log=lambda level, msg: logged.append((level, msg)))
    outs, _ = _drive(pipe, seconds=1.0)
    assert [s for k, s in outs if k == 'odom'] and not [k for k, _ in outs if k == 'tf']
    assert [m for level, m in logged if level == 'warn' and 'map_frame' in m] != []


def test_replay_writes_tf_into_the_output_bag(tmp_path):
    from robot_calib.io import bags
    from robot_calib.replay import replay
    src = tmp_path / 'in'
    with bags.BagWriter(src) as w:
        for i in range(300):
            t = 10.0 + i * 0.01
            w.write('/imu', _imu(t, wz=0.1), int(round(t * 1e9)))
            if i % 5 == 0:
                w.write('/odom', _odom(t, 0.5 * (t - 10.0)), int(round(t * 1e9)))
    summary = replay([src], tmp_path / 'out', nodes=['odometry_fusion'],
                     overrides=['odometry_fusion.publish_tf=true'], progress=False)
    topics = summary['output']['topics']
    assert topics['/tf'] == topics['/odometry/fused'] > 0
    msgs = [m for m in bags.read_messages([tmp_path / 'out']) if m.topic == '/tf']
    assert msgs[0].msgtype == 'tf2_msgs/msg/TFMessage'
    tf = msgs[-1].samples[0]
    assert (tf.parent, tf.child) == ('odom', 'base_link') and tf.translation[0] > 0.5


# -- live nodes through rclpy -----------------------------------------------------------------
def _node(pipeline_cls, **overrides):
    from rclpy.parameter import Parameter
    from robot_calib.nodes.base import PipelineNode
    return PipelineNode(pipeline_cls, parameter_overrides=[
        Parameter(k, value=v) for k, v in overrides.items()])


def _publishers(node, topic):
    return [types for name, types in node.get_publisher_names_and_types_by_node(
        node.get_name(), node.get_namespace()) if name == topic]


@pytest.mark.needs_tf2_msgs
def test_tf2_msgs_is_the_robots_type(ros):
    """The TFMessage built by the set-up has Jazzy's type hash and CDR layout."""
    import rclpy
    from rclpy.serialization import serialize_message
    from tf2_msgs.msg import TFMessage
    from robot_calib import codec
    node = rclpy.create_node('tf_type_check')
    try:
        node.create_publisher(TFMessage, '/tf', 10)
        info = node.get_publishers_info_by_topic('/tf')
        assert [i.topic_type for i in info] == ['tf2_msgs/msg/TFMessage']
        assert str(info[0].topic_type_hash) == JAZZY_TFMESSAGE_HASH
    finally:
        node.destroy_node()
    tf = T.StaticTransform('base_link', 'imu_link', np.array([0.1, -0.2, 0.3]),
                           np.array([0.5, 0.5, 0.5, 0.5]), 1.5, 1_500_000_000)
    msgtype, raw = codec.serialize([tf])
    msg = TFMessage()
    msg.transforms = [_transform_stamped(tf)]
    decoded = codec.deserialize(msgtype, serialize_message(msg))[0]
    assert (decoded.parent, decoded.child, decoded.stamp_ns) == ('base_link', 'imu_link',
                                                                 1_500_000_000)
    np.testing.assert_allclose(decoded.translation, tf.translation)
    np.testing.assert_allclose(decoded.rotation, tf.rotation)
    from rclpy.serialization import deserialize_message
    back = deserialize_message(raw, TFMessage).transforms[0]
    assert back.child_frame_id == 'imu_link' and back.transform.translation.z == 0.3


def _transform_stamped(tf):
    from geometry_msgs.msg import TransformStamped
    msg = TransformStamped()
    msg.header.frame_id, msg.child_frame_id = tf.parent, tf.child
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(tf.stamp_ns, 10**9)
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = (
        float(v) for v in tf.translation)
    q = msg.transform.rotation
    q.w, q.x, q.y, q.z = (float(v) for v in tf.rotation)
    return msg


@pytest.mark.needs_tf2_msgs
def test_fusion_node_broadcasts_odom_to_base_link_on_tf(ros):
    """publish_tf: one odom -> base_link per fused pose on /tf, same stamp and pose."""
    import rclpy
    from nav_msgs.msg import Odometry
    from tf2_msgs.msg import TFMessage
    from ros_helpers import executor_with, spin_until
    node = _node(FusionPipeline, publish_tf=True)
    peer = rclpy.create_node('tf_listener')
    got, fused = [], []
    peer.create_subscription(TFMessage, '/tf', got.append, 100)
    peer.create_subscription(Odometry, 'odometry/fused', fused.append, 100)
    ex = executor_with(node, peer)
    try:
        assert _publishers(node, '/tf') == [['tf2_msgs/msg/TFMessage']]
        assert spin_until(ex, lambda: node._pubs['tf'].get_subscription_count()
                          and node._pubs['odom'].get_subscription_count())
        for sample in _fusion_inputs():
            node._on_message(*sample)
            ex.spin_once(timeout_sec=0.0)
        assert spin_until(ex, lambda: len(got) >= 20 and len(fused) >= 20, 200, 0.02)
    finally:
        ex.shutdown()
        node.destroy_node()
        peer.destroy_node()
    by_stamp = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in fused}
    assert all(len(m.transforms) == 1 for m in got)
    pairs = [(m.transforms[0], by_stamp.get((m.transforms[0].header.stamp.sec,
                                             m.transforms[0].header.stamp.nanosec)))
             for m in got]
    assert len([1 for _, odom in pairs if odom is not None]) >= 20
    for tf, odom in pairs:
        assert (tf.header.frame_id, tf.child_frame_id) == ('odom', 'base_link')
        if odom is None:
            continue
        pose = odom.pose.pose
        assert tf.transform.translation.x == pytest.approx(pose.position.x)
        assert tf.transform.translation.y == pytest.approx(pose.position.y)
        assert tf.transform.rotation.z == pytest.approx(pose.orientation.z)
    assert got[-1].transforms[0].transform.translation.x > 0.3


def _fusion_inputs():
    """(key, msgtype, CDR bytes) of 2 s of IMU (100 Hz) and odometry (20 Hz) driving an arc."""
    out = []
    for i in range(200):
        t = 10.0 + i * 0.01
        out.append(('imu', 'sensor_msgs/msg/Imu', _serialized(_imu(t, wz=0.1))))
        if i % 5 == 0:
            od = _odom(t, 0.5 * (t - 10.0), yaw=0.1 * (t - 10.0), wz=0.1)
            out.append(('odom', 'nav_msgs/msg/Odometry', _serialized(od)))
    return out


@pytest.mark.parametrize('pipeline_cls', [FusionPipeline, LoopClosurePipeline,
                                          GyroLinePipeline])
@pytest.mark.needs_tf2_msgs
def test_nodes_advertise_tf_only_with_publish_tf(ros, pipeline_cls):
    node = _node(pipeline_cls)
    try:
        assert _publishers(node, '/tf') == []
    finally:
        node.destroy_node()
    node = _node(pipeline_cls, publish_tf=True)
    try:
        assert _publishers(node, '/tf') == [['tf2_msgs/msg/TFMessage']]
    finally:
        node.destroy_node()


@pytest.mark.needs_tf2_msgs
def test_live_node_takes_the_imu_mounting_from_tf_static(ros):
    """A static transform latched before the node starts (as tf2 does) mounts its IMU."""
    import rclpy
    from tf2_msgs.msg import TFMessage
    from robot_calib.nodes.base import LATCHED_QOS
    from ros_helpers import executor_with, spin_until
    peer = rclpy.create_node('static_broadcaster')
    static = peer.create_publisher(TFMessage, '/tf_static', LATCHED_QOS)
    upside_down = T.StaticTransform('base_link', 'imu_link', np.zeros(3),
                                    np.array([0.0, 1.0, 0.0, 0.0]))  # roll = pi
    msg = TFMessage()
    msg.transforms = [_transform_stamped(upside_down)]
    static.publish(msg)
    node = _node(TiltPipeline)
    ex = executor_with(node, peer)
    try:
        assert spin_until(ex, lambda: node.pipeline.static_transforms, 200, 0.02)
        for k in range(100):  # an upright robot seen by an upside-down IMU
            node._on_message('imu', 'sensor_msgs/msg/Imu',
                             _serialized(_imu(1.0 + 0.005 * k, acc=(0.0, 0.0, -G))))
        summary = node.pipeline.method_summary()
    finally:
        ex.shutdown()
        node.destroy_node()
        peer.destroy_node()
    assert summary['mounting'] == '/tf_static'
    assert summary['alerts'] == 0 and summary['final_tilt_deg'] < 5.0  # upright
    assert node.pipeline.static_transforms[('base_link', 'imu_link')].rotation[1] == 1.0


def test_publish_tf_without_tf2_msgs_is_one_line_and_exit_2(ros, monkeypatch, capsys):
    """Where tf2_msgs is missing, publish_tf:=true stops the node with one line (exit 2)."""
    from robot_calib.nodes import base
    real = base.message_class
    monkeypatch.setattr(base, 'message_class',
                        lambda t: None if t.startswith('tf2_msgs/') else real(t))
    import rclpy
    monkeypatch.setattr(rclpy, 'spin', lambda node: None)  # a node that starts returns at once
    rclpy.try_shutdown()
    code = base.run(FusionPipeline, args=['--ros-args', '-p', 'publish_tf:=true'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1
    assert err[0].startswith('odometry_fusion: error: cannot publish /tf: tf2_msgs/msg/TFMessage '
                             'is not installed (/tf and /tf_static need it: '
                             'tools/build_tf2_msgs.sh builds it')
    rclpy.init()
    node = _node(FusionPipeline)  # without publish_tf it runs, without /tf_static
    try:
        assert _publishers(node, '/tf') == []
        assert 'tf_static' not in [s.topic_name.strip('/') for s in node._subs]
    finally:
        node.destroy_node()


@pytest.mark.needs_tf2_msgs
def test_live_node_hears_every_static_broadcaster(ros):
    """Two static broadcasters that started first (a robot description and a sensor driver)."""
    import rclpy
    from tf2_msgs.msg import TFMessage
    from robot_calib.methods.wheel_odometry_calibration.pipeline import WheelCalibrationPipeline
    from robot_calib.nodes.base import LATCHED_QOS
    from ros_helpers import executor_with, spin_until
    peers = [rclpy.create_node(f'static_broadcaster_{k}') for k in range(3)]
    children = ['imu_link', 'laser', 'camera_link']
    for peer, child in zip(peers, children):
        msg = TFMessage()
        msg.transforms = [_transform_stamped(T.StaticTransform(
            'base_link', child, np.array([0.5, 0.0, 0.2]), np.array([1.0, 0.0, 0.0, 0.0])))]
        peer.create_publisher(TFMessage, '/tf_static', LATCHED_QOS).publish(msg)
    node = _node(WheelCalibrationPipeline)
    ex = executor_with(node, *peers)
    try:
        spin_until(ex, lambda: len(node.pipeline.static_transforms) == 3, 200, 0.02)
    finally:
        ex.shutdown()
        node.destroy_node()
        for peer in peers:
            peer.destroy_node()
    assert sorted(c for _, c in node.pipeline.static_transforms) == sorted(children)
