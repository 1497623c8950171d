# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
``robot-calib ideal``: the recording a perfect robot would have made, from a ground truth.

Reads a ground-truth motion from a bag (motion capture as
``geometry_msgs/PoseStamped``, ``PoseWithCovarianceStamped`` or
``TransformStamped``; a ground-truth ``nav_msgs/Odometry``) and writes a bag
with the ideal sensors (:mod:`.ideal`):

- ``/imu``: the ideal IMU at the tracked body (or at ``imu_xyz``/``imu_rpy``
  in it): body rates and specific force ``R^T (p'' + g)``;
- ``/odom``: the ideal wheel odometry twist (forward speed, yaw rate) of the
  body's planar motion;
- ``/joint_states`` when a drive is given: the wheel rates of a differential
  drive (``left_wheel_joint``, ``right_wheel_joint``) or the steering angle
  and traction rate of a steered drive wheel (``steering_joint``,
  ``traction_joint``) with the nominal geometry.

The smoothing each derived channel went through is written into the bag's
metadata (``robot_calib.kernels``), so ``robot-calib mismatch`` compares the
real channels through the same kernels.

Truth poses are cleaned first (:func:`clean_truth`): a quaternion of another
length than 1 is normalised (the same rotation), one that is zero or not
finite, or a position not finite, drops the pose (counted); nothing is
differentiated across the gaps that leaves or that the truth had
(:func:`robot_calib.mismatch.ideal.segments`).
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
from typing import Optional

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.constants import GRAVITY
from robot_calib.core.geometry import quat_from_rpy
from robot_calib.core.params import param
from robot_calib.mismatch.channels import (ChannelError, encode_kernels, IMU_TYPE,
                                           JOINT_STATE_TYPE, KERNELS_KEY, ODOM_TYPE, Topic)
from robot_calib.mismatch.ideal import (choose_half, ideal_imu, per_segment, quat_products,
                                        segments)
from robot_calib.mismatch.ideal_scan import derive_scans, ScanRequest

TRUTH_TYPES = ('geometry_msgs/msg/PoseStamped', 'geometry_msgs/msg/PoseWithCovarianceStamped',
               'geometry_msgs/msg/TransformStamped', 'nav_msgs/msg/Odometry')


@dataclass
class IdealParams:
    """Parameters of the ideal-sensor derivation (``robot-calib ideal --set``)."""

    imu_xyz: list = param([0.0, 0.0, 0.0], 'm', 'IMU position in the tracked body frame',
                          length=3)
    imu_rpy: list = param([0.0, 0.0, 0.0], 'rad', 'IMU orientation in the tracked body '
                          'frame (roll, pitch, yaw)', length=3)
    gravity: float = param(GRAVITY, 'm/s^2', 'gravity', minimum=0.0)
    rel_noise: float = param(0.02, '', 'largest noise of a derived channel as a fraction of '
                             'its RMS (chooses the differentiation windows)', minimum=0.0)
    max_window: float = param(0.1, 's', 'largest half width of a differentiation window',
                              minimum=0.0)
    drive_type: str = param('none', '', "joint states to derive: 'none', 'differential' or "
                            "'steered_wheel'", choices=('none', 'differential', 'steered_wheel'))
    wheel_radius: float = param(0.1, 'm', 'wheel radius (both wheels; the traction wheel)',
                                minimum=0.0)
    track_width: float = param(0.5, 'm', 'distance between the two wheels of a differential '
                               'drive', minimum=0.0)
    wheel_base: float = param(1.0, 'm', 'rear axle to the steered wheel', minimum=0.0)
    map_resolution: float = param(0.05, 'm', 'cell side of the map built by --map-from-scans',
                                  minimum=1e-3, maximum=10.0)
    map_min_hits: int = param(2, '', 'scan end points that make a cell of that map occupied',
                              minimum=1)
    lidar_x: float = param(0.0, 'm', 'laser x in the tracked body when /tf_static lacks it')
    lidar_y: float = param(0.0, 'm', 'laser y in the tracked body when /tf_static lacks it')
    lidar_yaw: float = param(0.0, 'rad', 'laser yaw in the tracked body when /tf_static '
                             'lacks it')
    scan_rate: float = param(10.0, 'Hz', 'ideal scan rate without real scans', minimum=0.1,
                             maximum=1000.0)
    scan_beams: int = param(360, '', 'beams per ideal scan without real scans', minimum=1,
                            maximum=100000)
    scan_fov: float = param(6.283185307179586, 'rad', 'field of view without real scans',
                            minimum=1e-3, maximum=6.283185307179586)
    scan_range_min: float = param(0.05, 'm', 'minimum range without real scans', minimum=0.0)
    scan_range_max: float = param(12.0, 'm', 'maximum range without real scans', minimum=0.01)
    scan_frame: str = param('laser', '', 'scan frame without real scans')


