# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
``suggestions.yaml``: the findings as settings of the knobs users already have.

ros2_control's ``diff_drive_controller`` (wheel radius and separation
multipliers, velocity and acceleration limits) and a Gazebo SDF ``<imu>``
block, for the SIMULATED robot, so that it behaves like the real one
(:mod:`.export` writes it beside ``sim_params.yaml``).
"""

from __future__ import annotations

import math

from robot_calib.mismatch.export import (
    _axis, _drive_axes, _fmt, _NO_COUNTERPART, _sources, _split_channel, _yaml_scalar,
    one_per_slot)


def _controller(findings: dict) -> tuple[dict, list, list]:
    """Return diff_drive_controller values, their reasons and what it cannot express."""
    lin, ang = 1.0, 1.0
    why: list = []
    limits: dict = {'linear': math.nan, 'angular': math.nan}
    speeds: dict = {'linear': math.nan, 'angular': math.nan}
    rest: list = []
    kept, _ = one_per_slot(findings.get('findings', []), {})
    for f, drive_axes in kept:
        e, par = f['effect'], f.get('parameters') or {}
        _, field = _split_channel(f['channel'])
        axes = drive_axes or _drive_axes(field)
        text = f'{e} on {f["channel"]} ({_fmt(par)})'
        if f.get('window'):
            rest.append(f'{text}: only in a window')
        elif e == 'wheel_radius_scale' and not field.startswith('velocity.'):
            lin *= 1.0 + float(par['scale'])
            why.append(text)
        elif e == 'track_width_scale':
            ang /= 1.0 + float(par['scale'])
            why.append(text)
        elif e == 'drive_gain':
            for axis in axes:
                if axis == 'linear':
                    lin *= 1.0 + float(par['gain'])
                else:
                    ang *= 1.0 + float(par['gain'])
            why.append(text)
        elif e == 'wheel_speed_limit' and field.startswith('velocity.'):
            rest.append(f'{text}: a cap on the wheel rates (rad/s); diff_drive_controller '
                        'limits the body velocity: the cap times the wheel radius is the top '
                        'speed driving straight')
        elif e == 'wheel_speed_limit':
            # the faster wheel's cap: its bounds driving straight and turning in place
            half = par.get('half_track')
            speeds = {'linear': float(par['limit']),
                      'angular': math.nan if half is None else float(par['limit']) / half}
            why.append(text)
        elif e == 'drive_rate_limit':
            for axis in axes:
                old = limits[axis]
                limits[axis] = float(par['limit']) if math.isnan(old) else \
                    min(old, float(par['limit']))
            why.append(text)
        elif e in ('drive_lag', 'drive_dead_time', 'drive_deadband', 'turn_speed_loss'):
            rest.append(f'{text}: diff_drive_controller has no such parameter (a lag or dead '
                        "time is the motors' and their PID loop's; in Gazebo tune the wheel "
                        "joints' velocity controller, or model it with simulate follow "
                        '--params sim_params.yaml)')
    # wheel speeds = (v -+ w S m_s / 2) / (r m_r) on a robot of true radius r, track S:
    # v_true = v / m_r, w_true = w m_s / m_r
    m_r = 1.0 / lin
    m_s = ang / lin
    return {'radius': m_r, 'separation': m_s, 'limits': limits, 'speeds': speeds}, why, rest


def _imu_block(findings: dict) -> tuple[str, list, list]:
    """Return a Gazebo SDF imu sensor block, its reasons and what it cannot express."""
    mean = {'angular_velocity': [0.0, 0.0, 0.0], 'linear_acceleration': [0.0, 0.0, 0.0]}
    why: list = []
    rest: list = []
    pose = [0.0] * 6
    for f, _ in one_per_slot(findings.get('findings', []), {})[0]:
        e, par = f['effect'], f.get('parameters') or {}
        _, field = _split_channel(f['channel'])
        ax = _axis(field)
        text = f'{e} on {f["channel"]} ({_fmt(par)})'
        if e in ('gyro_bias', 'accel_bias') and ax is not None and not f.get('window'):
            group = 'angular_velocity' if e == 'gyro_bias' else 'linear_acceleration'
            mean[group][ax] += float(par['bias'])
            why.append(text)
        elif e in ('imu_mounting_tilt', 'imu_mounting_rotation'):
            for i, k in enumerate(('roll', 'pitch', 'yaw')):
                pose[3 + i] += float(par.get(k, 0.0) or 0.0)
            why.append(text + ' (as the sensor <pose>)')
        elif e == 'lever_arm':
            for i, k in enumerate('xyz'):
                v = par.get(k)
                if v is not None and math.isfinite(v):
                    pose[i] += float(v)
            why.append(text + ' (as the sensor <pose>)')
        elif e in ('gyro_scale', 'accel_scale', 'gyro_bias_drift', 'gyro_cross_axis',
                   'time_offset') and (_split_channel(f['channel'])[1].startswith(
                       ('angular_velocity', 'linear_acceleration')) or e == 'time_offset'):
            rest.append(f'{text}: the SDF noise model has no scale, drift, misalignment or '
                        'latency element')
    lines = ['<sensor name="imu_sensor" type="imu">',
             f'  <pose>{" ".join(f"{v:.6g}" for v in pose)}</pose>', '  <imu>']
    for group, vals in mean.items():
        lines.append(f'    <{group}>')
        for axis, val in zip('xyz', vals):
            lines.append(f'      <{axis}><noise type="gaussian"><mean>{val:.6g}</mean>'
                         '<stddev>0</stddev><bias_mean>0</bias_mean><bias_stddev>0</bias_stddev>'
                         f'</noise></{axis}>')
        lines.append(f'    </{group}>')
    lines += ['  </imu>', '</sensor>']
    return '\n'.join(lines), why, rest


def suggestions_text(findings: dict) -> str:
    """Return ``suggestions.yaml``: diff_drive_controller and Gazebo IMU settings (YAML)."""
    ctrl, cwhy, crest = _controller(findings)
    sdf, iwhy, irest = _imu_block(findings)
    src = _sources(findings)
    lim = ctrl['limits']
    lines = ['# Settings for the SIMULATED robot, so that it behaves like the real one',
             '# (from robot-calib mismatch findings; real = f(sim)).',
             f'# simulated recording: {src["sim"]}', f'# real recording: {src["real"]}',
             f'source: {{sim: {_yaml_scalar(src["sim"])}, real: {_yaml_scalar(src["real"])}}}',
             '# ros2_control diff_drive_controller of the simulated robot (Humble/Jazzy names).',
             '# It turns the wheels at (v -+ omega S m_s / 2) / (r m_r): with the true radius r',
             '# and separation S the robot then drives v / m_r and turns omega m_s / m_r.',
             "# If instead the REAL robot's controller runs with wrong geometry, calibrate it",
             '# (wheel_odometry_calibration) rather than detune the simulation.']
    lines += [f'# from {w}' for w in cwhy] or ['# no speed or turn-rate scale was found']
    lines += ['diff_drive_controller:', '  ros__parameters:',
              f'    wheel_separation_multiplier: {ctrl["separation"]:.6g}',
              f'    left_wheel_radius_multiplier: {ctrl["radius"]:.6g}',
              f'    right_wheel_radius_multiplier: {ctrl["radius"]:.6g}']
    for axis, comp, unit in (('linear', 'x', 'm/s'), ('angular', 'z', 'rad/s')):
        a, top = lim[axis], ctrl['speeds'][axis]
        has, fast = not math.isnan(a), not math.isnan(top)
        lines += [f'    {axis}:', f'      {comp}:',
                  f'        # velocity limit ({unit}) of the wheel-speed cap (wheel_speed_limit; '
                  'the cap binds on the faster wheel, sooner when driving and turning at once)'
                  if fast else '        # no velocity saturation in the findings (.nan: no '
                  'limit)', f'        has_velocity_limits: {"true" if fast else "false"}',
                  f'        max_velocity: {_yaml_scalar(top)}',
                  f'        min_velocity: {_yaml_scalar(-top)}',
                  f'        # acceleration limit ({unit}/s) from drive_rate_limit' if has else
                  '        # no acceleration limit in the findings',
                  f'        has_acceleration_limits: {"true" if has else "false"}',
                  f'        max_acceleration: {_yaml_scalar(a)}',
                  f'        min_acceleration: {_yaml_scalar(-a)}']
    lines += ['# Gazebo IMU sensor (SDF <imu>): a constant offset goes into <mean>, whose sign',
              '# Gazebo keeps; <bias_mean> is drawn with a random sign at every start, so it',
              '# cannot carry a known bias. stddev: white noise, not measured by the comparison.']
    lines += [f'# from {w}' for w in iwhy]
    lines += ['gazebo_imu_sdf: |'] + ['  ' + ln for ln in sdf.splitlines()]
    rest = crest + irest
    for f in findings.get('findings', []):
        if f['effect'] in _NO_COUNTERPART:
            rest.append(f'{f["effect"]} on {f["channel"]} ({_fmt(f.get("parameters", {}))}): '
                        f'{_NO_COUNTERPART[f["effect"]]}')
    lines.append('not_covered:' + ('' if rest else ' []'))
    lines += [f'  - {_yaml_scalar(r)}' for r in dict.fromkeys(rest)]
    return '\n'.join(lines) + '\n'
