# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The findings as settings: a simulator parameter file and suggestions for common knobs.

Beside ``findings.json`` the analyser writes:

- ``sim_params.yaml``: the simulator parameters that make the simulated robot
  do what the real one did (``robot-calib simulate follow REAL_BAG --params
  sim_params.yaml``). A finding says ``real = f(sim)``, so the corrected
  simulation applies ``f``: a ``drive_lag`` tau makes the simulated drive lag
  by tau, a ``wheel_radius_scale`` k makes the simulated odometry speed
  ``(1 + k)`` times (through the drive's forward gain: the wheels turn that
  much faster than commanded, so odometry and true motion scale alike). When
  ``<sim bag>.truth.json`` exists (a simulation of this tool), its parameters
  are the starting point and the findings are composed onto them; effects
  without a simulator counterpart are listed in comments.
- ``suggestions.yaml``: the same findings in the knobs a ROS user already has:
  ros2_control ``diff_drive_controller`` parameters (wheel radius and separation
  multipliers, velocity and acceleration limits) for the SIMULATED robot's
  controller, and a Gazebo SDF ``<imu>`` noise block; what neither can express
  is listed under ``not_covered``.

Both files name the recordings they came from.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Optional

import numpy as np

from robot_calib.sim.params import SimParams

SKIP_BASE = ('start_time', 'odom.cmd_vel_rate', 'mode')
"""Base parameters not carried into sim_params.yaml (follow sets them from the recording)."""

AXES = {'x': 0, 'y': 1, 'z': 2}


def _split_channel(channel: str) -> tuple[str, str]:
    """Return (topic, field path) of a findings channel (``/imu.angular_velocity.z``)."""
    topic, _, field = str(channel).partition('.')
    return topic, field


def _axis(field: str) -> Optional[int]:
    return AXES.get(field.rsplit('.', 1)[-1]) if field else None


def _drive_axes(field: str) -> tuple:
    """
    Return the drive axes a channel speaks for: linear, angular, or both.

    Both for a whole topic and for a wheel joint (its motor carries speed and turn alike).
    """
    if field.endswith('linear.x'):
        return ('linear',)
    if field.endswith('angular.z'):
        return ('angular',)
    return ('linear', 'angular')


def _sensor_kind(topic: str, field: str, topic_map: dict) -> str:
    """Return imu, odom or joint_states for a channel (the sim's topic map, else its names)."""
    kind = topic_map.get(topic)
    if kind in ('imu', 'odom', 'joint_states'):
        return kind
    if field.startswith(('angular_velocity', 'linear_acceleration')) or 'imu' in topic:
        return 'imu'
    if field.startswith(('velocity.', 'position.')) or 'joint' in topic:
        return 'joint_states'
    return 'odom'


def _rot(roll: float, pitch: float, yaw: float) -> np.ndarray:
    from robot_calib.sim.robot import rotation_matrix
    return np.asarray(rotation_matrix(roll, pitch, yaw), float).reshape(3, 3)


