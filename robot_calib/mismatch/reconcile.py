# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
One physical cause, one finding: scale findings that say the same thing, merged.

Each topic is explained on its own, so a difference in how the real robot
moved shows on every sensor that saw the motion. Two cases name a false
effect if left alone:

- wheels larger by the same amount on both sides scale an odometry's speed and
  its yaw rate alike; the yaw rate alone reads as a track width scale
  ``1 / (1 + k) = 1 + s``, and a user correcting both would count the one
  error twice;
- a gyro whose rate differs from the simulated one exactly as another topic's
  yaw rate does (a ground truth, the odometry) reports a robot that turned
  faster or slower than simulated, which both sensors agree on: the gyro is
  not at fault.
"""

from __future__ import annotations

import numpy as np

SPEED, YAW = 'twist.twist.linear.x', 'twist.twist.angular.z'
GYRO_Z = 'angular_velocity.z'
REL_TOL = 0.1
"""Relative difference within which two scales are the same one (10 % of the larger)."""


def _same(a: float, sa: float, b: float, sb: float) -> bool:
    """Return True when two scales agree within their errors or ``REL_TOL``."""
    return abs(a - b) <= max(3.0 * float(np.hypot(sa, sb)), REL_TOL * max(abs(a), abs(b)))


def _whole(findings: list, effect: str, channel: str) -> dict | None:
    return next((f for f in findings if f['effect'] == effect and f['channel'] == channel and
                 f['window'] is None), None)


def _yaw_scale(f: dict) -> tuple[float, float]:
    """Return the relative yaw-rate change (and its error) a finding states."""
    if f['effect'] == 'track_width_scale':
        k, sk = f['parameters']['scale'], f['std']['scale']
        return 1.0 / (1.0 + k) - 1.0, sk / (1.0 + k) ** 2
    key = 'scale'
    return f['parameters'][key], f['std'][key]


def reconcile(findings: list, notes: list) -> list:
    """Return ``findings`` with the scale findings of one cause merged (notes say which)."""
    out = list(findings)
    yaw = []  # (topic channel of a yaw rate, its scale, error, finding)
    for f in findings:
        if f['effect'] != 'wheel_radius_scale' or f['window'] is not None or \
                not f['channel'].endswith('.' + SPEED):
            continue
        topic = f['channel'][:-len(SPEED) - 1]
        tw = _whole(out, 'track_width_scale', f'{topic}.{YAW}')
        if tw is None:
            continue
        k, sk = f['parameters']['scale'], f['std']['scale']
        s, ss = _yaw_scale(tw)
        if not _same(k, sk, s, ss):
            continue
        out.remove(tw)
        f['channels'] = [f['channel'], tw['channel']]
        f['explanation'] += f' The yaw rate of {topic} scales alike ({s * 100:+.2f}%), as ' \
            'wheels larger by this much on both sides make it: the track width is as ' \
            'modelled (correcting it too would count the one error twice).'
        notes.append(f'{tw["channel"]}: the track width scale {tw["parameters"]["scale"]:.4g} '
                     f'is the wheel radius scale of {f["channel"]} ({k:.4g}) seen on the yaw '
                     'rate; not reported on its own')
        yaw.append((tw['channel'], s, ss))
    yaw += [(f['channel'], *_yaw_scale(f)) for f in out
            if f['effect'] == 'track_width_scale' and f['window'] is None]
    for g in [f for f in out if f['effect'] == 'gyro_scale' and f['window'] is None and
              f['channel'].endswith('.' + GYRO_Z)]:
        s, ss = _yaw_scale(g)
        topic = g['channel'].rsplit('.', 2)[0]
        match = next((y for y in yaw if not y[0].startswith(topic + '.') and
                      _same(s, ss, y[1], y[2])), None)
        if match is None:
            continue
        out.remove(g)
        notes.append(f'{g["channel"]} reads {s * 100:+.2f}% against the simulation, as the yaw '
                     f'rate of {match[0]} does ({match[1] * 100:+.2f}%): the real robot turned '
                     'that much faster than simulated, which both sensors agree on; not a gyro '
                     'scale error, so not reported as one')
    return out
