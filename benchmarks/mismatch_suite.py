# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Concealed-effect generator: pairs of a plain simulation and a "real" run with 0-2 effects.

A differential-drive robot follows random velocity commands (ramped with
acceleration limits; the published ``/cmd_vel`` is the ramped command) with a
first-order speed lag; terrain adds small deterministic vibrations shared by
both runs. The simulated recording has ``/imu`` (gyro, specific force with
gravity), ``/odom`` (twist) and ``/cmd_vel``; the "real" one is made from the
same continuous motion with concealed effects from the contract table
(random magnitudes from near the noise floor to typical low-cost sizes,
random windows) and its own noise (white or coloured), sometimes at another
rate or length. Trajectory kinds include hard ones: ``circle`` (one constant
turn: offset and scale look alike), ``straight`` (hardly any rotation),
``stop_go`` (many accelerations), ``gentle`` (slow).

``make_pair(seed)`` returns ``(sim, real, truth)`` as
:class:`robot_calib.mismatch.channels.Recording` objects; ``write_bag`` writes
a recording as a ROS 2 bag with :class:`robot_calib.io.bags.BagWriter`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robot_calib.core.constants import GRAVITY
from robot_calib.mismatch.channels import (IMU_FIELDS, IMU_TYPE, ODOM_FIELDS, ODOM_TYPE,
                                           Topic)
from robot_calib.mismatch.effects import tilt_rotate

EFFECTS = ('gyro_bias', 'gyro_scale', 'gyro_bias_drift', 'time_offset', 'accel_bias',
           'centripetal_acceleration', 'imu_mounting_tilt', 'wheel_radius_scale',
           'track_width_scale', 'wheel_slip')
WINDOWABLE = ('gyro_bias', 'gyro_scale', 'accel_bias', 'wheel_radius_scale',
              'track_width_scale', 'wheel_slip')
KINDS = ('mixed', 'mixed', 'mixed', 'circle', 'straight', 'stop_go', 'gentle')


@dataclass
class Motion:
    """The continuous motion on a fine base grid (s, m/s, rad/s, m/s^2)."""

    t: np.ndarray
    v: np.ndarray
    w: np.ndarray
    a: np.ndarray
    cmd_v: np.ndarray
    cmd_w: np.ndarray
    cmd_a: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    az_bump: np.ndarray


def _ramp(target: np.ndarray, dt: float, limit: float) -> np.ndarray:
    out = np.empty_like(target)
    x = 0.0
    for i, y in enumerate(target):
        x += float(np.clip(y - x, -limit * dt, limit * dt))
        out[i] = x
    return out


def _smooth_noise(rng: np.random.Generator, n: int, dt: float, tc: float) -> np.ndarray:
    """Return unit-variance first-order low-pass noise with time constant ``tc`` (s)."""
    a = np.exp(-dt / tc)
    e = rng.standard_normal(n) * np.sqrt(1 - a * a)
    from scipy.signal import lfilter
    return lfilter([1.0], [1.0, -a], e)


def make_motion(rng: np.random.Generator, kind: str, duration: float,
                dt: float = 0.0025) -> Motion:
    """Return a random motion of ``kind`` lasting ``duration`` s on a ``dt`` grid."""
    n = int(duration / dt) + 1
    t = np.arange(n) * dt
    tv = np.zeros(n)
    tw = np.zeros(n)
    i = int(rng.uniform(1.0, 4.0) / dt)  # start at rest
    if kind == 'circle':
        v0, w0 = rng.uniform(0.2, 0.6), rng.choice([-1, 1]) * rng.uniform(0.3, 1.0)
        tv[i:], tw[i:] = v0, w0
        i = n
    while i < n:
        seg = int(rng.uniform(2.0, 12.0 if kind != 'stop_go' else 5.0) / dt)
        u = rng.random()
        if kind == 'straight':
            v, w = (rng.uniform(-0.8, 0.8), rng.normal(0, 0.03)) if u < 0.8 else (0.0, 0.0)
        elif kind == 'gentle':
            v, w = rng.uniform(0, 0.3), rng.uniform(-0.2, 0.2)
        elif kind == 'stop_go':
            v, w = (rng.uniform(0.3, 1.0), rng.uniform(-0.5, 0.5)) if u < 0.6 else (0.0, 0.0)
        else:
            if u < 0.3:
                v, w = rng.uniform(0.2, 1.0), 0.0
            elif u < 0.6:
                v, w = rng.uniform(0.1, 0.8), rng.uniform(-1.2, 1.2)
            elif u < 0.8:
                v, w = 0.0, rng.choice([-1, 1]) * rng.uniform(0.3, 2.0)
            else:
                v, w = 0.0, 0.0
        tv[i:i + seg], tw[i:i + seg] = v, w
        i += seg
    amax = rng.uniform(0.3, 1.0)
    cmd_v = _ramp(tv, dt, amax)
    cmd_w = _ramp(tw, dt, rng.uniform(1.0, 3.0))
    cmd_a = np.gradient(cmd_v, dt)
    from scipy.signal import lfilter
    lag = rng.uniform(0.05, 0.2)
    al = dt / (lag + dt)
    v = lfilter([al], [1, -(1 - al)], cmd_v)
    w = lfilter([al], [1, -(1 - al)], cmd_w)
    a = np.gradient(v, dt)
    rough = rng.uniform(0.0, 1.0)
    speed = np.abs(v) + 0.3 * np.abs(w)
    gx = rough * 0.03 * _smooth_noise(rng, n, dt, 0.05) * speed
    gy = rough * 0.03 * _smooth_noise(rng, n, dt, 0.05) * speed
    az = rough * 0.3 * _smooth_noise(rng, n, dt, 0.03) * speed
    return Motion(t, v, w, a, cmd_v, cmd_w, cmd_a, gx, gy, az)