def _rpy(r: np.ndarray) -> tuple[float, float, float]:
    """Return roll, pitch, yaw (rad) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -float(r[2, 0]))))
    return (math.atan2(float(r[2, 1]), float(r[2, 2])), pitch,
            math.atan2(float(r[1, 0]), float(r[0, 0])))


def base_params(sim_bag: Optional[str]) -> tuple[dict, dict, str]:
    """
    Return the simulated run's parameters (flat), its topic map and where they came from.

    From ``<sim_bag>.truth.json`` when it exists; else the simulator defaults.
    """
    from robot_calib.core.params import to_flat
    defaults = to_flat(SimParams())
    if sim_bag:
        path = Path(str(sim_bag).rstrip('/'))
        tpath = path.with_name(path.name + '.truth.json')
        try:
            truth = json.loads(tpath.read_text())
            params = truth.get('params')
            if isinstance(params, dict):
                merged = dict(defaults)
                merged.update({k: v for k, v in params.items()
                               if k in defaults or k.startswith('follow.')})
                return merged, truth.get('topic_map') or {}, str(tpath)
        except (OSError, ValueError):
            pass
    return dict(defaults), {}, 'the simulator defaults (no truth.json beside the simulated bag)'


class _Mapper:
    """Compose findings onto simulator parameters; collect what cannot be expressed."""

    def __init__(self, base: dict, topic_map: dict):
        self.v = {k: (list(x) if isinstance(x, list) else x) for k, x in base.items()}
        self.topic_map = topic_map
        self.notes: dict[str, list] = {}
        self.unmapped: list = []

    def note(self, key: str, text: str) -> None:
        self.notes.setdefault(key, []).append(text)

    def vec_add(self, key: str, axis: int, value: float, why: str) -> None:
        self.v[key][axis] = float(self.v[key][axis]) + float(value)
        self.note(key, why)

    def vec_scale(self, key: str, axis: int, scale: float, why: str) -> None:
        self.v[key][axis] = (1.0 + float(self.v[key][axis])) * (1.0 + float(scale)) - 1.0
        self.note(key, why)

    def add(self, key: str, value: float, why: str) -> None:
        self.v[key] = float(self.v[key]) + float(value)
        self.note(key, why)

    def gain(self, key: str, factor: float, why: str) -> None:
        self.v[key] = (1.0 + float(self.v[key])) * float(factor) - 1.0
        self.note(key, why)

    def cannot(self, f: dict, why: str) -> None:
        self.unmapped.append(f'{f["effect"]} on {f["channel"]} '
                             f'({_fmt(f.get("parameters", {}))}): {why}')

    def apply(self, f: dict, axes: Optional[tuple] = None) -> None:  # noqa: C901
        """Compose one finding (one branch per effect of the table); ``axes``: drive axes."""
        e = f['effect']
        par = f.get('parameters') or {}
        topic, field = _split_channel(f['channel'])
        why = f'{e} on {f["channel"]} ({_fmt(par)}, confidence {f.get("confidence", 0):.2f})'
        ax = _axis(field)
        if f.get('window'):
            self.cannot(f, f'acts only between {f["window"][0]:.1f} and {f["window"][1]:.1f} s; '
                           'the simulator parameters act over the whole run')
            return
        if e in ('gyro_bias', 'gyro_scale', 'gyro_bias_drift', 'accel_bias', 'accel_scale') \
                and ax is None:
            self.cannot(f, 'no axis in the channel')
            return
        if e == 'gyro_bias':
            self.vec_add('imu.gyro_bias', ax, par['bias'], why)
        elif e == 'gyro_scale':
            self.vec_scale('imu.gyro_scale', ax, par['scale'], why)
        elif e == 'gyro_bias_drift':
            self.vec_add('imu.gyro_bias', ax, par['bias'], why)
            self.vec_add('imu.gyro_bias_drift', ax, par['drift'], why)
        elif e == 'accel_bias':
            self.vec_add('imu.accel_bias', ax, par['bias'], why)
        elif e == 'accel_scale':
            self.vec_scale('imu.accel_scale', ax, par['scale'], why)
        elif e == 'time_offset':
            key = f'latency.{_sensor_kind(topic, field, self.topic_map)}'
            new = float(self.v[key]) + float(par['tau'])
            if new < 0 or new > 1.0:
                self.cannot(f, f'{key} would be {new:.4f} s; the simulator delays a sensor by '
                               '0 to 1 s only (the real one is earlier: shift the real stamps)')
                return
            self.add(key, par['tau'], why)
        elif e == 'centripetal_acceleration':
            if 0.5 <= float(par.get('gain', 0)) <= 1.5:
                self.v['imu.centripetal'] = True
                self.note('imu.centripetal', why)
            else:
                self.cannot(f, 'only the whole centripetal term (gain 1) can be switched on')
        elif e in ('imu_mounting_tilt', 'imu_mounting_rotation'):
            r0 = _rot(self.v['imu.roll'], self.v['imu.pitch'], self.v['imu.yaw'])
            r = _rot(par.get('roll', 0.0), par.get('pitch', 0.0), par.get('yaw', 0.0))
            for key, val in zip(('imu.roll', 'imu.pitch', 'imu.yaw'), _rpy(r0 @ r)):
                self.v[key] = val
                self.note(key, why)
        elif e == 'lever_arm':
            r0 = _rot(self.v['imu.roll'], self.v['imu.pitch'], self.v['imu.yaw'])
            arm = np.array([par.get(k) if par.get(k) is not None and
                            math.isfinite(par.get(k)) else 0.0 for k in 'xyz'], float)
            for key, val in zip(('imu.x', 'imu.y', 'imu.z'), r0 @ arm):
                self.add(key, val, why)
        elif e in ('wheel_radius_scale', 'track_width_scale'):
            self._scale(f, e, par, field, why)
        elif e in ('drive_rate_limit', 'drive_deadband') and field.startswith('velocity.'):
            self.cannot(f, "one wheel's own limit, in its rate's units (rad/s, rad/s^2); the "
                           "simulator's drive limits act on the body's speed and turn rate")
        elif e in ('drive_lag', 'drive_dead_time', 'drive_gain', 'drive_rate_limit',
                   'drive_deadband'):
            self._drive(e, par, axes or _drive_axes(field), why)
        elif e == 'turn_speed_loss':
            self.add('drive.turn_speed_loss', par['coefficient'], why)
        elif e == 'wheel_speed_limit':
            self._cap(f, par, field, why)
        elif e == 'steering_offset':
            self.add('wheels.steering_offset', par['offset'], why)
        elif e in LIDAR_KEYS:
            self._lidar(f, e, par, why)
        elif e == 'scan_distortion':
            self._sweep(f, par, why)
        else:
            self.cannot(f, _NO_COUNTERPART.get(e, 'no simulator parameter models it'))

    def _lidar(self, f: dict, e: str, par: dict, why: str) -> None:
        """Compose a lidar finding onto the simulator's lidar effects (``lidar.*``)."""
        if e == 'lidar_time_offset' and 'lidar.time_offset' not in self.v:
            new = float(self.v.get('latency.scan', 0.0)) + float(par['tau'])
            if 'latency.scan' in self.v and 0.0 <= new <= 1.0:
                self.add('latency.scan', par['tau'], why)
            else:
                self.cannot(f, 'the simulator delays its scans by 0 to 1 s only')
            return
        keys = LIDAR_KEYS[e]
        if e == 'dropout_rate' and 'incidence' in par:
            keys = DROPOUT_INCIDENCE_KEYS
        missing = [k for k, _ in keys if k not in self.v]
        if missing:
            self.cannot(f, f'this simulator has no {", ".join(missing)} (its lidar effects)')
            return
        if e == 'dropout_rate':
            if 'incidence' in par:  # lost at grazing incidence (rad from the normal)
                self.v['lidar.dropout_incidence'] = float(par['incidence'])
                self.v['lidar.dropout_incidence_rate'] = float(par['rate'])
                self.note('lidar.dropout_incidence', why)
                self.note('lidar.dropout_incidence_rate', why)
            elif float(par.get('beyond', 0.0)) > 0:
                self.v['lidar.dropout_beyond'] = float(par['beyond'])
                self.v['lidar.dropout_beyond_rate'] = float(par['rate'])
                self.note('lidar.dropout_beyond', why)
                self.note('lidar.dropout_beyond_rate', why)
            else:
                self.add('lidar.dropout', par['rate'], why)
            return
        for key, name in keys:
            self.add(key, par[name], why)

    def _sweep(self, f: dict, par: dict, why: str) -> None:
        """Turn the simulator's sweep distortion on or off (it sweeps in 0 s or 1 / rate)."""
        if 'lidar.motion_distortion' not in self.v or 'lidar.rate' not in self.v:
            self.cannot(f, 'this simulator has no lidar.motion_distortion')
            return
        period = 1.0 / float(self.v['lidar.rate'])
        new = (period if self.v['lidar.motion_distortion'] else 0.0) + float(par['sweep_time'])
        on = new > 0.5 * period
        if abs(new - (period if on else 0.0)) > 0.25 * period:
            self.cannot(f, f'the simulator sweeps in 0 s (deskewed) or one scan period '
                           f'({period * 1000:.0f} ms); a sweep of {new * 1000:.0f} ms is neither')
            return
        self.v['lidar.motion_distortion'] = bool(on)
        self.note('lidar.motion_distortion', why)

    def _scale(self, f: dict, e: str, par: dict, field: str, why: str) -> None:
        k = float(par['scale'])
        if field.startswith('velocity.'):
            self.cannot(f, 'on a wheel joint rate the wheel radius itself differs; the simulator '
                           'keeps the commanded wheel rate, so set wheels.left_radius_error / '
                           'right_radius_error by hand if the wheel is really larger')
            return
        if e == 'wheel_radius_scale':  # real v = (1 + k) sim v
            self.gain('drive.linear_gain', 1.0 + k, why + ': the forward speed (odometry and '
                      'true motion) becomes (1 + k) times')
        else:  # real omega = sim omega / (1 + k)
            self.gain('drive.angular_gain', 1.0 / (1.0 + k), why + ': the turn rate becomes '
                      '1 / (1 + k) times')

    def _cap(self, f: dict, par: dict, field: str, why: str) -> None:
        """Compose a wheel-speed cap: the simulator's ``drive.max_wheel_speed`` (rad/s)."""
        if field.startswith('velocity.'):
            # found on the wheel joints' rates: the simulator's own cap, in rad/s
            self.v['drive.max_wheel_speed'] = float(par['limit'])
            self.note('drive.max_wheel_speed', why + ' (a wheel rate, from the joint states)')
        elif par.get('half_track') is None:
            self.cannot(f, 'a top speed met driving straight: the half track it acts about is '
                           "not known, and as the simulator's wheel-speed cap it would slow "
                           'the turns too, which the recording does not show (a linear '
                           'velocity limit of the controller: suggestions.yaml)')
        else:
            # the simulator caps the faster wheel in rad/s of its nominal radius, about its
            # own track
            r = float(self.v['robot.wheel_radius'])
            half = 0.5 * float(self.v['robot.track_width'])
            self.v['drive.max_wheel_speed'] = float(par['limit']) / r
            found = float(par['half_track'])
            self.note('drive.max_wheel_speed', why + (
                f' (found about a half track of {found:.3g} m; the simulated robot has '
                f'{half:.3g} m)' if abs(found - half) > 0.1 * half else ''))

    def _drive(self, e: str, par: dict, axes: tuple, why: str) -> None:
        for axis in axes:
            if e == 'drive_lag':
                # cascaded first-order lags: the sum of time constants keeps the mean delay
                self.add(f'drive.{axis}_time_constant', par['tau'], why)
                if par.get('damping'):  # second order, of the same mean delay
                    self.v[f'drive.{axis}_damping'] = float(par['damping'])
                    self.note(f'drive.{axis}_damping', why)
            elif e == 'drive_dead_time':
                self.add(f'drive.{axis}_dead_time', par['tau'], why)
            elif e == 'drive_gain':
                self.gain(f'drive.{axis}_gain', 1.0 + float(par['gain']), why)
            elif e == 'drive_rate_limit':
                key = f'drive.{axis}_rate_limit'
                old = float(self.v[key])
                self.v[key] = float(par['limit']) if old <= 0 else min(old, float(par['limit']))
                self.note(key, why)
            else:
                key = f'drive.{axis}_deadband'
                self.v[key] = max(float(self.v[key]), float(par['band']))
                self.note(key, why)


