# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""One or two plain sentences per finding, in the words a robotics engineer uses."""

from __future__ import annotations

from typing import Optional

import numpy as np

from robot_calib.mismatch import effects as E

_SCALED = {'gyro_scale': 'the real gyro rate', 'accel_scale': 'the real acceleration',
           'wheel_radius_scale': 'the real odometry speed (wheel radius)',
           'track_width_scale': 'the effective track width (odometry yaw rate / (1+k))'}


def _fmt(v: float, unit: str) -> str:
    return f'{v:.4g} {unit}'.strip()


def _deg(v: float) -> str:
    return f'{np.degrees(v):.2f} deg'


def _sentence(effect: str, params: dict, where: str, meta: dict) -> str:
    p = params
    if effect == 'gyro_bias':
        return f'The real gyro reads {_fmt(p["bias"], "rad/s")} more than the simulation{where}.'
    if effect == 'gyro_bias_drift':
        return (f'The real gyro has an offset of {_fmt(p["bias"], "rad/s")} at the start that '
                f'changes by {_fmt(p["drift"], "rad/s^2")} (a warm-up drift){where}.')
    if effect in _SCALED:
        k = p['scale']
        what = _SCALED[effect]
        return f'{what[0].upper() + what[1:]} is {abs(k) * 100:.2f}% ' \
            f'{"larger" if k > 0 else "smaller"} than simulated{where}.'
    if effect == 'time_offset':
        tau = p['tau']
        return f'The real recording {"lags" if tau > 0 else "leads"} the simulation by ' \
            f'{abs(tau) * 1000:.1f} ms (a latency the simulation does not have).'
    if effect == 'timing_drift':
        most = meta.get('max_lag', np.inf)

        def part(d) -> str:
            if d is None:
                return 'not measured'
            if d.at_edge:
                return f'beyond {np.sign(d.tau) * most * 1000:+.0f} ms'
            return f'{d.tau * 1000:+.0f} ms'
        parts = '; '.join(f'{a:.0f}-{b:.0f} s: {part(d)}' for a, b, d in meta.get('parts', []))
        return 'The delay between the recordings is not one constant within the ' \
            f'+-{most * 1000:.0f} ms searched ({parts}; positive: real lags). No latency ' \
            'explains it: a clock of another ' \
            'rate, or a run that did not keep the simulated timeline (closed-loop driving ' \
            'reaching its goals at other times), so the two compare motions that are not ' \
            f'simultaneous; aligned by its run-wide {meta.get("tau", 0.0) * 1000:.0f} ms ' \
            'for the rest of the analysis.'
    if effect == 'drive_lag':
        return f'The real drive follows its command with a first-order lag of ' \
            f'{p["tau"] * 1000:.0f} ms that the simulation does not model.'
    if effect == 'accel_bias':
        return f'The real accelerometer reads {_fmt(p["bias"], "m/s^2")} more than the ' \
            f'simulation{where}.'
    if effect == 'centripetal_acceleration':
        return f'The real lateral acceleration contains v*omega with gain {p["gain"]:.3f}: ' \
            'the simulation leaves out the centripetal acceleration in turns.'
    if effect == 'imu_mounting_tilt':
        return f'The IMU is mounted tilted by roll {_deg(p["roll"])} and pitch ' \
            f'{_deg(p["pitch"])}, so gravity leaks into a_x and a_y.'
    if effect == 'imu_mounting_rotation':
        return f'The real IMU frame is rotated from the simulated one by roll ' \
            f'{_deg(p["roll"])}, pitch {_deg(p["pitch"])}, yaw {_deg(p["yaw"])}: rates and ' \
            'accelerations leak between axes alike.'
    if effect == 'lever_arm':
        xyz = ', '.join(f'{p[k] * 100:.1f}' for k in 'xyz')
        return f'The real IMU sits {xyz} cm (x, y, z) from the point the simulation ' \
            'measured, so it feels extra centripetal and tangential acceleration when turning.'
    if effect == 'wheel_slip':
        return f'The real odometry speed changes with the commanded acceleration (coefficient ' \
            f'{_fmt(p["coefficient"], "s^2/m")}): the wheels slip{where}.'
    if effect == 'gyro_cross_axis':
        src = meta.get('source', 'another axis')
        c = p['coefficient']
        return f'Rotation about {src} leaks into this axis with coefficient {c:.4f} (an axis ' \
            f'misalignment of {np.degrees(np.arcsin(np.clip(c, -1, 1))):.2f} deg).'
    if effect == 'steering_scale':
        return f'The real steering angle is {abs(p["scale"]) * 100:.1f}% ' \
            f'{"larger" if p["scale"] > 0 else "smaller"} than simulated: the encoder-to-angle ' \
            'gain differs.'
    if effect == 'wheel_radius_difference':
        return f'The real odometry turns by {_fmt(p["coefficient"], "rad/m")} per metre driven ' \
            f'more than simulated{where}: the right and left wheels differ in radius by about ' \
            'that times the track width (relative).'
    if effect == 'yaw_rate_offset':
        return f'The real yaw rate reads {_fmt(p["offset"], "rad/s")} more than the simulated ' \
            f'one{where}: a gyro bias of the reference, or odometry that turns while driving ' \
            'straight.'
    if effect == 'steering_offset':
        return f'The real steering angle reads {_deg(p["offset"])} ' \
            f'{"more" if p["offset"] > 0 else "less"} than simulated (a zero offset of the ' \
            f'steering encoder){where}.'
    return f'{E.SPECS[effect].what}{where}.'


def explain(effect: str, params: dict, window: Optional[list], fitd: dict,
            meta: Optional[dict] = None) -> str:
    """Return one or two plain sentences on a finding (and a warning when implausible)."""
    spec = E.SPECS[effect]
    where = f' between {window[0]:.1f} s and {window[1]:.1f} s' if window else ''
    s = _sentence(effect, params, where, meta or {})
    hb, ha = fitd.get('heldout_rmse_before'), fitd.get('heldout_rmse_after')
    if hb and ha is not None and hb > 0:
        s += f' Modelling it cuts the held-out residual from {hb:.3g} to {ha:.3g}.' \
            if ha < hb else ' It does not lower the held-out residual as plainly measured ' \
            f'({hb:.3g} before, {ha:.3g} after): it improves only the fit that weighs quiet ' \
            'samples more.'
    for name, lim in zip(spec.params, spec.plausible):
        if abs(params.get(name, 0.0)) > lim:
            s += f' The {name} is beyond the plausible {lim:g}: check units and the pairing.'
    return s


def unexplained(channel: str, rms: float, noise: float, corr: Optional[tuple],
                window: Optional[list]) -> str:
    """Return the sentences of an ``unexplained`` finding."""
    where = f' between {window[0]:.1f} s and {window[1]:.1f} s' if window else ''
    s = f'After the effects found, {channel} still differs by {rms:.3g} (RMS) beyond its ' \
        f'noise of {noise:.3g}{where}; no effect of the library explains it.'
    if corr is not None:
        s += f' It follows {corr[0]} (correlation {corr[1]:+.2f}): look for physics tied to ' \
            f'that signal, or an error of the reference.'
    else:
        s += ' It follows none of speed, acceleration, turn rate or time.'
    return s
