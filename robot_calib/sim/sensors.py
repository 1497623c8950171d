# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Sensor models on the true internal-rate arrays: IMU, encoders, wheel odometry, lidar.

Each function takes the true arrays (from :mod:`robot_calib.sim.robot`), the
parameters, the sample times (s from the start) and its own random generator,
and returns arrays (one row per message). A message stamped ``t`` carries the
data of ``t - latency`` (linear interpolation of the internal-rate truth).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

import numpy as np

from robot_calib.core.scan_incidence import incidence
from robot_calib.sim.params import SimParams
from robot_calib.sim.robot import _rot_zyx, rotation_matrix, true_geometry


def sample_times(rate: float, duration: float) -> np.ndarray:
    """Return ``k / rate`` (s) for k = 0, 1, ... up to ``duration`` (s) inclusive."""
    n = int(math.floor(duration * rate + 1e-9)) + 1
    return np.arange(n) / rate


def interp(tr: dict[str, np.ndarray], key: str, times: np.ndarray) -> np.ndarray:
    """Return ``tr[key]`` (1-D or (N, k)) linearly interpolated at ``times`` (s)."""
    t = tr['t']
    values = tr[key]
    if values.ndim == 1:
        return np.interp(times, t, values)
    return np.column_stack([np.interp(times, t, values[:, j]) for j in range(values.shape[1])])


def imu_mount(p: SimParams) -> np.ndarray:
    """Return R_bi: the rotation of imu_link in base_link (3x3)."""
    return rotation_matrix(p.imu.roll, p.imu.pitch, p.imu.yaw)


def true_gyro_bias(p: SimParams, rng_bias: np.random.Generator) -> np.ndarray:
    """Return the constant gyro bias (rad/s, imu_link): gyro_bias plus the per-seed draw."""
    bias = np.asarray(p.imu.gyro_bias, dtype=float)
    draw = rng_bias.normal(0.0, 1.0, 3) * p.imu.gyro_bias_sigma
    return bias + draw