def _pose_of(msg, msgtype: str) -> Optional[tuple]:
    """Return (stamp s, position (3,), quaternion (w, x, y, z)) of a truth message."""
    if msgtype.endswith('TransformStamped'):
        tr, rot = msg.transform.translation, msg.transform.rotation
    else:
        pose = msg.pose.pose if msgtype.endswith(('WithCovarianceStamped', 'Odometry')) \
            else msg.pose
        tr, rot = pose.position, pose.orientation
    stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    return stamp, np.array([tr.x, tr.y, tr.z]), np.array([rot.w, rot.x, rot.y, rot.z])


def read_truth(path: os.PathLike | str, topic: Optional[str] = None) -> tuple:
    """
    Return (topic, t (n,), positions (n, 3), quaternions (n, 4)) of the truth in a bag.

    Without ``topic``, the only pose-carrying topic, or the one whose name
    says truth (``truth``, ``mocap``, ``vrpn``, ``vicon``, ``optitrack``).

    :raises ChannelError: no truth topic, several candidates, or too few poses
    """
    from robot_calib.io import bags
    with bags.BagSet([path]) as bagset:
        streams = [s for s in bagset.streams if s.msgtype in TRUTH_TYPES]
        if topic is not None:
            known = ', '.join(sorted({s.topic for s in streams})) or 'none'
            streams = [s for s in streams if s.topic == bags.normalize_topic(topic)]
            if not streams:
                raise ChannelError(f'--truth-topic {topic}: no pose topic of that name (pose '
                                   f'topics: {known})')
        if len({s.topic for s in streams}) > 1:
            named = [s for s in streams if any(w in s.topic.lower() for w in (
                'truth', 'mocap', 'vrpn', 'vicon', 'optitrack'))]
            if len({s.topic for s in named}) != 1:
                raise ChannelError('several pose topics (' + ', '.join(sorted(
                    {s.topic for s in streams})) + '): say which is the truth with '
                    '--truth-topic')
            streams = named
        if not streams:
            raise ChannelError(f'no ground-truth pose topic in {path} (expected one of '
                               f'{", ".join(TRUTH_TYPES)})')
        rows = []
        for stream, _, raw in bagset.messages(streams):
            pose = _pose_of(stream.to_msg(raw), stream.msgtype)
            if pose is not None:
                rows.append(pose)
    if len(rows) < 50:
        raise ChannelError(f'only {len(rows)} truth poses on {streams[0].topic}; need 50 or '
                           'more')
    rows.sort(key=lambda r: r[0])
    t = np.array([r[0] for r in rows])
    keep = np.concatenate(([True], np.diff(t) > 0))
    p = np.array([r[1] for r in rows])[keep]
    q = np.array([r[2] for r in rows])[keep]
    q *= np.sign(q[:, :1] + 1e-300)  # one hemisphere
    return streams[0].topic, t[keep], p, q


UNIT_TOLERANCE = 1e-6
"""A quaternion whose length is further than this from 1 is normalised."""

ZERO_QUATERNION = 1e-6
"""A quaternion shorter than this is no rotation at all: its pose is dropped."""


def clean_truth(t: np.ndarray, p: np.ndarray, q: np.ndarray) -> tuple:
    """
    Return (t, p, q, counts) of truth poses with the unusable dropped and the quaternions unit.

    A pose is dropped when its stamp, position or quaternion is not finite or
    its quaternion is (nearly) zero; a quaternion of another length is divided
    by it. ``counts``: ``poses_dropped``, ``quaternions_normalised`` and
    ``gaps`` (stretches the derivation does not cross, after the drops).
    """
    t = np.asarray(t, float)
    p = np.asarray(p, float)
    q = np.asarray(q, float)
    norm = np.sqrt(np.sum(q * q, axis=1))
    good = np.isfinite(t) & np.all(np.isfinite(p), axis=1) & np.isfinite(norm) \
        & (norm > ZERO_QUATERNION)
    dropped = int(t.size - np.count_nonzero(good))
    if dropped:
        t, p, q, norm = t[good], p[good], q[good], norm[good]
    off = np.abs(norm - 1.0) > UNIT_TOLERANCE
    normalised = int(np.count_nonzero(off))
    if normalised:
        q = q.copy()
        q[off] /= norm[off, None]
    gaps = len(segments(t)) - 1 if t.size else 0
    return t, p, q, {'poses_dropped': dropped, 'quaternions_normalised': normalised,
                     'gaps': gaps}