_NO_COUNTERPART = {
    'gyro_cross_axis': 'the simulated gyro has no axis-misalignment matrix (a mounting '
                       'rotation moves all axes alike)',
    'wheel_slip': 'the simulated slip (wheels.slip_coefficient) acts on the true motion, not '
                  'on the odometry the finding compares',
    'yaw_rate_offset': 'a constant yaw-rate difference is a reference gyro bias or odometry '
                       'that turns when driving straight; neither is a drive parameter',
    'wheel_radius_difference': 'the simulated odometry uses the nominal geometry, so unequal '
                               'wheel radii would not show in it',
    'steering_scale': 'the simulated steering reading has no scale error parameter here',
    'timing_drift': "the simulator runs on one clock; a drifting delay is the recording's",
    'unexplained': 'not a physical effect: structure no model of the library explains',
}


DRIVE_EFFECTS = ('drive_lag', 'drive_dead_time', 'drive_gain', 'drive_rate_limit',
                 'drive_deadband')


LIDAR_KEYS = {'lidar_mounting_yaw': [('lidar.yaw_error', 'yaw')],
              'lidar_mounting_offset': [('lidar.x_error', 'x'), ('lidar.y_error', 'y')],
              'lidar_time_offset': [('lidar.time_offset', 'tau')],
              'range_bias': [('lidar.range_bias', 'bias')],
              'range_scale': [('lidar.range_scale', 'scale')],
              'range_noise_growth': [('lidar.noise_growth', 's1')],
              'dropout_rate': [('lidar.dropout_beyond', 'beyond'),
                               ('lidar.dropout_beyond_rate', 'rate')]}
