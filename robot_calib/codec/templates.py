# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Fast CDR encoding of uniform message streams by template patching (the simulator writes these).

All messages of one simulated topic have the same layout (same frame ids,
same array lengths), so their CDR bytes differ only in a few numeric fields.
:func:`encode_stream` serialises ONE message with rosbags (the reference
encoder), with sentinel values in the fields that change, finds the sentinels'
byte offsets, and then fills a (N, length) byte array for all messages with
numpy. It is byte-identical to rosbags' ``serialize_cdr`` (tested) and about
50x faster. When a sentinel is not found exactly once it raises
:class:`TemplateError` and the caller uses the reference encoder.
"""

from __future__ import annotations

import struct
from typing import Any, Sequence

import numpy as np

from robot_calib.codec.messages import typestore


class TemplateError(RuntimeError):
    """The template's sentinels could not be located unambiguously."""


_SEC, _NSEC = 0x2B3C4D5E, 0x1A2B3C4D


def _resolve(msg: Any, path: str) -> tuple[Any, str]:
    parts = path.split('.')
    obj = msg
    for part in parts[:-1]:
        obj = getattr(obj, part)
    return obj, parts[-1]


def _sentinels(n: int, start: int, dtype: str) -> np.ndarray:
    # distinct values with distinctive byte patterns, never produced by a simulation
    base = -3.14159e-77 if dtype == '<f8' else -3.14159e-17
    return np.array([base * (1.0 + 0.0137 * (start + i)) for i in range(n)], dtype=dtype)


def encode_stream(msgtype: str, msg: Any, patches: Sequence[tuple[str, str, np.ndarray]]
                  ) -> list[bytes]:
    """
    Return the CDR bytes of N messages that differ from ``msg`` only in ``patches``.

    :param msgtype: ROS 2 type name, e.g. ``sensor_msgs/msg/Imu``
    :param msg: a rosbags message of that type (modified in place for the template)
    :param patches: (path, kind, values) with kind ``stamp`` (values (N, 2) int: sec,
        nanosec), ``xyz`` (N, 3), ``xyzw`` (N, 4) float64 of a Vector3/Point/Quaternion at
        ``path``, ``f8``/``f4`` (N, k) arrays of float64/float32 at ``path``
    """
    if not patches:
        raise TemplateError('nothing to patch')
    n = patches[0][2].shape[0]
    counter = 0
    located = []
    for path, kind, values in patches:
        obj, attr = _resolve(msg, path)
        target = getattr(obj, attr)
        if kind == 'stamp':
            target.sec, target.nanosec = _SEC, _NSEC
            pattern = struct.pack('<iI', _SEC, _NSEC)
            dtype, width = None, 8
        elif kind in ('xyz', 'xyzw'):
            names = 'xyz' if kind == 'xyz' else 'xyzw'
            sent = _sentinels(len(names), counter, '<f8')
            counter += len(names)
            for name, value in zip(names, sent):
                setattr(target, name, float(value))
            pattern, dtype, width = sent.tobytes(), '<f8', 8 * len(names)
        elif kind in ('f8', 'f4'):
            k = values.shape[1]
            sent = _sentinels(k, counter, '<' + kind)
            counter += k
            setattr(obj, attr, sent.astype(np.float64 if kind == 'f8' else np.float32))
            pattern, dtype, width = sent.tobytes(), '<' + kind, sent.nbytes
        else:
            raise TemplateError(f'unknown patch kind {kind!r}')
        located.append((pattern, kind, dtype, width, values))
    data = bytes(typestore().serialize_cdr(msg, msgtype))
    buf = np.empty((n, len(data)), dtype=np.uint8)
    buf[:] = np.frombuffer(data, dtype=np.uint8)
    for pattern, kind, dtype, width, values in located:
        if data.count(pattern) != 1:
            raise TemplateError(f'{msgtype}: sentinel not unique')
        off = data.index(pattern)
        if kind == 'stamp':
            v = np.asarray(values, dtype=np.int64)
            block = np.empty((n, 2), dtype='<u4')
            block[:, 0] = (v[:, 0].astype('<i4')).view('<u4')
            block[:, 1] = v[:, 1]
            raw = block.view(np.uint8).reshape(n, 8)
        else:
            raw = np.ascontiguousarray(values, dtype=dtype).view(np.uint8).reshape(n, width)
        buf[:, off:off + width] = raw
    return [row.tobytes() for row in buf]


def stamps(times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (ns int64, (N, 2) sec/nanosec) of times (s)."""
    ns = np.round(np.asarray(times, dtype=float) * 1e9).astype(np.int64)
    return ns, np.column_stack((ns // 1_000_000_000, ns % 1_000_000_000))


def quat_xyzw(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """
    Return (N, 4) quaternions (x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll).

    Same formula as :func:`robot_calib.core.geometry.quat_from_rpy` (no sign flip).
    """
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.column_stack((sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy))