def imu(tr: dict[str, np.ndarray], p: SimParams, times: np.ndarray, rng: np.random.Generator,
        gyro_bias: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """
    Return gyro (N, 3) rad/s, accel (N, 3) m/s^2 in imu_link and the true bias series.

    gyro = (1 + scale) R_bi^T w_b + b0 + drift t + warmup exp(-t / tau) + rw(t) + n,
    accel = (1 + scale) R_bi^T f_b + b + rw(t) + n, with white noise of density
    ``*_noise`` (sigma = density sqrt(rate)) and bias random walks of density
    ``*_random_walk`` (step sigma = density / sqrt(rate)).
    """
    q = p.imu
    rate = q.rate
    tm = np.maximum(times - p.latency.imu, 0.0)
    rbi = imu_mount(p)
    w_b = interp(tr, 'gyro_body', tm)
    f_b = interp(tr, 'accel_body', tm)
    w_i = w_b @ rbi  # R_bi^T w for row vectors
    f_i = f_b @ rbi
    n = times.size
    noise = rng.standard_normal((n, 12))
    bias = (gyro_bias[None, :] + np.asarray(q.gyro_bias_drift)[None, :] * times[:, None]
            + np.asarray(q.gyro_warmup)[None, :] * np.exp(-times / q.gyro_warmup_tau)[:, None])
    if q.gyro_random_walk > 0:
        bias = bias + np.cumsum(noise[:, 6:9] * q.gyro_random_walk / math.sqrt(rate), axis=0)
    accel_bias = np.asarray(q.accel_bias, dtype=float)[None, :] + np.zeros((n, 1))
    if q.accel_random_walk > 0:
        accel_bias = accel_bias + np.cumsum(noise[:, 9:12] * q.accel_random_walk
                                            / math.sqrt(rate), axis=0)
    gyro = (1.0 + np.asarray(q.gyro_scale))[None, :] * w_i + bias
    accel = (1.0 + np.asarray(q.accel_scale))[None, :] * f_i + accel_bias
    if q.gyro_noise > 0:
        gyro = gyro + noise[:, 0:3] * q.gyro_noise * math.sqrt(rate)
    if q.accel_noise > 0:
        accel = accel + noise[:, 3:6] * q.accel_noise * math.sqrt(rate)
    return gyro, accel, {'gyro_bias': bias, 'accel_bias': accel_bias, 'gyro_true': w_i,
                         'accel_true': f_i}


def encoders(tr: dict[str, np.ndarray], p: SimParams, times: np.ndarray,
             rng: np.random.Generator,
             latency: Optional[float] = None) -> tuple[np.ndarray, np.ndarray]:
    """
    Return joint positions and velocities (N, 2) at ``times`` (s), latency included.

    ``latency`` (s) defaults to ``latency.joint_states`` (odometry passes its own).

    Differential drive: (left, right) wheel angle (rad) and rate (rad/s).
    Steered wheel: (steering reading rad, traction angle rad) and their rates.
    Positions are quantised to ``2 pi / encoder_ticks``.
    """
    lat = p.latency.joint_states if latency is None else latency
    tm = np.maximum(times - lat, 0.0)
    w = p.wheels
    pos = np.column_stack((np.interp(tm, tr['t'], tr['angle1']),
                           np.interp(tm, tr['t'], tr['angle2'])))
    vel = np.column_stack((np.interp(tm, tr['t'], tr['rate1']),
                           np.interp(tm, tr['t'], tr['rate2'])))
    noise = rng.standard_normal((times.size, 3))
    steered = p.robot.drive_type == 'steered_wheel'
    quant = 2.0 * math.pi / w.encoder_ticks if w.encoder_ticks > 0 else 0.0
    if steered:
        if w.steering_noise > 0:
            pos[:, 0] = pos[:, 0] + noise[:, 2] * w.steering_noise
        vel[:, 0] = np.gradient(pos[:, 0], times) if times.size > 1 else 0.0
        if quant:
            pos[:, 1] = np.round(pos[:, 1] / quant) * quant
    elif quant:
        pos = np.round(pos / quant) * quant
    if w.velocity_noise > 0:
        if steered:
            vel[:, 1] = vel[:, 1] + noise[:, 1] * w.velocity_noise
        else:
            vel = vel + noise[:, :2] * w.velocity_noise
    return pos, vel


def wheel_odometry(p: SimParams, times: np.ndarray, pos: np.ndarray) -> dict[str, np.ndarray]:
    """
    Integrate odometry from encoder positions (N, 2) with the NOMINAL geometry.

    Differential: ds = r (dR + dL) / 2, dyaw = r (dR - dL) / T; steered wheel:
    ds = r dTraction cos(delta), dyaw = r dTraction sin(delta) / L with delta the
    mean steering reading of the interval (no offset correction: the robot
    does not know it). Midpoint heading for x, y. Starts at (0, 0, 0).
    """
    r = p.robot
    d = np.diff(pos, axis=0)
    if r.drive_type == 'steered_wheel':
        delta = 0.5 * (pos[1:, 0] + pos[:-1, 0])
        g = d[:, 1] * r.wheel_radius
        ds = g * np.cos(delta)
        dyaw = g * np.sin(delta) / r.wheel_base
    else:
        ds = 0.5 * r.wheel_radius * (d[:, 0] + d[:, 1])
        dyaw = r.wheel_radius * (d[:, 1] - d[:, 0]) / r.track_width
    yaw = np.concatenate(([0.0], np.cumsum(dyaw)))
    mid = yaw[:-1] + 0.5 * dyaw
    x = np.concatenate(([0.0], np.cumsum(ds * np.cos(mid))))
    y = np.concatenate(([0.0], np.cumsum(ds * np.sin(mid))))
    dts = np.diff(times)
    vx = np.concatenate(([0.0], ds / dts))
    wz = np.concatenate(([0.0], dyaw / dts))
    return {'x': x, 'y': y, 'yaw': yaw, 'vx': vx, 'wz': wz}


def lidar_geometry(p: SimParams) -> tuple[float, float, float]:
    """Return (angle_min, angle_increment, time_increment) of the scans (rad, rad, s)."""
    li = p.lidar
    full = li.fov >= 2 * math.pi - 1e-9
    if full:
        inc = 2 * math.pi / li.beams
        amin = -math.pi
    else:
        inc = li.fov / max(li.beams - 1, 1)
        amin = -0.5 * li.fov
    tinc = (1.0 / li.rate) / li.beams if li.motion_distortion else 0.0
    return amin, inc, tinc


def lidar_true_mount(li: Any) -> Any:
    """Return the lidar parameters with the TRUE mounting (nominal + ``*_error``)."""
    if li.x_error == 0.0 and li.y_error == 0.0 and li.yaw_error == 0.0:
        return li
    return dataclasses.replace(li, x=li.x + li.x_error, y=li.y + li.y_error,
                               yaw=li.yaw + li.yaw_error)


def lidar(tr: dict[str, np.ndarray], p: SimParams, world: Any, times: np.ndarray,
          rng: np.random.Generator) -> np.ndarray:
    """
    Return ranges (S, beams) (m) of scans stamped ``times`` (s), REP-117 invalid values.

    Beam i of a scan is cast from the TRUE laser pose (nominal mounting plus
    ``x_error``, ``y_error``, ``yaw_error``) at ``t - latency - time_offset + i *
    time_increment`` (world frame, interpolated); the range is then
    ``(1 + range_scale) r + range_bias`` plus Gaussian noise of sigma ``noise +
    noise_growth r`` (r the true range), and then: below ``range_min`` -> -inf,
    no return within ``range_max`` -> +inf (or NaN), dropouts -> NaN, lost
    returns beyond ``dropout_beyond`` or at an incidence above
    ``dropout_incidence`` -> the no-return value. When the robot is tilted
    (terrain, tip-over) the scan plane tilts with it: walls (vertical) are hit
    along the beam's horizontal projection at the 3D range, and beams pointing
    down hit the floor (terrain height under the laser).
    """
    li = lidar_true_mount(p.lidar)
    amin, inc, tinc = lidar_geometry(p)
    beams = li.beams
    lag = p.latency.scan + li.time_offset if li.time_offset != 0.0 else p.latency.scan
    bt = (np.maximum(times - lag, 0.0)[:, None] + tinc * np.arange(beams)[None, :])
    x = np.interp(bt, tr['t'], tr['x'])
    y = np.interp(bt, tr['t'], tr['y'])
    yaw = np.interp(bt, tr['t'], tr['yaw'])
    c, s = np.cos(yaw), np.sin(yaw)
    ox = x + c * li.x - s * li.y
    oy = y + s * li.x + c * li.y
    if li.upside_down:  # the laser's angle a points along -a in base_link
        ang = yaw + li.yaw - amin - inc * np.arange(beams)[None, :]
    else:
        ang = yaw + li.yaw + amin + inc * np.arange(beams)[None, :]
    tilted = bool(np.any(tr['roll'] != 0.0) or np.any(tr['pitch'] != 0.0))
    if not tilted:
        ranges = world.raycast_fan(ox, oy, ang)
    else:
        ranges = _tilted_ranges(tr, li, world, bt, yaw, ang - yaw)
    noise = rng.standard_normal(ranges.shape)
    drop = rng.random(ranges.shape)
    hit = np.isfinite(ranges)
    true_r = ranges
    if li.range_scale != 0.0 or li.range_bias != 0.0:
        ranges = np.where(hit, (1.0 + li.range_scale) * ranges + li.range_bias, ranges)
    if li.noise_growth != 0.0:
        sigma = li.noise + li.noise_growth * np.where(hit, true_r, 0.0)
        ranges = np.where(hit, ranges + noise * sigma, ranges)
    else:
        ranges = np.where(hit, ranges + noise * li.noise, ranges)
    no_return = math.inf if li.no_return == 'inf' else math.nan
    ranges[hit & (ranges > li.range_max)] = no_return
    ranges[~hit] = no_return
    ranges[hit & (ranges < li.range_min)] = -math.inf
    if li.dropout > 0:
        ranges[drop < li.dropout] = math.nan
    lost = _lost_returns(li, true_r, ang, rng)
    if lost is not None:
        ranges[lost & hit] = no_return
    return ranges


def _lost_returns(li: Any, true_r: np.ndarray, ang: np.ndarray,
                  rng: np.random.Generator) -> Optional[np.ndarray]:
    """Return the beams (S, B bool) lost by range or incidence, None when both are off."""
    if li.dropout_beyond <= 0.0 and li.dropout_incidence <= 0.0:
        return None
    u = rng.random(true_r.shape)  # drawn after the other streams' numbers: they keep theirs
    lost = np.zeros(true_r.shape, dtype=bool)
    with np.errstate(invalid='ignore'):
        if li.dropout_beyond > 0.0:
            lost |= (true_r > li.dropout_beyond) & (u < li.dropout_beyond_rate)
        if li.dropout_incidence > 0.0:
            lost |= (incidence(true_r, ang) > li.dropout_incidence) & \
                (u < li.dropout_incidence_rate)
    return lost


def lidar_effects(p: SimParams) -> dict[str, Any]:
    """
    Return the truth of the lidar effects, keyed by the contract's effect names (SI).

    ``nominal`` is what ``/tf_static`` says, ``true`` the mounting the scans were
    drawn from; ``lidar_time_offset.tau`` is the whole lag of the stamps behind
    the sweep start (``latency.scan + time_offset``); ``scan_distortion``
    gives the sweep time (0 when deskewed, i.e. ``motion_distortion`` off).
    """
    li = p.lidar
    sweep = (1.0 / li.rate) if li.motion_distortion else 0.0
    return {
        'lidar_mounting_yaw': {'yaw': li.yaw_error, 'nominal': li.yaw,
                               'true': li.yaw + li.yaw_error},
        'lidar_mounting_offset': {'x': li.x_error, 'y': li.y_error,
                                  'nominal': [li.x, li.y], 'true': [li.x + li.x_error,
                                                                    li.y + li.y_error]},
        'lidar_time_offset': {'tau': p.latency.scan + li.time_offset},
        'scan_distortion': {'sweep_time': sweep, 'deskewed': not li.motion_distortion},
        'range_bias': {'bias': li.range_bias},
        'range_scale': {'scale': li.range_scale},
        'range_noise_growth': {'s0': li.noise, 's1': li.noise_growth},
        'dropout_rate': {'rate': li.dropout, 'beyond': li.dropout_beyond,
                         'beyond_rate': li.dropout_beyond_rate if li.dropout_beyond > 0 else 0.0,
                         'incidence': li.dropout_incidence,
                         'incidence_rate': (li.dropout_incidence_rate
                                            if li.dropout_incidence > 0 else 0.0)},
    }


def _tilted_ranges(tr: dict[str, np.ndarray], li: Any, world: Any, bt: np.ndarray,
                   yaw: np.ndarray, beam_b: np.ndarray) -> np.ndarray:
    """Return 3D ranges (m) of beams at angles ``beam_b`` (rad, in base_link) of a tilted robot."""
    roll = np.interp(bt, tr['t'], tr['roll'])
    pitch = np.interp(bt, tr['t'], tr['pitch'])
    rot = _rot_zyx(roll, pitch, yaw)
    pos = [np.interp(bt, tr['t'], tr[k]) for k in ('x', 'y', 'z')]
    lever = np.array([li.x, li.y, li.z])
    origin = [pos[k] + rot[..., k, :] @ lever for k in range(3)]
    cb, sb = np.cos(beam_b), np.sin(beam_b)
    d = [rot[..., k, 0] * cb + rot[..., k, 1] * sb for k in range(3)]
    horiz = np.hypot(d[0], d[1])
    with np.errstate(divide='ignore', invalid='ignore'):
        wall = world.raycast_fan(origin[0], origin[1], np.arctan2(d[1], d[0])) / horiz
        ground = world.height(origin[0], origin[1]) if world.terrain else 0.0
        floor = np.where(d[2] < -1e-9, (origin[2] - ground) / -d[2], np.inf)
    floor = np.where(floor > 0, floor, np.inf)
    out = np.minimum(np.where(np.isfinite(wall) & (wall > 0), wall, np.inf), floor)
    return out


def truth_values(p: SimParams, gyro_bias: np.ndarray) -> dict[str, Any]:
    """Return the true parameter values (SI) for ``truth.json``."""
    geo = true_geometry(p)
    steered = p.robot.drive_type == 'steered_wheel'
    out: dict[str, Any] = {
        'drive_type': 'steered_wheel' if steered else 'differential',
        'wheel_radius': geo['wheel_radius'],
        'left_wheel_radius': geo['left_wheel_radius'],
        'right_wheel_radius': geo['right_wheel_radius'],
        'track_width': geo['track_width'],
        'wheel_base': geo['wheel_base'],
        'steering_offset': geo['steering_offset'] if steered else 0.0,
        'steering_scale': geo['steering_scale'] if steered else 1.0,
        'nominal': {'wheel_radius': p.robot.wheel_radius, 'track_width': p.robot.track_width,
                    'wheel_base': p.robot.wheel_base},
        'gyro_bias': [float(v) for v in gyro_bias],
        'gyro_bias_z': float(gyro_bias[2]),
        'gyro_bias_drift': list(map(float, p.imu.gyro_bias_drift)),
        'gyro_warmup': list(map(float, p.imu.gyro_warmup)),
        'gyro_warmup_tau': p.imu.gyro_warmup_tau,
        'gyro_scale': list(map(float, p.imu.gyro_scale)),
        'gyro_noise': p.imu.gyro_noise,
        'gyro_random_walk': p.imu.gyro_random_walk,
        'accel_bias': list(map(float, p.imu.accel_bias)),
        'accel_scale': list(map(float, p.imu.accel_scale)),
        'accel_noise': p.imu.accel_noise,
        'accel_random_walk': p.imu.accel_random_walk,
        'centripetal': p.imu.centripetal,
        'imu_roll': p.imu.roll, 'imu_pitch': p.imu.pitch, 'imu_yaw': p.imu.yaw,
        'imu_x': p.imu.x, 'imu_y': p.imu.y, 'imu_z': p.imu.z,
        'lidar_x': p.lidar.x + p.lidar.x_error, 'lidar_y': p.lidar.y + p.lidar.y_error,
        'lidar_z': p.lidar.z, 'lidar_yaw': p.lidar.yaw + p.lidar.yaw_error,
        'lidar_effects': lidar_effects(p),
        'slip_ratio': p.wheels.slip_ratio,
        'slip_coefficient': p.wheels.slip_coefficient,
        'slip_episodes': [list(map(float, e)) for e in
                          np.asarray(p.wheels.slip_episodes, float).reshape(-1, 4)],
        'latency': {'imu': p.latency.imu, 'odom': p.latency.odom,
                    'joint_states': p.latency.joint_states, 'scan': p.latency.scan},
        'rates': {'internal': p.rate, 'imu': p.imu.rate, 'scan': p.lidar.rate,
                  'odom': p.odom.rate, 'joint_states': p.odom.joint_states_rate,
                  'ground_truth': p.odom.ground_truth_rate, 'cmd_vel': p.odom.cmd_vel_rate},
    }
    return out
