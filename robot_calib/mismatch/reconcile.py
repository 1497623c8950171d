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
ACC_Y = 'linear_acceleration.y'
ABS_TOL = 0.002
"""Scales this close are one (0.2 %: below the smallest scale worth naming, 0.5 %)."""
GAIN_TOL = 0.02
"""Centripetal gains this close are one (a fifth of the smallest worth naming, 0.1)."""


def _same(a: float, sa: float, b: float, sb: float, tol: float = ABS_TOL) -> bool:
    """Return True when two scales agree within their errors (3 sigma) or ``tol``."""
    return abs(a - b) <= max(3.0 * float(np.hypot(sa, sb)), tol)


def _whole(findings: list, effect: str, channel: str) -> dict | None:
    return next((f for f in findings if f['effect'] == effect and f['channel'] == channel and
                 f['window'] is None), None)


def _yaw_scale(f: dict) -> tuple[float, float]:
    """Return the relative yaw-rate change (and its error) a finding states."""
    if f['effect'] == 'track_width_scale':
        k, sk = f['parameters']['scale'], f['std']['scale']
        return 1.0 / (1.0 + k) - 1.0, sk / (1.0 + k) ** 2
    return f['parameters']['scale'], f['std']['scale']


def _own(this: float, other: float) -> float:
    """Return what is left of relative change ``this`` once ``other`` is taken out."""
    return (1.0 + this) / (1.0 + other) - 1.0


def reconcile(findings: list, notes: list) -> list:
    """Return ``findings`` with the findings of one cause merged (notes say which)."""
    out = list(findings)
    yaw = []     # (yaw-rate channel, relative change, its error)
    motion = []  # (topic, speed change, yaw-rate change): how the robot moved differently
    for f in findings:
        if f['effect'] != 'wheel_radius_scale' or f['window'] is not None or \
                not f['channel'].endswith('.' + SPEED):
            continue
        topic = f['channel'][:-len(SPEED) - 1]
        k, sk = f['parameters']['scale'], f['std']['scale']
        tw = _whole(out, 'track_width_scale', f'{topic}.{YAW}')
        if tw is None:
            motion.append((topic, k, 0.0))
            continue
        s, ss = _yaw_scale(tw)
        motion.append((topic, k, s))
        if not _same(k, sk, s, ss):
            tw['explanation'] += f' Wheels of another size change the yaw rate of {topic} as ' \
                f"much as its speed ({k * 100:+.2f}%); the track width's own part is " \
                f'{_own(s, k) * 100:+.2f}% of the yaw rate.'
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
        others = [y for y in yaw if not y[0].startswith(topic + '.')]
        match = next((y for y in others if _same(s, ss, y[1], y[2])), None)
        if match is None:
            for y in others[:1]:
                g['explanation'] += f' The yaw rate of {y[0]} changed too ({y[1] * 100:+.2f}%): ' \
                    "if that topic measures the true motion, the gyro's own scale error is " \
                    f'{_own(s, y[1]) * 100:+.2f}%.'
            continue
        out.remove(g)
        notes.append(f'{g["channel"]} reads {s * 100:+.2f}% against the simulation, as the yaw '
                     f'rate of {match[0]} does ({match[1] * 100:+.2f}%): the real robot turned '
                     f'that much {"faster" if match[1] > 0 else "slower"} than simulated, which '
                     'both sensors agree on; not a gyro scale error, so not reported as one')
    for c in [f for f in out if f['effect'] == 'centripetal_acceleration' and
              f['window'] is None and f['channel'].endswith('.' + ACC_Y)]:
        gain, sg = c['parameters']['gain'], c['std']['gain']
        for topic, kv, kw in motion:
            if kv == 0.0 or kw == 0.0:
                continue
            want = (1.0 + kv) * (1.0 + kw) - 1.0   # v * omega of the real robot
            if _same(gain, sg, want, 0.0, GAIN_TOL):
                out.remove(c)
                notes.append(f'{c["channel"]}: the centripetal gain {gain:.3g} is the real '
                             f"robot's v*omega, {want * 100:+.1f}% of the simulated one as "
                             f'{topic} moved; not a missing centripetal term')
                break
    return out