def _planar(t: np.ndarray, p: np.ndarray, q: np.ndarray, prm: IdealParams) -> tuple:
    """Return (v, omega, half) of the planar motion: central differences over +-half samples."""
    w, x, y, z = q.T
    yaw = np.unwrap(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    parts = segments(t)

    def twist_of(t: np.ndarray, p: np.ndarray, yaw: np.ndarray, h: int) -> np.ndarray:
        n = t.size
        out = np.full((n, 3), np.nan)
        if n <= 2 * h:
            return out
        span = t[2 * h:] - t[:-2 * h]
        vx, vy = (p[2 * h:, 0] - p[:-2 * h, 0]) / span, (p[2 * h:, 1] - p[:-2 * h, 1]) / span
        yc = yaw[h:n - h]
        out[h:n - h, 0] = np.cos(yc) * vx + np.sin(yc) * vy
        out[h:n - h, 1] = (yaw[2 * h:] - yaw[:-2 * h]) / span
        out[h:n - h, 2] = 0.0
        return out

    def twist(h: int) -> np.ndarray:
        return per_segment(lambda ts, ps, ys: twist_of(ts, ps, ys, h), t, p, yaw, parts=parts)
    h = choose_half(twist, t, prm.rel_noise, prm.max_window)
    tw = twist(h)
    return tw[:, 0], tw[:, 1], h


def derive_recording(t: np.ndarray, p: np.ndarray, q: np.ndarray,
                     prm: Optional[IdealParams] = None) -> dict:
    """Return the ideal recording (``/imu``, ``/odom``, maybe ``/joint_states``) of a truth."""
    prm = prm or IdealParams()
    if len(prm.imu_xyz) != 3 or len(prm.imu_rpy) != 3:
        raise ChannelError('imu_xyz and imu_rpy take three numbers each')
    t, p, q, _ = clean_truth(t, p, q)
    if t.size < 3:
        raise ChannelError(f'only {t.size} usable truth poses')
    qm = quat_from_rpy(*prm.imu_rpy)
    q_imu = quat_products(q, np.broadcast_to(qm, q.shape))
    lever = np.asarray(prm.imu_xyz, float)
    w, x, y, z = q.T
    rot = np.stack((np.column_stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z),
                                     2 * (x * z + w * y))),
                    np.column_stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z),
                                     2 * (y * z - w * x))),
                    np.column_stack((2 * (x * z - w * y), 2 * (y * z + w * x),
                                     1 - 2 * (x * x + y * y)))), axis=1)
    p_imu = p + np.einsum('nij,j->ni', rot, lever)
    imu = ideal_imu(t, q_imu, p_imu, prm.gravity, prm.rel_noise, prm.max_window)
    fields = {f'angular_velocity.{a}': imu['gyro'][:, i] for i, a in enumerate('xyz')}
    fields.update({f'linear_acceleration.{a}': imu['accel'][:, i] for i, a in enumerate('xyz')})
    kern = {f: imu['kernels']['gyro' if f.startswith('angular') else 'accel'] for f in fields}
    rec = {'/imu': Topic('/imu', IMU_TYPE, t, fields,
                         {f: k for f, k in kern.items() if k is not None})}
    v, om, h = _planar(t, p, q, prm)
    dt = float(np.median(np.diff(t)))
    box = ('box', h * dt)
    rec['/odom'] = Topic('/odom', ODOM_TYPE, t, {'twist.twist.linear.x': v,
                                                 'twist.twist.angular.z': om},
                         {'twist.twist.linear.x': box, 'twist.twist.angular.z': box})
    if prm.drive_type == 'differential':
        half = 0.5 * prm.track_width
        js = {'velocity.left_wheel_joint': (v - om * half) / prm.wheel_radius,
              'velocity.right_wheel_joint': (v + om * half) / prm.wheel_radius}
    elif prm.drive_type == 'steered_wheel':
        sgn = np.sign(np.where(v == 0, 1.0, v))
        js = {'position.steering_joint': np.arctan2(om * prm.wheel_base, np.abs(v)) * sgn,
              'velocity.traction_joint': sgn * np.hypot(v, om * prm.wheel_base) /
              prm.wheel_radius}
    else:
        js = None
    if js is not None:
        rec['/joint_states'] = Topic('/joint_states', JOINT_STATE_TYPE, t, js,
                                     {f: box for f in js})
    return rec


