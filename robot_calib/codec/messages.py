# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The generic converters between ROS messages and core samples, one pair per message type.

``*_from_msg`` read any object with the ROS field names (rosbags messages from
ROS 1 or ROS 2 bags, and rclpy messages alike); ``*_to_msg`` build rosbags
messages of the ROS 2 Jazzy typestore. The table that names them, and the
fast paths beside them, is :mod:`robot_calib.codec`.
"""

from __future__ import annotations

from functools import lru_cache
import math
from typing import Any, Optional

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy, quat_normalize, quat_to_rpy

POSE_IDX = np.ix_([0, 1, 5], [0, 1, 5])
"""Rows/columns (x, y, yaw) of a ROS 6x6 pose covariance; (vx, vy, wz) for a twist."""


@lru_cache(maxsize=1)
def typestore():
    """Return the cached ROS 2 Jazzy type store of rosbags."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def stamp_ns(header_stamp: Any) -> int:
    """Return a ``builtin_interfaces/Time`` as integer nanoseconds."""
    return int(header_stamp.sec) * 1_000_000_000 + int(header_stamp.nanosec)


def cov3(values: Any) -> np.ndarray:
    """Return a 3x3 covariance from 9 values, NaN-filled when not provided (-1 in [0])."""
    cov = np.asarray(values, dtype=float).reshape(3, 3)
    if cov[0, 0] < 0:  # REP-145 / sensor_msgs: -1 in [0] means "not provided"
        return np.full((3, 3), np.nan)
    return cov


def _vec(v: Any) -> np.ndarray:
    return np.array((v.x, v.y, v.z), dtype=float)


# ---------------------------------------------------------------------------------------
# message -> core
# ---------------------------------------------------------------------------------------
def imu_from_msg(msg: Any) -> T.ImuSample:
    """Convert a sensor_msgs/Imu into an :class:`ImuSample`."""
    ns = stamp_ns(msg.header.stamp)
    q = msg.orientation
    ocov = np.asarray(msg.orientation_covariance, dtype=float)
    orientation = None
    if ocov[0] >= 0 and (q.w, q.x, q.y, q.z) != (0.0, 0.0, 0.0, 0.0):
        orientation = np.array((q.w, q.x, q.y, q.z), dtype=float)
    return T.ImuSample(ns * 1e-9, _vec(msg.angular_velocity), _vec(msg.linear_acceleration),
                       msg.header.frame_id, orientation,
                       None if orientation is None else ocov.reshape(3, 3),
                       cov3(msg.angular_velocity_covariance),
                       cov3(msg.linear_acceleration_covariance), ns)


def odom_from_msg(msg: Any) -> T.OdomSample:
    """Convert a nav_msgs/Odometry into a planar :class:`OdomSample`."""
    ns = stamp_ns(msg.header.stamp)
    p = msg.pose.pose.position
    q = msg.pose.pose.orientation
    quat = (float(q.w), float(q.x), float(q.y), float(q.z))
    roll, pitch, yaw = quat_to_rpy(quat_normalize(quat))
    lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
    pcov = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[POSE_IDX]
    tcov = np.asarray(msg.twist.covariance, dtype=float).reshape(6, 6)[POSE_IDX]
    return T.OdomSample(ns * 1e-9, float(p.x), float(p.y), yaw, float(lin.x), float(lin.y),
                        float(ang.z), msg.header.frame_id, msg.child_frame_id, pcov, tcov,
                        float(p.z), roll, pitch, ns, math.hypot(*quat))


def scan_from_msg(msg: Any) -> T.ScanSample:
    """Convert a sensor_msgs/LaserScan into a :class:`ScanSample`."""
    ns = stamp_ns(msg.header.stamp)
    intens = np.asarray(msg.intensities, dtype=float)
    return T.ScanSample(ns * 1e-9, float(msg.angle_min), float(msg.angle_increment),
                        np.asarray(msg.ranges, dtype=float), float(msg.range_min),
                        float(msg.range_max), msg.header.frame_id,
                        intens if intens.size else None, float(msg.time_increment),
                        float(msg.scan_time), ns)


def joint_state_from_msg(msg: Any) -> T.JointStateSample:
    """Convert a sensor_msgs/JointState; missing positions or velocities become NaN."""
    ns = stamp_ns(msg.header.stamp)
    names = tuple(msg.name)
    n = len(names)
    pos = np.asarray(msg.position, dtype=float)
    vel = np.asarray(msg.velocity, dtype=float)
    if pos.size != n:
        pos = np.full(n, np.nan)
    if vel.size != n:
        vel = np.full(n, np.nan)
    return T.JointStateSample(ns * 1e-9, names, pos, vel, ns)


