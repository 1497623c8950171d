# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The drive's channels by name and the drive model in words (:mod:`.drive` fits it)."""

from __future__ import annotations

import math

from robot_calib.mismatch import drive_interval as DI

V, W = 'twist.twist.linear.x', 'twist.twist.angular.z'
AXIS = {V: 'forward speed', W: 'turn rate'}
UNIT = {V: 'm/s', W: 'rad/s'}


def wheel_rates(fields) -> list:
    """Return the wheel-rate channels of a joint-state topic (rad/s; not steering joints)."""
    return [f for f in fields if f.startswith('velocity.') and 'steer' not in f]


def driven(f: str) -> bool:
    """Return True for a channel a drive moves: forward speed, turn rate, or a wheel's rate."""
    return f in (V, W) or bool(wheel_rates([f]))


def axis_name(f: str) -> str:
    """Return the name of a driven channel in words (a wheel joint's by its joint name)."""
    return AXIS.get(f, f'{f.partition(".")[2]} wheel rate')


def unit_of(f: str) -> str:
    """Return the unit of a driven channel (m/s, or rad/s for a turn rate or a wheel)."""
    return UNIT.get(f, 'rad/s')


def _damping_sentence(zeta: float, sd: float, test: tuple) -> str:
    over = math.exp(-math.pi * zeta / math.sqrt(1.0 - zeta * zeta)) if zeta < 1 else 0.0
    shape = f'overshoots a step by {100 * over:.0f} %' if over >= 0.005 else \
        'does not overshoot, but starts more slowly than a first-order lag'
    return f'The response is second order (damping {DI.with_std(zeta, sd)}, mean delay as ' \
        f'given): it {shape}; against a first-order lag of the same parts the held-out ' \
        f'fit improves (z {test[0]:.1f} > {test[1]:.1f} over {test[2]} pieces).'


def _sentence(p: str, f: str, val: float, sd: float = math.nan) -> str:
    ax, v = axis_name(f), DI.with_std(val, sd)
    if p == 'drive_lag':
        return f'The real {ax} follows the command with a first-order lag of {v} s.'
    if p == 'drive_dead_time':
        return f'The real {ax} starts to follow the command {DI.with_std(val, sd, 1000.0)} ' \
            'ms late (dead time, before the lag).'
    if p == 'drive_deadband':
        return f'{ax.capitalize()} commands smaller than {v} {unit_of(f)} move nothing (deadband).'
    if p == 'drive_rate_limit':
        return f'The real {ax} changes no faster than {v} {unit_of(f)}/s (acceleration limit).'
    if p == 'drive_gain':
        return f'The real {ax} settles at {DI.with_std(1.0 + val, sd, 100.0)} % of the ' \
            'command (steady-state gain, fitted with the dynamics).'
    v = f'({v})' if '+-' in v else v
    return f'The real forward speed drops while turning: speed = command x (1 - {v} ' \
        '|omega|), omega in rad/s.'


def describe(models: dict) -> str:
    """Return the drive in its own terms, one clause per axis."""
    parts = []
    for f, m in models.items():
        s = f'{axis_name(f)}: '
        bits = []
        if m.d > 0 and 'drive_dead_time' in m.parts:
            bits.append(f'{m.d:.2f} s dead time')
        if 'drive_lag' in m.parts and m.zeta > 0 and 'drive_damping' in m.parts:
            bits.append(f'{m.tau:.2f} s second-order response (damping {m.zeta:.2f})')
        elif 'drive_lag' in m.parts:
            bits.append(f'{m.tau:.2f} s time constant')
        if not bits:
            bits.append('no lag')
        s += ' + '.join(bits)
        if 'drive_gain' in m.parts:
            s += f', settles at {100 * (1 + m.gain):.1f} % of the command'
        if 'turn_speed_loss' in m.parts:
            s += f', slows by {m.k:.2f} x |omega| in turns'
        if 'drive_deadband' in m.parts:
            s += f', deadband {m.band:.3g} {unit_of(f)}'
        if 'drive_rate_limit' in m.parts:
            s += f', rate limit {m.limit:.3g} {unit_of(f)}/s'
        parts.append(s)
    return 'Drive model (fitted together): ' + '; '.join(parts) + '.'