def write_recording(rec: dict, out: os.PathLike | str, lidar: Optional[dict] = None) -> int:
    """
    Write a recording of ideal channels as a ROS 2 bag (NaN samples left out); return count.

    ``lidar`` (:func:`robot_calib.mismatch.ideal_scan.derive_scans`) adds its
    ``/scan`` and the laser's ``/tf_static``.
    """
    from robot_calib.io.bags import BagWriter
    items = []
    if lidar is not None:
        tf = lidar['tf']
        items.append((int(round(tf.t * 1e9)), '/tf_static', [tf]))
        items += [(ns, lidar['topic'], s) for ns, s in lidar['samples']]
    for name, tp in rec.items():
        f = tp.fields
        for i, ti in enumerate(tp.t):
            ns = int(round(float(ti) * 1e9))
            if tp.msgtype == IMU_TYPE:
                g = np.array([f[f'angular_velocity.{a}'][i] for a in 'xyz'])
                a = np.array([f[f'linear_acceleration.{a}'][i] for a in 'xyz'])
                if np.all(np.isfinite(g)) and np.all(np.isfinite(a)):
                    items.append((ns, name, T.ImuSample(float(ti), g, a, stamp_ns=ns)))
            elif tp.msgtype == ODOM_TYPE:
                vx, wz = f['twist.twist.linear.x'][i], f['twist.twist.angular.z'][i]
                if np.isfinite(vx) and np.isfinite(wz):
                    items.append((ns, name, T.OdomSample(float(ti), 0.0, 0.0, 0.0, vx=float(vx),
                                                         wz=float(wz), stamp_ns=ns)))
            else:
                names = tuple(k.split('.', 1)[1] for k in f)
                vals = [float(f[k][i]) for k in f]
                if all(np.isfinite(vals)):
                    pos = np.array([v if k.startswith('position.') else np.nan
                                    for k, v in zip(f, vals)])
                    vel = np.array([v if k.startswith('velocity.') else np.nan
                                    for k, v in zip(f, vals)])
                    items.append((ns, name, T.JointStateSample(float(ti), names, pos, vel,
                                                               stamp_ns=ns)))
    items.sort(key=lambda z: z[0])
    with BagWriter(out, custom={KERNELS_KEY: encode_kernels(rec)}) as w:
        for ns, name, s in items:
            w.write(name, s, ns)
    return len(items)


def derive(truth_bag: os.PathLike | str, out: os.PathLike | str,
           truth_topic: Optional[str] = None, params: Optional[IdealParams] = None,
           scan: Optional[ScanRequest] = None) -> dict:
    """
    Derive the ideal sensors of the truth in ``truth_bag`` and write them to the bag ``out``.

    :returns: a summary: the truth topic, its poses and span, the half widths
        (samples) of the differentiation windows and the messages written
    :raises ChannelError: on input that cannot be used (one-line message)
    """
    if not Path(truth_bag).exists():
        raise ChannelError(f'truth bag not found: {truth_bag}')
    topic, t, p, q = read_truth(truth_bag, truth_topic)
    t, p, q, counts = clean_truth(t, p, q)
    if t.size < 50:
        dropped = counts['poses_dropped']
        raise ChannelError(f'only {t.size} usable truth poses on {topic} ({dropped} dropped: '
                           'zero or non-finite quaternion or position); need 50 or more')
    rec = derive_recording(t, p, q, params)
    lidar = None
    if scan is not None and (scan.map_path or scan.from_scans):
        lidar = derive_scans(truth_bag, t, p, q, scan, params or IdealParams())
    count = write_recording(rec, out, lidar)
    info = {'truth_topic': topic, 'poses': int(t.size), 'span_s': float(t[-1] - t[0]),
            'kernels': {k: dict(v.kernels) for k, v in rec.items()}, 'messages': count,
            **counts}
    if lidar is not None:
        info['scan'] = {k: v for k, v in lidar.items() if k not in ('samples', 'tf')}
    return info
