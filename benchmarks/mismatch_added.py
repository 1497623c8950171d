# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Effects concealed in a real IMU recording, for scoring the mismatch analyser on real data.

A real pair (the ideal IMU derived from optical truth as "sim", the real IMU
as "real") already differs by what the real sensor does (its bias, its
latency). This module adds known effects to the real side, two at a time,
so the analyser can be scored against the untouched pair: what it finds on
the modified pair beyond what it found on the untouched one must be what
was added. The effects act on the real signals as physics would:

- ``time_offset``: the real recording lags by tau (10-40 ms), all channels;
- ``gyro_scale``: one gyro axis reads (1 + s) times the rate (|s| 2-6 %);
- ``accel_bias`` in a window: one accelerometer axis reads b more (|b| 0.15-0.5
  m/s^2) during 20-40 % of the recording;
- ``imu_mounting_tilt``: the IMU is tilted by roll and pitch (1-3 deg each):
  both sensors read ``R^T v``;
- ``gyro_bias_drift``: one gyro axis drifts linearly, by 0.005-0.02 rad/s over
  the recording;
- ``lever_arm``: the IMU sits 4-12 cm from the measured point: the accelerometer
  adds ``w' x r + w x (w x r)`` of the real rate (smoothed over 35 ms).
"""

from __future__ import annotations

import numpy as np

from robot_calib.mismatch.channels import Topic
from robot_calib.mismatch.effects import rotate

NAMES = ('time_offset', 'gyro_scale', 'accel_bias', 'imu_mounting_tilt', 'gyro_bias_drift',
         'lever_arm')
GYRO = tuple(f'angular_velocity.{a}' for a in 'xyz')
ACC = tuple(f'linear_acceleration.{a}' for a in 'xyz')


def _signed(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi) * rng.choice([-1.0, 1.0]))


def draw(rng: np.random.Generator, name: str, real: Topic) -> dict:
    """Return one effect to add: name, channel, parameters, window (s from the start) or None."""
    t = real.t - real.t[0]
    dur = float(t[-1])
    moving = [f for f in GYRO if np.nanstd(real.fields[f]) > 0.3]
    axis = str(rng.choice(moving or list(GYRO)))
    if name == 'time_offset':
        return {'effect': name, 'channel': '/imu', 'window': None,
                'parameters': {'tau': float(rng.uniform(0.010, 0.040))}}
    if name == 'gyro_scale':
        return {'effect': name, 'channel': f'/imu.{axis}', 'window': None,
                'parameters': {'scale': _signed(rng, 0.02, 0.06)}}
    if name == 'accel_bias':
        f = str(rng.choice(ACC))
        t0 = rng.uniform(0.1, 0.5) * dur
        return {'effect': name, 'channel': f'/imu.{f}',
                'window': [float(t0), float(min(0.97 * dur, t0 + rng.uniform(0.2, 0.4) * dur))],
                'parameters': {'bias': _signed(rng, 0.15, 0.5)}}
    if name == 'imu_mounting_tilt':
        return {'effect': name, 'channel': '/imu', 'window': None,
                'parameters': {'roll': np.radians(_signed(rng, 1.0, 3.0)),
                               'pitch': np.radians(_signed(rng, 1.0, 3.0))}}
    if name == 'gyro_bias_drift':
        return {'effect': name, 'channel': f'/imu.{axis}', 'window': None,
                'parameters': {'bias': 0.0, 'drift': _signed(rng, 0.005, 0.02) / dur}}
    if name == 'lever_arm':
        d = rng.standard_normal(3)
        r = d / np.linalg.norm(d) * rng.uniform(0.04, 0.12)
        return {'effect': name, 'channel': '/imu', 'window': None,
                'parameters': {'x': float(r[0]), 'y': float(r[1]), 'z': float(r[2])}}
    raise ValueError(f'unknown effect {name}')


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    ok = np.isfinite(x)
    k = np.ones(width) / width
    num = np.convolve(np.where(ok, x, 0.0), k, mode='same')
    den = np.convolve(ok.astype(float), k, mode='same')
    return np.where(den > 0.5, num / np.maximum(den, 1e-9), np.nan)


def apply(real: Topic, effects: list) -> Topic:
    """Return a copy of the real IMU topic with ``effects`` added (see the module doc)."""
    t = real.t
    rel = t - t[0]
    f = {k: v.copy() for k, v in real.fields.items()}
    for e in effects:
        p, name = e['parameters'], e['effect']
        if name == 'imu_mounting_tilt':
            for group in (GYRO, ACC):
                rot = rotate(tuple(f[k] for k in group), p['roll'], p['pitch'], 0.0)
                f.update(dict(zip(group, rot)))
        elif name == 'lever_arm':
            dt = float(np.median(np.diff(t)))
            w = np.column_stack([_smooth(f[k], max(3, int(round(0.035 / dt)))) for k in GYRO])
            wd = np.gradient(w, dt, axis=0)
            r = np.array([p['x'], p['y'], p['z']])
            extra = np.cross(wd, r) + np.cross(w, np.cross(w, r))
            for i, k in enumerate(ACC):
                f[k] = f[k] + extra[:, i]
        elif name == 'gyro_scale':
            k = e['channel'].split('.', 1)[1]
            f[k] = f[k] * (1.0 + p['scale'])
        elif name == 'gyro_bias_drift':
            k = e['channel'].split('.', 1)[1]
            f[k] = f[k] + p['bias'] + p['drift'] * rel
        elif name == 'accel_bias':
            k = e['channel'].split('.', 1)[1]
            w0, w1 = e['window']
            f[k] = f[k] + np.where((rel >= w0) & (rel <= w1), p['bias'], 0.0)
    tau = sum(e['parameters']['tau'] for e in effects if e['effect'] == 'time_offset')
    # a latency: each reading is stamped tau after the motion it measured
    return Topic(real.name, real.msgtype, t + tau, f)