def twist_from_msg(msg: Any, bag_time_ns: Optional[int] = None) -> T.TwistSample:
    """Convert a geometry_msgs/Twist (time from the bag) or TwistStamped."""
    if hasattr(msg, 'header'):
        ns = stamp_ns(msg.header.stamp)
        msg = msg.twist
    else:
        ns = int(bag_time_ns or 0)
    return T.TwistSample(ns * 1e-9, float(msg.linear.x), float(msg.linear.y),
                         float(msg.angular.z), ns)


def navsat_from_msg(msg: Any) -> T.NavSatSample:
    """Convert a sensor_msgs/NavSatFix."""
    ns = stamp_ns(msg.header.stamp)
    return T.NavSatSample(ns * 1e-9, float(msg.latitude), float(msg.longitude),
                          float(msg.altitude), int(msg.status.status),
                          np.asarray(msg.position_covariance, dtype=float).reshape(3, 3),
                          msg.header.frame_id, ns)


def transforms_from_msg(msg: Any) -> list[T.StaticTransform]:
    """Convert a tf2_msgs/TFMessage into static transforms."""
    out = []
    for tf in msg.transforms:
        tr, q = tf.transform.translation, tf.transform.rotation
        ns = stamp_ns(tf.header.stamp)
        out.append(T.StaticTransform(tf.header.frame_id.lstrip('/'), tf.child_frame_id.lstrip('/'),
                                     _vec(tr), quat_normalize((q.w, q.x, q.y, q.z)),
                                     ns * 1e-9, ns))
    return out


def bool_from_msg(msg: Any, bag_time_ns: Optional[int] = None) -> T.BoolSample:
    """Convert a std_msgs/Bool (time from the bag)."""
    ns = int(bag_time_ns or 0)
    return T.BoolSample(ns * 1e-9, bool(msg.data), ns)


def diagnostics_from_msg(msg: Any) -> T.DiagnosticSample:
    """Convert a diagnostic_msgs/DiagnosticArray."""
    ns = stamp_ns(msg.header.stamp)
    statuses = tuple(
        T.DiagnosticStatus(s.name, int(s.level), s.message, s.hardware_id,
                           tuple((kv.key, kv.value) for kv in s.values))
        for s in msg.status)
    return T.DiagnosticSample(ns * 1e-9, statuses, ns)


# ---------------------------------------------------------------------------------------
# core -> message (rosbags, ROS 2 Jazzy)
# ---------------------------------------------------------------------------------------
def _types():
    return typestore().types