def _draw(rng: np.random.Generator, lo: float, hi: float, signed: bool = True) -> float:
    x = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    return x * (rng.choice([-1.0, 1.0]) if signed else 1.0)


def draw_effect(rng: np.random.Generator, name: str, duration: float) -> dict:
    """Return a random concealed effect: name, channel, parameters, window (s) or None."""
    axis = 'z' if rng.random() < 0.7 else str(rng.choice(['x', 'y']))
    p: dict = {}
    ch = ''
    if name == 'gyro_bias':
        p = {'bias': _draw(rng, 5e-4, 0.02)}
        ch = f'/imu.angular_velocity.{axis}'
    elif name == 'gyro_scale':
        p = {'scale': _draw(rng, 0.005, 0.05)}
        ch = '/imu.angular_velocity.z'
    elif name == 'gyro_bias_drift':
        p = {'bias': _draw(rng, 5e-4, 0.005), 'drift': _draw(rng, 0.003, 0.02) / duration}
        ch = f'/imu.angular_velocity.{axis}'
    elif name == 'time_offset':
        p = {'tau': _draw(rng, 0.005, 0.08)}
        ch = '/imu' if rng.random() < 0.6 else '/odom'
    elif name == 'accel_bias':
        p = {'bias': _draw(rng, 0.02, 0.3)}
        ch = f'/imu.linear_acceleration.{rng.choice(["x", "y", "z"])}'
    elif name == 'centripetal_acceleration':
        p = {'gain': float(rng.uniform(0.2, 1.0))}
        ch = '/imu.linear_acceleration.y'
    elif name == 'imu_mounting_tilt':
        p = {'roll': _draw(rng, 0.005, 0.05), 'pitch': _draw(rng, 0.005, 0.05)}
        ch = '/imu.linear_acceleration'
    elif name == 'wheel_radius_scale':
        p = {'scale': _draw(rng, 0.005, 0.05)}
        ch = '/odom.twist.twist.linear.x'
    elif name == 'track_width_scale':
        p = {'scale': _draw(rng, 0.01, 0.1)}
        ch = '/odom.twist.twist.angular.z'
    elif name == 'wheel_slip':
        p = {'coefficient': _draw(rng, 0.02, 0.3)}
        ch = '/odom.twist.twist.linear.x'
    window = None
    if name in WINDOWABLE and rng.random() < 0.35:
        t0 = rng.uniform(0.05, 0.55) * duration
        window = [float(t0), float(min(duration * 0.97, t0 + rng.uniform(0.15, 0.4) * duration))]
    return {'effect': name, 'channel': ch, 'parameters': p, 'window': window}


def _in(window, t: np.ndarray) -> np.ndarray:
    if window is None:
        return np.ones(t.size, bool)
    return (t >= window[0]) & (t <= window[1])