"""Simulator parameters (the lidar effects of ``sim.params.LidarParams``) per lidar finding."""
DROPOUT_INCIDENCE_KEYS = [('lidar.dropout_incidence', 'incidence'),
                          ('lidar.dropout_incidence_rate', 'rate')]
"""The simulator parameters of a ``dropout_rate`` finding by incidence (rad, probability)."""


def one_per_slot(findings: list, topic_map: dict) -> tuple[list, list]:
    """
    Return ([(finding, drive axes or None)], [set-aside findings]): one finding per slot.

    The same physical effect is often seen on several channels (a drive lag on the
    odometry, the ground truth and the wheel joints); composing them all would
    apply it several times. Each effect acts once per slot: per drive axis for the
    drive effects (a channel of that axis beats a wheel joint or a whole topic, which
    speak for both axes), per axis for the IMU effects, per sensor for a latency;
    the most specific, then the most confident finding wins.
    """
    best: dict = {}
    for i, f in enumerate(findings):
        e = f['effect']
        topic, field = _split_channel(f['channel'])
        conf = float(f.get('confidence') or 0.0)
        if e in DRIVE_EFFECTS:
            axes = _drive_axes(field)
            slots = [((e, a), (len(axes) == 1, conf, -i), (a,)) for a in axes]
        elif e in ('gyro_bias', 'gyro_scale', 'gyro_bias_drift', 'accel_bias', 'accel_scale'):
            slots = [((e, field.split('.', 1)[0], _axis(field)), (True, conf, -i), None)]
        elif e == 'time_offset':
            slots = [((e, _sensor_kind(topic, field, topic_map)), (True, conf, -i), None)]
        elif e in ('turn_speed_loss', 'imu_mounting_tilt', 'imu_mounting_rotation',
                   'lever_arm', 'centripetal_acceleration', 'steering_offset'):
            slots = [((e,), (True, conf, -i), None)]
        elif e in ('wheel_radius_scale', 'track_width_scale') and \
                not field.startswith('velocity.'):
            slots = [((e,), (True, conf, -i), None)]
        elif e == 'wheel_speed_limit':
            # one cap of the robot: the odometry's with its half track, else the wheel joints'
            # (rad/s), else a top speed met driving straight (not applied: a note)
            known = (f.get('parameters') or {}).get('half_track') is not None
            rank = 2 if field.startswith('velocity.') else 1 + 2 * known
            slots = [((e,), (rank, conf, -i), None)]
        else:
            slots = [((e, f['channel']), (True, conf, -i), None)]
        for slot, rank, axes in slots:
            if slot not in best or rank > best[slot][0]:
                best[slot] = (rank, i, axes)
    chosen: dict = {}
    for rank, i, axes in best.values():
        chosen.setdefault(i, []).extend(axes or [])
    kept = [(findings[i], tuple(axes) or None) for i, axes in sorted(chosen.items())]
    aside = [f for i, f in enumerate(findings) if i not in chosen]
    return kept, aside