def header(t: float, stamp: int, frame_id: str) -> Any:
    """Return a std_msgs/Header for time ``t`` (s) or the exact stamp (ns) when >= 0."""
    ty = _types()
    ns = T.stamp_of(t, stamp)
    return ty['std_msgs/msg/Header'](ty['builtin_interfaces/msg/Time'](
        ns // 1_000_000_000, ns % 1_000_000_000), frame_id)


def _v3(v: Any) -> Any:
    return _types()['geometry_msgs/msg/Vector3'](float(v[0]), float(v[1]), float(v[2]))


def _quat(q: Any) -> Any:
    quaternion = _types()['geometry_msgs/msg/Quaternion']
    return quaternion(float(q[1]), float(q[2]), float(q[3]), float(q[0]))


def _cov_out(cov: Optional[np.ndarray], unknown: float = -1.0) -> np.ndarray:
    if cov is None or not np.all(np.isfinite(cov)):
        out = np.zeros(9)
        out[0] = unknown
        return out
    return np.asarray(cov, dtype=float).reshape(9)


def _cov6(cov3: np.ndarray, fill: float) -> np.ndarray:
    out = np.zeros((6, 6))
    out[2, 2] = out[3, 3] = out[4, 4] = fill
    c = np.where(np.isfinite(cov3), cov3, 0.0)
    out[POSE_IDX] = c
    return out.reshape(36)


def imu_to_msg(s: T.ImuSample) -> Any:
    """Build a sensor_msgs/Imu; unknown orientation gets covariance[0] = -1 (REP-145)."""
    ty = _types()
    if s.orientation is None:
        q, ocov = (1.0, 0.0, 0.0, 0.0), _cov_out(None)
    else:
        q, ocov = s.orientation, _cov_out(s.orientation_cov, 0.0)
    return ty['sensor_msgs/msg/Imu'](
        header(s.t, s.stamp_ns, s.frame_id), _quat(q), ocov, _v3(s.gyro),
        _cov_out(s.gyro_cov, 0.0), _v3(s.accel), _cov_out(s.accel_cov, 0.0))


def odom_to_msg(s: T.OdomSample) -> Any:
    """Build a nav_msgs/Odometry from a planar pose and twist (covariances in 6x6)."""
    ty = _types()
    pose = ty['geometry_msgs/msg/Pose'](ty['geometry_msgs/msg/Point'](float(s.x), float(s.y),
                                                                      float(s.z)),
                                        _quat(quat_from_rpy(s.roll, s.pitch, s.yaw)))
    twist = ty['geometry_msgs/msg/Twist'](_v3((s.vx, s.vy, 0.0)), _v3((0.0, 0.0, s.wz)))
    return ty['nav_msgs/msg/Odometry'](
        header(s.t, s.stamp_ns, s.frame_id), s.child_frame_id,
        ty['geometry_msgs/msg/PoseWithCovariance'](pose, _cov6(s.pose_cov, 1e6)),
        ty['geometry_msgs/msg/TwistWithCovariance'](twist, _cov6(s.twist_cov, 1e6)))


def scan_to_msg(s: T.ScanSample) -> Any:
    """Build a sensor_msgs/LaserScan."""
    ty = _types()
    n = s.ranges.size
    intens = s.intensities if s.intensities is not None else np.zeros(0)
    return ty['sensor_msgs/msg/LaserScan'](
        header(s.t, s.stamp_ns, s.frame_id), float(s.angle_min),
        float(s.angle_min + s.angle_increment * max(n - 1, 0)), float(s.angle_increment),
        float(s.time_increment), float(s.scan_time), float(s.range_min), float(s.range_max),
        np.asarray(s.ranges, dtype=np.float32), np.asarray(intens, dtype=np.float32))


def joint_state_to_msg(s: T.JointStateSample, frame_id: str = '') -> Any:
    """Build a sensor_msgs/JointState (no efforts)."""
    return _types()['sensor_msgs/msg/JointState'](
        header(s.t, s.stamp_ns, frame_id), list(s.names), np.asarray(s.position, dtype=float),
        np.asarray(s.velocity, dtype=float), np.zeros(0))


def twist_to_msg(s: T.TwistSample) -> Any:
    """Build a geometry_msgs/Twist (unstamped, as cmd_vel)."""
    return _types()['geometry_msgs/msg/Twist'](_v3((s.vx, s.vy, 0.0)), _v3((0.0, 0.0, s.wz)))


def twist_stamped_to_msg(s: T.StampedTwistSample) -> Any:
    """Build a geometry_msgs/TwistStamped from a :class:`StampedTwistSample`."""
    ty = _types()
    twist = twist_to_msg(T.TwistSample(s.t, s.vx, s.vy, s.wz))
    return ty['geometry_msgs/msg/TwistStamped'](header(s.t, s.stamp_ns, s.frame_id), twist)


def bool_to_msg(s: T.BoolSample) -> Any:
    """Build a std_msgs/Bool."""
    return _types()['std_msgs/msg/Bool'](bool(s.value))


def diagnostics_to_msg(s: T.DiagnosticSample) -> Any:
    """Build a diagnostic_msgs/DiagnosticArray."""
    ty = _types()
    kv = ty['diagnostic_msgs/msg/KeyValue']
    statuses = [ty['diagnostic_msgs/msg/DiagnosticStatus'](
        int(st.level), st.name, st.message, st.hardware_id,
        [kv(str(k), str(v)) for k, v in st.values]) for st in s.statuses]
    return ty['diagnostic_msgs/msg/DiagnosticArray'](header(s.t, s.stamp_ns, ''), statuses)


def navsat_to_msg(s: T.NavSatSample) -> Any:
    """Build a sensor_msgs/NavSatFix (covariance type: known when finite)."""
    ty = _types()
    cov = np.where(np.isfinite(s.position_cov), s.position_cov, 0.0).reshape(9)
    status = ty['sensor_msgs/msg/NavSatStatus'](int(s.status), 1)
    return ty['sensor_msgs/msg/NavSatFix'](header(s.t, s.stamp_ns, s.frame_id), status,
                                           float(s.latitude), float(s.longitude),
                                           float(s.altitude), cov,
                                           2 if np.all(np.isfinite(s.position_cov)) else 0)


def transforms_to_msg(transforms: list[T.StaticTransform]) -> Any:
    """Build a tf2_msgs/TFMessage of static transforms."""
    ty = _types()
    items = [ty['geometry_msgs/msg/TransformStamped'](
        header(tf.t, tf.stamp_ns, tf.parent), tf.child,
        ty['geometry_msgs/msg/Transform'](_v3(tf.translation), _quat(tf.rotation)))
        for tf in transforms]
    return ty['tf2_msgs/msg/TFMessage'](items)


def clock_to_msg(t: float) -> Any:
    """Build a rosgraph_msgs/Clock at time ``t`` (s)."""
    ty = _types()
    ns = int(round(t * 1e9))
    return ty['rosgraph_msgs/msg/Clock'](ty['builtin_interfaces/msg/Time'](
        ns // 1_000_000_000, ns % 1_000_000_000))
