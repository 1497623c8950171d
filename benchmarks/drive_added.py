# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Known drive effects added to a real drive recording (the motion-capture side of a pair).

Each effect acts on the real body-frame twist as the drive would have moved
(one at a time, scored against the untouched pair):

- ``turn_rate_scale``: the yaw rate is (1 + s) times what it was (|s| 7-10 %);
- ``speed_scale``: the forward speed is (1 + s) times (|s| 6-10 %);
- ``yaw_rate_offset``: the yaw rate reads b more (|b| 0.01-0.03 rad/s);
- ``transport_delay``: the whole motion happens 0.1 s later (the stamps move,
  the commands do not);
- ``time_constant``: one axis passes through a further first-order lag of
  0.15-0.35 s (exact discrete lag, per gap-free stretch);
- ``deadband``: turn commands smaller than a band (0.02-0.04 rad/s) move
  nothing: the yaw rate is zero where the held command, delayed by the
  drive's own response time (``response``, s), lies inside the band;
- ``accel_limit``: one axis' motion changes no faster than a limit (forward
  0.08-0.15 m/s^2, turn 0.4-0.8 rad/s^2): the measured speed's motion (its
  centred 0.2 s moving average) is rate limited and the measurement's noise
  (the rest) added back unchanged. Limiting the measured speed itself, noise
  and all, slews the noise too (at 50 Hz the motion capture's speed changes
  faster than the limit in a third of its samples even at a constant
  command), which is a low-pass filter the drive does not have.
"""

from __future__ import annotations

import numpy as np

NAMES = ('turn_rate_scale', 'speed_scale', 'yaw_rate_offset', 'transport_delay',
         'time_constant', 'deadband', 'accel_limit')
FWD, TURN = 'twist.twist.linear.x', 'twist.twist.angular.z'


def _signed(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi) * rng.choice([-1.0, 1.0]))


def draw(rng: np.random.Generator, name: str, k: int = 0) -> dict:
    """Return one effect: name, axis field, parameters; ``k`` alternates the axis."""
    axis = (FWD, TURN)[k % 2]
    if name == 'turn_rate_scale':
        return {'effect': name, 'field': TURN, 'parameters': {'scale': _signed(rng, .07, .10)}}
    if name == 'speed_scale':
        return {'effect': name, 'field': FWD, 'parameters': {'scale': _signed(rng, .06, .10)}}
    if name == 'yaw_rate_offset':
        return {'effect': name, 'field': TURN,
                'parameters': {'offset': _signed(rng, 0.01, 0.03)}}
    if name == 'transport_delay':
        return {'effect': name, 'field': None, 'parameters': {'tau': 0.1}}
    if name == 'time_constant':
        return {'effect': name, 'field': axis, 'parameters': {'tau': rng.uniform(0.15, 0.35)}}
    if name == 'deadband':
        return {'effect': name, 'field': TURN, 'parameters': {'band': rng.uniform(0.02, 0.04)}}
    if name == 'accel_limit':
        lo, hi = (0.08, 0.15) if axis == FWD else (0.4, 0.8)
        return {'effect': name, 'field': axis, 'parameters': {'limit': rng.uniform(lo, hi)}}
    raise ValueError(f'unknown effect {name}')


def stretches(t: np.ndarray, factor: float = 1.5) -> list:
    """Return (start, stop) index pairs of the gap-free stretches of ``t``."""
    if t.size < 2:
        return [(0, t.size)]
    dt = np.diff(t)
    cuts = np.flatnonzero(dt > factor * np.median(dt)) + 1
    edges = np.concatenate(([0], cuts, [t.size]))
    return list(zip(edges[:-1], edges[1:]))


def _lag(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    a = np.exp(-dt / tau)
    y = np.empty_like(x)
    acc = x[0]
    for i, xi in enumerate(x):
        y[i] = acc
        acc = a * acc + (1 - a) * xi
    return y


def _rate_limit(x: np.ndarray, dt: float, limit: float) -> np.ndarray:
    y = np.empty_like(x)
    acc = x[0]
    step = limit * dt
    for i, xi in enumerate(x):
        acc += min(max(xi - acc, -step), step)
        y[i] = acc
    return y


MOTION_S = 0.2  # s, the zero-phase moving average that separates motion from noise


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Return the centred moving average of ``width`` samples (shorter at the ends)."""
    k = np.ones(width)
    return np.convolve(x, k, mode='same') / np.convolve(np.ones(x.size), k, mode='same')


def apply(t: np.ndarray, fields: dict, e: dict, cmd: dict, response: float = 0.0) -> tuple:
    """
    Return (t, fields) of the real twist with effect ``e`` added.

    ``cmd``: the commands (``t``, ``v``, ``w``) for the deadband; ``response``:
    the drive's response time (s) the deadband's mask is delayed by.
    """
    f = {k: v.copy() for k, v in fields.items()}
    p, name, k = e['parameters'], e['effect'], e['field']
    if name in ('turn_rate_scale', 'speed_scale'):
        f[k] = f[k] * (1.0 + p['scale'])
    elif name == 'yaw_rate_offset':
        f[k] = f[k] + p['offset']
    elif name == 'transport_delay':
        return t + p['tau'], f
    elif name in ('time_constant', 'accel_limit'):
        for a, b in stretches(t):
            dt = float(np.median(np.diff(t[a:b]))) if b - a > 1 else 0.02
            seg = f[k][a:b]
            if name == 'time_constant':
                f[k][a:b] = _lag(seg, dt, p['tau'])
            else:  # the motion limited, the measurement's noise on it as it was
                motion = _smooth(seg, max(1, int(round(MOTION_S / dt))))
                f[k][a:b] = _rate_limit(motion, dt, p['limit']) + (seg - motion)
    elif name == 'deadband':
        idx = np.searchsorted(cmd['t'], t - response, side='right') - 1
        held = np.where(idx >= 0, cmd['w'][np.clip(idx, 0, None)], 0.0)
        f[k] = np.where(np.abs(held) < p['band'], 0.0, f[k])
    else:
        raise ValueError(f'unknown effect {name}')
    return t, f