def _sample(m: Motion, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.interp(t, m.t, x)


def _imu(m: Motion, t: np.ndarray, centripetal: bool) -> dict:
    v, w, a = (_sample(m, t, x) for x in (m.v, m.w, m.a))
    f = dict(zip(IMU_FIELDS, (_sample(m, t, m.gx), _sample(m, t, m.gy), w, a,
                              v * w if centripetal else np.zeros_like(t),
                              GRAVITY + _sample(m, t, m.az_bump))))
    return f


def _odom(m: Motion, t: np.ndarray) -> dict:
    return dict(zip(ODOM_FIELDS, (_sample(m, t, m.v), _sample(m, t, m.w))))


def make_pair(seed: int, n_effects: int | None = None, duration: float | None = None,
              imu_rate: float | None = None, odom_rate: float | None = None,
              kind: str | None = None, noise: bool = True,
              effects: list | None = None) -> tuple[dict, dict, dict]:
    """
    Return ``(sim, real, truth)`` for one seeded pair.

    :param seed: random seed
    :param n_effects: number of concealed effects (0-2; random when None)
    :param duration: length (s; random 60-240 when None)
    :param imu_rate: IMU rate (Hz; random 100-200 when None)
    :param odom_rate: odometry rate (Hz; random 20-50 when None)
    :param kind: trajectory kind (random from :data:`KINDS` when None)
    :param noise: add sensor noise to the real run (and sometimes the simulated one)
    :param effects: explicit effects (dicts as :func:`draw_effect` returns) instead of drawn ones
    """
    rng = np.random.default_rng(seed)
    duration = float(duration or rng.uniform(60.0, 240.0))
    kind = kind or str(rng.choice(KINDS))
    imu_rate = float(imu_rate or rng.choice([100.0, 125.0, 200.0]))
    odom_rate = float(odom_rate or rng.choice([20.0, 30.0, 50.0]))
    m = make_motion(rng, kind, duration + 1.0)
    if effects is None:
        k = int(rng.choice([0, 1, 2])) if n_effects is None else int(n_effects)
        names = [str(x) for x in rng.choice(EFFECTS, size=k, replace=False)]
        if 'gyro_bias' in names and 'gyro_bias_drift' in names:
            names.remove('gyro_bias')
        effects = [draw_effect(rng, nm, duration) for nm in names]
    centripetal = bool(rng.random() < 0.5)
    t_imu = np.arange(0.0, duration, 1.0 / imu_rate)
    t_odom = np.arange(0.0, duration, 1.0 / odom_rate)
    t_cmd = np.arange(0.0, duration, 0.1)
    sim = {'/imu': Topic('/imu', IMU_TYPE, t_imu, _imu(m, t_imu, centripetal)),
           '/odom': Topic('/odom', ODOM_TYPE, t_odom, _odom(m, t_odom)),
           '/cmd_vel': Topic('/cmd_vel', 'geometry_msgs/msg/Twist', t_cmd,
                             {'linear.x': _sample(m, t_cmd, m.cmd_v),
                              'angular.z': _sample(m, t_cmd, m.cmd_w)})}
    # the real run: maybe another rate / length
    r_imu_rate = imu_rate if rng.random() < 0.8 else float(rng.choice([100.0, 200.0, 250.0]))
    r_len = duration if rng.random() < 0.8 else duration * rng.uniform(0.9, 1.0)
    tr_imu = np.arange(0.0, r_len, 1.0 / r_imu_rate)
    tr_odom = np.arange(0.0, r_len, 1.0 / odom_rate)
    tau_imu = sum(e['parameters']['tau'] for e in effects
                  if e['effect'] == 'time_offset' and e['channel'] == '/imu')
    tau_odom = sum(e['parameters']['tau'] for e in effects
                   if e['effect'] == 'time_offset' and e['channel'] == '/odom')
    ri = _imu(m, tr_imu - tau_imu, centripetal)
    ro = _odom(m, tr_odom - tau_odom)
    v_i = _sample(m, tr_imu, m.v)
    w_i = _sample(m, tr_imu, m.w)
    ri0, ro0 = _imu(m, tr_imu, centripetal), _odom(m, tr_odom)
    for e in effects:
        if e['effect'] == 'time_offset':
            a, b = (ri, ri0) if e['channel'] == '/imu' else (ro, ro0)
            e['energy'] = {k: float(np.sum((a[k] - b[k]) ** 2)) for k in a}
    for e in effects:
        before = {k: v.copy() for k, v in list(ri.items()) + list(ro.items())}
        p, win, name = e['parameters'], e['window'], e['effect']
        if name in ('gyro_bias', 'gyro_scale', 'gyro_bias_drift', 'accel_bias'):
            f = e['channel'].split('.', 1)[1]
            inw = _in(win, tr_imu)
            if name == 'gyro_scale':
                ri[f] = np.where(inw, ri[f] * (1 + p['scale']), ri[f])
            elif name == 'gyro_bias_drift':
                ri[f] = np.where(inw, ri[f] + p['bias'] + p['drift'] * tr_imu, ri[f])
            else:
                ri[f] = np.where(inw, ri[f] + p['bias'], ri[f])
        elif name == 'centripetal_acceleration':
            ri['linear_acceleration.y'] = ri['linear_acceleration.y'] + p['gain'] * v_i * w_i
        elif name == 'imu_mounting_tilt':
            fx, fy, fz = IMU_FIELDS[3:]
            ri[fx], ri[fy], ri[fz] = tilt_rotate(ri[fx], ri[fy], ri[fz], p['roll'], p['pitch'])
        elif name in ('wheel_radius_scale', 'wheel_slip', 'track_width_scale'):
            inw = _in(win, tr_odom)
            fv, fw = ODOM_FIELDS
            if name == 'wheel_radius_scale':
                ro[fv] = np.where(inw, ro[fv] * (1 + p['scale']), ro[fv])
            elif name == 'track_width_scale':
                ro[fw] = np.where(inw, ro[fw] / (1 + p['scale']), ro[fw])
            else:
                a = _sample(m, tr_odom, m.cmd_a)
                ro[fv] = np.where(inw, ro[fv] * (1 + p['coefficient'] * a), ro[fv])
        if name != 'time_offset':
            after = dict(list(ri.items()) + list(ro.items()))
            e['energy'] = {k: float(np.sum((after[k] - before[k]) ** 2)) for k in before
                           if np.any(after[k] != before[k])}
    noise_info = {}
    if noise:
        colored = rng.random() < 0.3
        sg, sa = _draw(rng, 0.001, 0.01, False), _draw(rng, 0.01, 0.1, False)
        sv, sw = _draw(rng, 0.002, 0.02, False), _draw(rng, 0.002, 0.02, False)
        tc = rng.uniform(0.01, 0.05)

        def nz(n: int, s: float, rate: float) -> np.ndarray:
            if colored:
                return s * _smooth_noise(rng, n, 1.0 / rate, tc)
            return s * rng.standard_normal(n)
        for i, f in enumerate(IMU_FIELDS):
            ri[f] = ri[f] + nz(tr_imu.size, sg if i < 3 else sa, r_imu_rate)
        ro[ODOM_FIELDS[0]] = ro[ODOM_FIELDS[0]] + nz(tr_odom.size, sv, odom_rate)
        ro[ODOM_FIELDS[1]] = ro[ODOM_FIELDS[1]] + nz(tr_odom.size, sw, odom_rate)
        sim_noise = rng.random() < 0.4
        if sim_noise:
            for i, f in enumerate(IMU_FIELDS):
                sim['/imu'].fields[f] = sim['/imu'].fields[f] + \
                    0.5 * (sg if i < 3 else sa) * rng.standard_normal(t_imu.size)
        noise_info = {'gyro': sg, 'accel': sa, 'speed': sv, 'yaw_rate': sw,
                      'colored': bool(colored), 'sim_noise': bool(sim_noise)}
    real = {'/imu': Topic('/imu', IMU_TYPE, tr_imu, ri),
            '/odom': Topic('/odom', ODOM_TYPE, tr_odom, ro),
            '/cmd_vel': sim['/cmd_vel']}
    truth = {'seed': seed, 'kind': kind, 'duration': duration, 'imu_rate': imu_rate,
             'real_imu_rate': r_imu_rate, 'odom_rate': odom_rate, 'effects': effects,
             'noise': noise_info, 'sim_centripetal': centripetal}
    return sim, real, truth


def write_bag(rec: dict, path, storage: str = 'mcap') -> None:
    """Write a recording (from :func:`make_pair`) as a ROS 2 bag folder at ``path``."""
    from robot_calib.core import types as T
    from robot_calib.io.bags import BagWriter
    items = []
    for name, tp in rec.items():
        f = tp.fields
        for i, t in enumerate(tp.t):
            if tp.msgtype == IMU_TYPE:
                s = T.ImuSample(float(t), np.array([f[k][i] for k in IMU_FIELDS[:3]]),
                                np.array([f[k][i] for k in IMU_FIELDS[3:]]))
            elif tp.msgtype == ODOM_TYPE:
                s = T.OdomSample(float(t), 0.0, 0.0, 0.0, vx=float(f[ODOM_FIELDS[0]][i]),
                                 wz=float(f[ODOM_FIELDS[1]][i]))
            else:
                s = T.TwistSample(float(t), float(f['linear.x'][i]), wz=float(f['angular.z'][i]))
            items.append((float(t), name, s))
    items.sort(key=lambda z: z[0])
    with BagWriter(path, storage=storage) as w:
        for t, name, s in items:
            w.write(name, s, int(round(t * 1e9)) + 1)
