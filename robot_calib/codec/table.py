# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The one table of message types: ROS type, sample kind, core type, converters and fast paths.

Every message robot_calib reads or writes has one row here. The generic
converters come from :mod:`robot_calib.codec.messages`; fast paths over
serialized bytes register into the row (:func:`register_fast`, see
:mod:`robot_calib.codec.cdr`). Adding a message kind is a converter pair in
``messages`` and one row below.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Optional

from robot_calib.codec import messages as M
from robot_calib.core import types as T

Decode = Callable[[bytes, int], list]
"""Serialized bytes and receive time (ns) -> core samples."""


@dataclass
class FastPaths:
    """Direct (de)serializers of one message type, without rosbags; each may be None."""

    decode_cdr: Optional[Callable[[bytes], Any]] = None
    decode: Optional[Decode] = None
    """Little-endian CDR and receive time (ns) -> samples, where decode_cdr does not fit."""
    decode_ros1: Optional[Callable[[bytes], Any]] = None
    decode_cdr_batch: Optional[Callable[[list], list]] = None
    encode_cdr: Optional[Callable[[Any], bytes]] = None


@dataclass(frozen=True)
class MessageType:
    """
    One row: a ROS 2 message type and how it becomes core samples and back.

    ``kind`` is the sample kind pipelines name their inputs and outputs by, and
    an input of a kind in ``read_as`` reads it too (a ``cmd_vel`` input takes
    TwistStamped as well as Twist); ``primary`` marks the type a kind is
    published as. ``from_msg(msg, bag_time_ns)`` returns a list of samples (a TF
    message holds several); messages without a header take the bag receive
    time. ``sample_type`` is the core type written as this message.
    """

    msgtype: str
    kind: str
    sample_type: type
    from_msg: Callable[[Any, Optional[int]], list]
    to_msg: Optional[Callable[[Any], Any]] = None
    primary: bool = True
    read_as: tuple[str, ...] = ()
    fast: FastPaths = field(default_factory=FastPaths, compare=False)


def _stamped(convert: Callable[[Any], Any]) -> Callable[[Any, Optional[int]], list]:
    return lambda msg, bag_time_ns=None: [convert(msg)]


def _bag_timed(convert: Callable[[Any, Optional[int]], Any]
               ) -> Callable[[Any, Optional[int]], list]:
    return lambda msg, bag_time_ns=None: [convert(msg, bag_time_ns)]


ROWS = (
    MessageType('sensor_msgs/msg/Imu', 'imu', T.ImuSample, _stamped(M.imu_from_msg),
                M.imu_to_msg),
    MessageType('nav_msgs/msg/Odometry', 'odom', T.OdomSample, _stamped(M.odom_from_msg),
                M.odom_to_msg),
    MessageType('sensor_msgs/msg/LaserScan', 'scan', T.ScanSample, _stamped(M.scan_from_msg),
                M.scan_to_msg),
    MessageType('sensor_msgs/msg/JointState', 'joint_states', T.JointStateSample,
                _stamped(M.joint_state_from_msg), M.joint_state_to_msg),
    MessageType('geometry_msgs/msg/Twist', 'cmd_vel', T.TwistSample,
                _bag_timed(M.twist_from_msg), M.twist_to_msg),
    MessageType('geometry_msgs/msg/TwistStamped', 'cmd_vel_stamped', T.StampedTwistSample,
                _bag_timed(M.twist_from_msg), M.twist_stamped_to_msg, read_as=('cmd_vel',)),
    MessageType('sensor_msgs/msg/NavSatFix', 'fix', T.NavSatSample, _stamped(M.navsat_from_msg),
                M.navsat_to_msg),
    MessageType('std_msgs/msg/Bool', 'bool', T.BoolSample, _bag_timed(M.bool_from_msg),
                M.bool_to_msg),
    MessageType('diagnostic_msgs/msg/DiagnosticArray', 'diagnostics', T.DiagnosticSample,
                _stamped(M.diagnostics_from_msg), M.diagnostics_to_msg),
    MessageType('tf2_msgs/msg/TFMessage', 'tf_static', T.StaticTransform,
                lambda msg, bag_time_ns=None: M.transforms_from_msg(msg), M.transforms_to_msg),
)

TYPES: dict[str, MessageType] = {row.msgtype: row for row in ROWS}
"""ROS 2 message type -> its row."""
KINDS: dict[str, MessageType] = {row.kind: row for row in ROWS if row.primary}
"""Sample kind -> the row of the type it is published as."""
KINDS['tf'] = KINDS['tf_static']
"""``/tf`` (moving frames) carries the type of ``/tf_static``: a list of transforms."""
BY_SAMPLE: dict[type, MessageType] = {row.sample_type: row for row in ROWS
                                      if row.primary and row.to_msg is not None}
"""Core sample type -> the row it is written as (a list of transforms: ``tf_static``)."""


def register_fast(msgtype: str, **paths: Callable) -> None:
    """Register fast paths (the fields of :class:`FastPaths`) for ``msgtype``."""
    fast = TYPES[msgtype].fast
    for name, fn in paths.items():
        if not hasattr(fast, name):
            raise TypeError(f'unknown fast path {name!r}')
        setattr(fast, name, fn)