def _fmt(params: dict) -> str:
    out = []
    for k, v in params.items():
        out.append(f'{k} = {v:.4g}' if isinstance(v, (int, float)) and v is not None
                   else f'{k} = {v}')
    return ', '.join(out)


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, list):
        return '[' + ', '.join(_yaml_scalar(v) for v in value) + ']'
    if isinstance(value, float):
        if math.isnan(value):
            return '.nan'
        return repr(round(value, 9))
    return repr(value)


def _sources(findings: dict) -> dict:
    inp = findings.get('inputs') or {}
    return {'sim': str(inp.get('sim', '')), 'real': str(inp.get('real', ''))}


def sim_params_text(findings: dict, sim_bag: Optional[str] = None) -> str:
    """Return ``sim_params.yaml``: the findings composed onto the simulated run's parameters."""
    from robot_calib.core.params import to_flat
    base, topic_map, origin = base_params(sim_bag)
    m = _Mapper(base, topic_map)
    kept, aside = one_per_slot(findings.get('findings', []), topic_map)
    for f, axes in kept:
        m.apply(f, axes)
    defaults = to_flat(SimParams())
    from robot_calib.sim.follow import FollowParams
    follow_defaults = {f'follow.{k}': v for k, v in to_flat(FollowParams()).items()}
    src = _sources(findings)
    lines = ['# Simulator parameters from robot-calib mismatch: the simulated robot with what the',
             '# real one showed (real = f(sim); this file applies f). Use it with',
             '#   robot-calib simulate follow REAL_BAG --out SIM_BAG --params sim_params.yaml',
             f'# simulated recording: {src["sim"]}', f'# real recording: {src["real"]}',
             f'# starting point: {origin}', f'# verdict: {findings.get("verdict", "?")}, '
             f'{len(findings.get("findings", []))} finding(s)',
             f'source: {{sim: {_yaml_scalar(src["sim"])}, real: {_yaml_scalar(src["real"])}}}',
             'sim:']
    groups: dict[str, list] = {}
    for key, value in m.v.items():
        if key in SKIP_BASE:
            continue
        changed = key in m.notes or (key in defaults and value != defaults[key]) or \
            (key.startswith('follow.') and value != follow_defaults.get(key))
        if not changed:
            continue
        group, _, name = key.partition('.')
        groups.setdefault(group, []).append((name, value, m.notes.get(key, [])))
    for group, items in groups.items():
        lines.append(f'  {group}:')
        for name, value, notes in items:
            for why in dict.fromkeys(notes):
                lines.append(f'    # from {why}')
            if not notes:
                lines.append('    # as in the simulated run')
            lines.append(f'    {name}: {_yaml_scalar(value)}')
    if not groups:
        lines[-1] = 'sim: {}'
    if m.unmapped:
        lines += ['# Findings with no simulator counterpart (not applied):']
        lines += [f'#  - {u}' for u in m.unmapped]
    if aside:
        lines += ['# The same effect seen on another channel (one finding per effect is applied):']
        lines += [f'#  - {f["effect"]} on {f["channel"]} ({_fmt(f.get("parameters", {}))}, '
                  f'confidence {f.get("confidence", 0):.2f})' for f in aside]
    minor = findings.get('minor_findings') or []
    if minor:
        lines += ['# Minor findings (significant, below the size worth naming; not applied):']
        lines += [f'#  - {f["effect"]} on {f["channel"]} ({_fmt(f.get("parameters", {}))})'
                  for f in minor]
    return '\n'.join(lines) + '\n'


def write(out: Path, findings: dict, sim_bag: Optional[str] = None) -> list:
    """Write ``sim_params.yaml`` and ``suggestions.yaml`` into ``out``; return their names."""
    (out / 'sim_params.yaml').write_text(sim_params_text(findings, sim_bag))
    from robot_calib.mismatch.suggestions import suggestions_text  # it reads this module

    (out / 'suggestions.yaml').write_text(suggestions_text(findings))
    return ['sim_params.yaml', 'suggestions.yaml']
