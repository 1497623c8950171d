# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Recordings as channels: topics, fields, kernels; reading them from bags.

A :class:`Recording` maps a topic (``/imu``) to a :class:`Topic`: one time
vector (s, header stamps) and named field arrays whose names follow the ROS
message field paths (``angular_velocity.z``, ``twist.twist.linear.x``,
``velocity.left_wheel_joint``), so a channel is ``topic + '.' + field`` as in
``findings.json``. A :class:`PairedTopic` holds one topic of both recordings
on common times (made by :mod:`.align`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import os
from typing import Optional

import numpy as np
from robot_calib import codec

IMU_TYPE = codec.KINDS['imu'].msgtype
ODOM_TYPE = codec.KINDS['odom'].msgtype
TWIST_TYPES = tuple(row.msgtype for row in codec.ROWS if codec.accepts('cmd_vel', row.msgtype))

IMU_FIELDS = ('angular_velocity.x', 'angular_velocity.y', 'angular_velocity.z',
              'linear_acceleration.x', 'linear_acceleration.y', 'linear_acceleration.z')
ODOM_FIELDS = ('twist.twist.linear.x', 'twist.twist.angular.z')
TWIST_FIELDS = ('linear.x', 'angular.z')
JOINT_STATE_TYPE = codec.KINDS['joint_states'].msgtype
COMPARED_TYPES = (IMU_TYPE, ODOM_TYPE, JOINT_STATE_TYPE)


class ChannelError(ValueError):
    """Input that cannot be compared at all (one-line message)."""


@dataclass
class Topic:
    """
    One topic of a recording: times (s) and field arrays (SI units) of equal length.

    ``kernels`` maps a field to the smoothing its values went through, as
    ``(shape, half_width_s)`` with shape ``'box'`` or ``'tri'`` (see
    :func:`kernel_weights`): a simulated channel derived from a ground truth
    is the truth seen through such a kernel, and the real channel is compared
    through the same one.
    """

    name: str
    msgtype: str
    t: np.ndarray
    fields: dict = field(default_factory=dict)
    kernels: dict = field(default_factory=dict)

    def __len__(self) -> int:
        """Return the number of samples."""
        return int(self.t.size)


Recording = dict


def _sorted_topic(name: str, msgtype: str, t: list, cols: dict) -> Topic:
    ta = np.asarray(t, float)
    order = np.argsort(ta, kind='stable')
    ta = ta[order]
    fields = {k: np.asarray(v, float)[order] for k, v in cols.items()}
    keep = np.concatenate(([True], np.diff(ta) > 0)) if ta.size else np.zeros(0, bool)
    return Topic(name, msgtype, ta[keep], {k: v[keep] for k, v in fields.items()})


def _odom_twist_from_pose(t: np.ndarray, x: np.ndarray, y: np.ndarray,
                          yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return forward speed (m/s) and yaw rate (rad/s) differentiated from planar poses."""
    if t.size < 3:
        return np.zeros_like(t), np.zeros_like(t)
    yaw_u = np.unwrap(yaw)
    dx, dy, dyaw = (np.gradient(a, t) for a in (x, y, yaw_u))
    v = np.cos(yaw) * dx + np.sin(yaw) * dy
    return v, dyaw


def _add(buf: dict, topic: str, msgtype: str, s) -> None:
    """Append one core sample to the per-topic column buffers."""
    from robot_calib.core import types as T
    if isinstance(s, T.ImuSample):
        vals = (s.gyro[0], s.gyro[1], s.gyro[2], s.accel[0], s.accel[1], s.accel[2])
        names = IMU_FIELDS
        msgtype = msgtype or IMU_TYPE
    elif isinstance(s, T.OdomSample):
        vals = (s.vx, s.wz, s.x, s.y, s.yaw)
        names = ODOM_FIELDS + ('pose.x', 'pose.y', 'pose.yaw')
        msgtype = msgtype or ODOM_TYPE
    elif isinstance(s, T.TwistSample):
        vals = (s.vx, s.wz)
        names = TWIST_FIELDS
        msgtype = msgtype or TWIST_TYPES[0]
    elif isinstance(s, T.JointStateSample):
        names = tuple(f'position.{n}' for n in s.names) + tuple(f'velocity.{n}'
                                                                for n in s.names)
        vals = tuple(np.asarray(s.position, float)) + tuple(np.asarray(s.velocity, float))
        msgtype = msgtype or JOINT_STATE_TYPE
    else:
        return
    b = buf.setdefault(topic, {'type': msgtype, 't': [], 'cols': {}})
    n = len(b['t'])
    b['t'].append(s.t)
    cols = b['cols']
    for k, v in zip(names, vals):
        col = cols.get(k)
        if col is None:
            # a joint that appears late reads NaN before it appeared
            col = cols[k] = [math.nan] * n
        elif len(col) < n:
            col.extend([math.nan] * (n - len(col)))  # a message that omitted it
        col.append(v)
    if len(cols) > len(names):
        for col in cols.values():
            if len(col) <= n:
                col.append(math.nan)


def _finish(buf: dict) -> Recording:
    rec: Recording = {}
    for topic, b in buf.items():
        tp = _sorted_topic(topic, b['type'], b['t'], b['cols'])
        if tp.msgtype == ODOM_TYPE and len(tp) > 2:
            f = tp.fields
            twist_dead = np.ptp(f['twist.twist.linear.x']) == 0 and \
                np.ptp(f['twist.twist.angular.z']) == 0
            moved = np.ptp(f['pose.x']) > 0 or np.ptp(f['pose.y']) > 0 or np.ptp(f['pose.yaw']) > 0
            if twist_dead and moved:
                v, w = _odom_twist_from_pose(tp.t, f['pose.x'], f['pose.y'], f['pose.yaw'])
                f['twist.twist.linear.x'], f['twist.twist.angular.z'] = v, w
        for k in ('pose.x', 'pose.y', 'pose.yaw'):
            tp.fields.pop(k, None)
        if tp.msgtype == JOINT_STATE_TYPE:
            tp.fields = joint_channels(tp.t, tp.fields)
        rec[topic] = tp
    return rec


def joint_channels(t: np.ndarray, fields: dict) -> dict:
    """
    Return the joint channels worth comparing: steering angles, and wheel rates.

    A steering joint (its name holds ``steer``) is compared by its angle; any
    other joint by its rate (rad/s), differentiated from its angle when the
    messages carry none: a wheel's angle is the integral of its rate, whose
    difference between two runs only grows.
    """
    out = {}
    joints = {k.split('.', 1)[1] for k in fields}
    for j in sorted(joints):
        pos, vel = fields.get(f'position.{j}'), fields.get(f'velocity.{j}')
        if 'steer' in j:
            if pos is not None and np.isfinite(pos).sum() > 2:
                out[f'position.{j}'] = pos
            continue
        if vel is None or np.isfinite(vel).sum() < 3:
            if pos is None or np.isfinite(pos).sum() < 3 or t.size < 3:
                continue
            ok = np.isfinite(pos)
            vel = np.full(t.size, np.nan)
            vel[ok] = np.gradient(pos[ok], t[ok])
        out[f'velocity.{j}'] = vel
    return out


def recording_from_samples(items) -> Recording:
    """
    Return a :class:`Recording` of ``(topic, core sample)`` pairs (e.g. a simulator run).

    IMU, odometry and twist samples are kept; others are ignored.
    """
    buf: dict = {}
    for topic, s in items:
        _add(buf, '/' + str(topic).lstrip('/'), '', s)
    return _finish(buf)


def read_bag(path: os.PathLike | str) -> Recording:
    """
    Read the IMU, odometry and velocity-command topics of a bag into a :class:`Recording`.

    Odometry without a twist (all zero while the pose moves) gets its forward
    speed (m/s) and yaw rate (rad/s) differentiated from the pose.

    :param path: a ROS 1 bag file or a ROS 2 bag folder
    :raises ChannelError: when the bag cannot be read
    """
    from robot_calib.io import bags
    buf: dict = {}
    try:
        with bags.BagSet([path]) as bagset:
            custom = bagset.custom_data()
        for msg in bags.read_messages([path]):
            if msg.msgtype not in COMPARED_TYPES and msg.msgtype not in TWIST_TYPES:
                continue
            for s in msg.samples:
                _add(buf, msg.topic, msg.msgtype, s)
    except bags.BagError as exc:
        raise ChannelError(str(exc)) from None
    except (OSError, ValueError, KeyError) as exc:
        raise ChannelError(f'cannot read {path}: {exc}') from None
    rec = _finish(buf)
    for topic, kernels in decode_kernels(custom.get(KERNELS_KEY, '')).items():
        if topic in rec:
            rec[topic].kernels.update({f: k for f, k in kernels.items()
                                       if f in rec[topic].fields})
    return rec


KERNELS_KEY = 'robot_calib.kernels'
"""Bag metadata key of the smoothing kernels of derived channels (JSON)."""


def encode_kernels(rec: Recording) -> str:
    """Return the kernels of a recording as the JSON kept in a bag's metadata."""
    import json
    return json.dumps({k: {f: [s[0], float(s[1])] for f, s in tp.kernels.items()}
                       for k, tp in rec.items() if tp.kernels}, sort_keys=True)


def decode_kernels(text: str) -> dict:
    """Return ``{topic: {field: (shape, half width s)}}`` from bag metadata (``{}`` if none)."""
    import json
    if not text:
        return {}
    try:
        data = json.loads(text)
        return {str(k): {str(f): (str(s[0]), float(s[1])) for f, s in v.items()}
                for k, v in data.items()}
    except (ValueError, TypeError, KeyError, IndexError) as exc:
        raise ChannelError(f'unreadable {KERNELS_KEY} in the bag metadata: {exc}') from None


@dataclass
class PairedTopic:
    """
    A topic of both recordings on common times (s from the sim bag start).

    ``sim`` and ``real`` map field -> array (NaN where a side has no value);
    ``tau_xcorr`` is the lag (s, positive: real lags) of the cross-correlation
    peak, ``xcorr_gain`` the correlation gained over lag 0; ``dt_sim`` and
    ``dt_real`` are each recording's own median sample period (s; 0 unknown).
    ``sim_reg`` maps field -> the simulated channel as a regressor
    (:func:`regressor_signal`), ``sim_noisy`` field -> True when that is a
    leave-one-out average (the simulation is noisy), ``sim_loo_rate`` field ->
    the channel's leave-one-out derivative (per s), filled when first needed.
    """

    name: str
    msgtype: str
    t: np.ndarray
    sim: dict
    real: dict
    dt: float
    tau_xcorr: float = 0.0
    xcorr_gain: float = 0.0
    notes: list = field(default_factory=list)
    sim_reg: dict = field(default_factory=dict)
    sim_noisy: dict = field(default_factory=dict)
    sim_loo_rate: dict = field(default_factory=dict)
    sim_src: Optional[tuple] = None
    kernels: dict = field(default_factory=dict)
    dt_sim: float = 0.0
    dt_real: float = 0.0

    def __post_init__(self) -> None:
        """Build the regressor copies of the simulated channels (see :func:`regressor_signal`)."""
        if not self.sim_reg:
            self.sim_noisy, self.sim_loo_rate = {}, {}
            for k, v in self.sim.items():
                self.sim_reg[k] = regressor_signal(v)
                self.sim_noisy[k] = self.sim_reg[k] is not v


def loo_derivative(x: np.ndarray, dt: float, half: int = 2) -> np.ndarray:
    """
    Return dx/dt from the means of the ``half`` samples after and before each sample.

    The sample itself is left out, so its noise does not enter (see
    :func:`regressor_signal`); exact for a straight line.
    """
    xz = np.nan_to_num(x)
    c = np.concatenate(([0.0], np.cumsum(xz)))
    n = x.size
    i = np.arange(n)
    a1, b1 = np.clip(i + 1, 0, n), np.clip(i + 1 + half, 0, n)
    a0, b0 = np.clip(i - half, 0, n), np.clip(i, 0, n)
    after = (c[b1] - c[a1]) / np.maximum(b1 - a1, 1)
    before = (c[b0] - c[a0]) / np.maximum(b0 - a0, 1)
    ca = (a1 + b1 - 1) / 2.0
    cb = (a0 + b0 - 1) / 2.0
    ok = (b1 > a1) & (b0 > a0)
    out = np.where(ok, (after - before) / (np.maximum(ca - cb, 1e-9) * dt), 0.0)
    return out


def regressor_signal(x: np.ndarray, half: int = 2) -> np.ndarray:
    """
    Return ``x`` for use as a regressor: a leave-one-out average when ``x`` is noisy.

    A noisy simulation used as a regressor of its own residual biases the fit
    (errors in variables: the sim noise is in both). When the second
    differences are as large as white noise makes them (MAD(d2)/MAD(d1) > 0.5;
    about 0 for a smooth signal, 1.73 for white noise) in at least a tenth of
    the 200-sample blocks (noise may show only at rest), each sample is
    replaced by the mean of its ``half`` neighbours on each side, which
    excludes the sample's own noise (and its correlated neighbours when the
    simulator noise is coloured); a smooth (noiseless) signal is returned
    unchanged so exact models stay exact.
    """
    ok = np.isfinite(x)
    if ok.sum() < 10 * half + 10:
        return x
    xs = x[ok]
    nb = max(1, xs.size // 200)
    noisy = 0
    tiny = 1e-6 * float(np.max(np.abs(xs))) + 1e-12  # rounding-level wiggles are not noise
    for blk in np.array_split(xs, nb):
        d1 = np.median(np.abs(np.diff(blk) - np.median(np.diff(blk))))
        d2 = np.median(np.abs(np.diff(blk, 2)))
        noisy += d1 > tiny and d2 / d1 > 0.5
    if noisy < max(1, 0.1 * nb):
        return x
    # correlated simulator noise (e.g. a rate differentiated over several samples):
    # leave out the whole correlation length around each sample
    e = xs[1:-1] - 0.5 * (xs[:-2] + xs[2:])
    e = e - e.mean()
    gap = 0
    den0 = float(np.dot(e, e)) if e.size else 0.0
    if den0 > 0:
        for k in range(1, 21):
            rho = float(np.einsum('i,i->', e[k:], e[:-k])) / den0
            if abs(rho) < 0.1:
                break
            gap = k
    k = np.ones(2 * (half + gap) + 1)
    k[half:half + 2 * gap + 1] = 0.0
    xz = np.where(ok, x, 0.0)
    num = np.convolve(xz, k, mode='same')
    den = np.convolve(ok.astype(float), k, mode='same')
    with np.errstate(invalid='ignore', divide='ignore'):
        y = np.where(den > 0, num / np.maximum(den, 1.0), np.nan)
    return np.where(ok, y, np.nan)


def kernel_weights(spec: tuple, dt: float) -> np.ndarray:
    """
    Return the FIR weights (odd length, sum 1) of a smoothing kernel on a grid of period ``dt``.

    ``('box', h)``: the mean over ``[t - h, t + h]`` (trapezoid ends; what a
    central difference of an integral over ``2h`` computes); ``('tri', h)``: the
    triangle of half width ``h`` (what a second difference over ``+-h`` does to
    an acceleration).
    """
    shape, half = spec
    m = max(0, int(round(float(half) / dt)))
    if m == 0:
        return np.ones(1)
    if shape == 'box':
        w = np.ones(2 * m + 1)
        w[0] = w[-1] = 0.5
    elif shape == 'tri':
        w = (m + 1.0 - np.abs(np.arange(-m, m + 1))).astype(float)
    else:
        raise ChannelError(f'unknown smoothing kernel {shape!r}; expected box or tri')
    return w / w.sum()


def smoothed(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Return ``x`` convolved with symmetric ``weights``; NaN where they reach a NaN or an end."""
    if weights.size < 2:
        return x
    ok = np.isfinite(x)
    y = np.convolve(np.where(ok, x, 0.0), weights, mode='same')
    cover = np.convolve(ok.astype(float), weights, mode='same')
    return np.where(cover > 1.0 - 1e-9, y, np.nan)
