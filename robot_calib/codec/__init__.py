# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The one message codec: ROS messages and serialized bytes <-> core samples.

Nodes, replay, live play, the simulator and the mismatch analyser convert
through these functions only; they look the message type up in the one table
(:mod:`robot_calib.codec.table`) and take a fast path over the bytes where one
is registered (:mod:`robot_calib.codec.cdr`), else rosbags' (de)serializer and
the generic converters (:mod:`robot_calib.codec.messages`). Both paths give
the same samples and bytes (tested).
"""

from __future__ import annotations

from typing import Any, Callable, Optional

from robot_calib.codec import cdr as _cdr  # noqa: F401 - registers the fast paths
from robot_calib.codec import cdr_more as _cdr_more  # noqa: F401 - and the others
from robot_calib.codec.definitions import definition as stored_definition, DEFINITIONS
from robot_calib.codec.messages import clock_to_msg, header, typestore
from robot_calib.codec.table import BY_SAMPLE, Decode, KINDS, MessageType, ROWS, TYPES
from robot_calib.core import types as T

__all__ = ['BY_SAMPLE', 'Decode', 'KINDS', 'MessageType', 'ROWS', 'TYPES', 'accepts',
           'batch_decoder', 'clock_to_msg', 'decoder', 'definition', 'deserialize', 'from_msg',
           'header', 'msgtype_of', 'normalize_type', 'sample_time_ns', 'serialize', 'supported',
           'to_msg', 'typestore']


def normalize_type(msgtype: str) -> str:
    """Return the ROS 2 form ``pkg/msg/Name`` of a ROS 1 (``pkg/Name``) or ROS 2 type name."""
    parts = msgtype.split('/')
    if len(parts) == 2:
        return f'{parts[0]}/msg/{parts[1]}'
    return msgtype


def definition(msgtype: str) -> tuple[str, str]:
    """
    Return (definition text, RIHS01 hash) of ``msgtype``, as a bag connection records them.

    Stored for the types of the table (:mod:`robot_calib.codec.definitions`), else
    derived from the type store.
    """
    if msgtype in DEFINITIONS:
        return stored_definition(msgtype)
    store = typestore()
    return store.generate_msgdef(msgtype, ros_version=2)[0], store.hash_rihs01(msgtype)


def supported(msgtype: str) -> bool:
    """Return whether messages of ``msgtype`` (ROS 1 or ROS 2 name) become core samples."""
    return normalize_type(msgtype) in TYPES


def accepts(kind: str, msgtype: str) -> bool:
    """Return whether an input of sample ``kind`` can read messages of ``msgtype``."""
    row = TYPES.get(normalize_type(msgtype))
    return row is not None and (row.kind == kind or kind in row.read_as)


def _row(msgtype: str) -> MessageType:
    row = TYPES.get(normalize_type(msgtype))
    if row is None:
        raise KeyError(f'unsupported message type {msgtype}; supported: {sorted(TYPES)}')
    return row


def from_msg(msgtype: str, msg: Any, bag_time_ns: Optional[int] = None) -> list:
    """Convert a message of type ``msgtype`` into a list of core samples (TF gives several)."""
    return _row(msgtype).from_msg(msg, bag_time_ns)


def msgtype_of(sample: Any) -> str:
    """Return the ROS 2 message type a core sample (or a list of transforms) is written as."""
    if isinstance(sample, list):
        return KINDS['tf_static'].msgtype
    return BY_SAMPLE[type(sample)].msgtype


def to_msg(sample: Any) -> tuple[str, Any]:
    """Convert a core sample (or a list of static transforms) into (msgtype, rosbags message)."""
    row = KINDS['tf_static'] if isinstance(sample, list) else BY_SAMPLE[type(sample)]
    return row.msgtype, row.to_msg(sample)


def serialize(sample: Any) -> tuple[str, bytes]:
    """Return (msgtype, CDR bytes) of a core sample, as rclpy publishes them."""
    if isinstance(sample, list):
        row = KINDS['tf_static']
        encode = row.fast.encode_cdr
        if encode is not None and all(_stamp_fits(s) for s in sample):
            return row.msgtype, encode(sample)
    else:
        row = BY_SAMPLE.get(type(sample))
        encode = None if row is None else row.fast.encode_cdr
        if encode is not None and _stamp_fits(sample):
            return row.msgtype, encode(sample)
    msgtype, msg = to_msg(sample)
    return msgtype, bytes(typestore().serialize_cdr(msg, msgtype))


def _stamp_fits(sample: Any) -> bool:
    """Return whether a sample's stamp fits a ROS time (else the generic path says why)."""
    return sample.stamp_ns < 2**62 and (sample.stamp_ns >= 0 or 0 <= sample.t < 2**31)


def deserialize(msgtype: str, data: bytes, bag_time_ns: Optional[int] = None) -> list:
    """Convert CDR bytes of ``msgtype`` into core samples (generic path)."""
    msgtype = normalize_type(msgtype)
    return from_msg(msgtype, typestore().deserialize_cdr(data, msgtype), bag_time_ns)


def decoder(msgtype: str, generic: Optional[Decode] = None, ros1: bool = False) -> Decode:
    """
    Return the decoder ``(raw bytes, receive time ns) -> samples`` of ``msgtype``.

    A fast path when one is registered (big-endian CDR falls back), else
    ``generic`` (default: :func:`deserialize`, for ROS 2 CDR).
    """
    row = _row(msgtype)
    if generic is None:
        def generic(raw: bytes, time_ns: int) -> list:
            return deserialize(row.msgtype, raw, time_ns)
    fast = row.fast.decode_ros1 if ros1 else row.fast.decode_cdr
    if ros1:
        return generic if fast is None else lambda raw, time_ns: [fast(raw)]
    if fast is not None:
        def full(raw: bytes, time_ns: int) -> list:
            return [fast(raw)]
    else:
        full = row.fast.decode
        if full is None:
            return generic

    def decode(raw: bytes, time_ns: int) -> list:
        if raw[1] != 1:  # big-endian CDR: rare, take the generic path
            return generic(raw, time_ns)
        return full(raw, time_ns)
    return decode


def pose_decoder(msgtype: str, ros1: bool = False) -> Optional[Callable[[bytes], tuple]]:
    """
    Return ``pose(raw) -> (t, x, y, yaw)`` of little-endian CDR odometry, None for others.

    The values the full decoder gives, for trajectories that are drawn only.
    """
    if ros1 or msgtype != KINDS['odom'].msgtype:
        return None
    from robot_calib.codec.cdr import odom_pose_from_cdr
    return odom_pose_from_cdr


def batch_decoder(msgtype: str, ros1: bool = False) -> Optional[Callable[[list], list]]:
    """Return a decoder of many CDR messages of one topic at once, or None when there is none."""
    return None if ros1 else _row(msgtype).fast.decode_cdr_batch


def sample_time_ns(sample: Any) -> int:
    """Return the stamp (ns) a core sample carries."""
    return T.stamp_of(sample.t, sample.stamp_ns)
