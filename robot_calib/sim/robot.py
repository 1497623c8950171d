# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Robot models: wheel actuators, true planar kinematics, and the 3D attitude on terrain.

:class:`Plant` turns control-rate commands into the TRUE state at the internal
rate (``SimParams.rate``), in vectorised chunks (a whole open-loop stretch at
once, or one control tick for closed-loop steps):

1. commands -> actuator targets with the NOMINAL geometry (as the robot's own
   base controller does): differential drive wheel speeds
   ``wL = (v - w T/2) / r``, ``wR = (v + w T/2) / r``; steered wheel
   ``delta = atan2(w L, v)``, traction speed ``hypot(v, w L) / r``;
2. first-order lag of the actuators (exact per control tick); with drive
   dynamics (``drive.*``, :mod:`robot_calib.sim.drive`) the commanded twist
   first goes through them at the internal rate, and the actuators follow the
   result sample by sample;
3. TRUE wheel geometry and slip -> body twist: differential
   ``v = (gL + gR) / 2``, ``w = (gR - gL) / T_true``; steered wheel
   ``v = g cos(delta_true)``, ``w = g sin(delta_true) / L_true`` with
   ``delta_true = reading * steering_scale + steering_offset``, where ``g`` is
   the wheel ground speed ``rim * (1 - slip) / (1 + c a)``;
4. trapezoidal integration of the pose.

:func:`attitude` then adds the third dimension: the height, roll and pitch
from the terrain under the wheel contacts (left/right wheel, front wheel or
caster at ``wheel_base``), tip-over events, the body rates
(from the ZYX Euler rates) and the specific force at the IMU point
(``R^T (a - g)``, ``a`` from the twice-differentiated IMU position, so lever
arm, centripetal and tangential terms are all included). The planar motion is
the horizontal projection (slopes do not slow the robot down).
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from robot_calib.sim.motion import State
from robot_calib.sim.params import SimParams


class PlantError(ValueError):
    """A command that the robot type cannot execute."""


def true_geometry(p: SimParams) -> dict[str, float]:
    """Return the TRUE geometry (m, rad) from the nominal values and the errors."""
    r = p.robot
    w = p.wheels
    return {
        'left_wheel_radius': r.wheel_radius * (1.0 + w.left_radius_error),
        'right_wheel_radius': r.wheel_radius * (1.0 + w.right_radius_error),
        'wheel_radius': r.wheel_radius * (1.0 + w.radius_error) if
        r.drive_type == 'steered_wheel' else
        r.wheel_radius * (1.0 + 0.5 * (w.left_radius_error + w.right_radius_error)),
        'track_width': r.track_width * (1.0 + w.track_width_error),
        'wheel_base': r.wheel_base * (1.0 + w.wheel_base_error),
        'steering_offset': w.steering_offset,
        'steering_scale': w.steering_scale,
    }


class Plant:
    """
    Integrate the true robot state chunk by chunk (see the module docstring).

    :param params: the simulator parameters
    :param start: start pose (x m, y m, yaw rad) in the world
    :param n_sub: internal samples per control tick
    """

    def __init__(self, params: SimParams, start, n_sub: int, world: Any = None):
        """Set up the state at rest at ``start``."""
        self.p = params
        self.world = world
        self.n_sub = int(n_sub)
        self.dt = 1.0 / (params.rate)
        self.steered = params.robot.drive_type == 'steered_wheel'
        self.geo = true_geometry(params)
        tau = params.robot.wheel_time_constant
        tau_s = params.robot.steering_time_constant
        self.a = np.array([math.exp(-self.dt / tau_s) if self.steered and tau_s > 0 else
                           (math.exp(-self.dt / tau) if tau > 0 else 0.0),
                           math.exp(-self.dt / tau) if tau > 0 else 0.0])
        self.pw = self.a[None, :] ** np.arange(self.n_sub)[:, None]  # (n_sub, 2)
        self.big_a = self.a ** self.n_sub
        eps = np.asarray(params.wheels.slip_episodes, dtype=float)
        if eps.size % 4:
            raise PlantError('wheels.slip_episodes must hold groups of 4 numbers '
                             '[t0, t1, left, right]')
        self.episodes = eps.reshape(-1, 4)
        self.act = np.zeros(2)  # lagged actuators at the last sample
        x0, y0, yaw0 = (float(v) for v in start)
        self.last = np.array([x0, y0, yaw0, 0.0, 0.0, 0.0, 0.0])  # x y yaw v w angL angR
        self.last_rim = np.zeros(2)
        self.last_act = np.zeros(2)
        self.ticks = 0
        self.chunks: list[dict[str, np.ndarray]] = []
        self.cmd_chunks: list[np.ndarray] = []
        self.drive = None
        if params.drive.active():
            from robot_calib.sim.drive import DriveDynamics
            self.drive = DriveDynamics(params.drive, self.dt, params.robot.track_width,
                                       params.robot.wheel_radius)

    # -- commands ------------------------------------------------------------------------
    def targets(self, kind: str, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return actuator set-points (K, 2) and the equivalent twist (K, 2) of commands."""
        r = self.p.robot
        values = np.asarray(values, dtype=float).reshape(-1, 2)
        rad = r.wheel_radius
        if kind == 'twist':
            v, w = values[:, 0], values[:, 1]
            if self.steered:
                wl = w * r.wheel_base
                back = v < 0
                delta = np.where(back, np.arctan2(-wl, -v), np.arctan2(wl, v))
                speed = np.where(back, -1.0, 1.0) * np.hypot(v, wl) / rad
                lim = r.max_steering_angle
                return np.column_stack((np.clip(delta, -lim, lim), speed)), values
            half = 0.5 * w * r.track_width
            return np.column_stack(((v - half) / rad, (v + half) / rad)), values
        if kind == 'steer':
            if not self.steered:
                raise PlantError('steer() needs robot.drive_type steered_wheel')
            lim = r.max_steering_angle
            tgt = np.column_stack((np.clip(values[:, 0], -lim, lim), values[:, 1] / rad))
        elif kind == 'wheels':
            tgt = values.copy()
        else:
            raise PlantError(f'unknown command kind {kind!r}')
        return tgt, self.nominal_twist(tgt)

    def nominal_twist(self, tgt: np.ndarray) -> np.ndarray:
        """Return the twist (v m/s, w rad/s) the nominal geometry predicts for targets."""
        r = self.p.robot
        if self.steered:
            g = tgt[:, 1] * r.wheel_radius
            return np.column_stack((g * np.cos(tgt[:, 0]), g * np.sin(tgt[:, 0]) / r.wheel_base))
        gl, gr = tgt[:, 0] * r.wheel_radius, tgt[:, 1] * r.wheel_radius
        return np.column_stack((0.5 * (gl + gr), (gr - gl) / r.track_width))

    # -- integration ---------------------------------------------------------------------
    def advance(self, kind: str, values: np.ndarray) -> None:
        """Apply K control ticks of commands ``values`` (K, 2) of ``kind``."""
        tgt, twist = self.targets(kind, values)
        k = tgt.shape[0]
        if k == 0:
            return
        n = self.n_sub
        if self.drive is not None:
            self._advance_dynamic(twist, k)
            return
        # actuator lag, exact for a held target: y = u + (y0 - u) a^k (per tick)
        ends = np.empty_like(tgt)
        starts = np.empty_like(tgt)
        for j in range(2):
            big = float(self.big_a[j])
            e = float(self.act[j])
            col = tgt[:, j].tolist()
            out = ends[:, j]
            for i in range(k):
                e = col[i] + (e - col[i]) * big
                out[i] = e
            starts[0, j] = self.act[j]
            starts[1:, j] = ends[:-1, j]
        act = (tgt[:, None, :] + (starts - tgt)[:, None, :] * self.pw[None, :, :]).reshape(-1, 2)
        self.act = ends[-1].copy()
        t = (self.ticks * n + np.arange(k * n)) / self.p.rate
        self._integrate(t, act)
        self.cmd_chunks.append(np.column_stack(((self.ticks + np.arange(k)) * n / self.p.rate,
                                                twist)))
        self.ticks += k

    def _advance_dynamic(self, twist: np.ndarray, k: int) -> None:
        """Apply K ticks of commanded twists (K, 2) through the drive dynamics (per sample)."""
        from scipy.signal import lfilter
        n = self.n_sub
        realised = self.drive(np.repeat(twist, n, axis=0))
        tgt, _ = self.targets('twist', realised)
        act = np.empty_like(tgt)
        for j in range(2):
            a = float(self.a[j])
            y0 = float(self.act[j])
            # y[i + 1] = a y[i] + (1 - a) u[i]: the held-target form of advance(), per sample
            yf, _ = lfilter([1.0 - a], [1.0, -a], tgt[:, j], zi=[a * y0])
            act[0, j] = y0
            act[1:, j] = yf[:-1]
            self.act[j] = yf[-1]
        t = (self.ticks * n + np.arange(k * n)) / self.p.rate
        self._integrate(t, act)
        self.cmd_chunks.append(np.column_stack(((self.ticks + np.arange(k)) * n / self.p.rate,
                                                twist)))
        self.ticks += k

    def _slip_factors(self, t: np.ndarray, rim: np.ndarray) -> np.ndarray:
        """Return ground / rim speed factors (N, 2) for rim speeds (N, 2) (m/s)."""
        w = self.p.wheels
        prev = np.vstack((self.last_rim[None, :], rim[:-1]))
        acc = (rim - prev) / self.dt
        fac = np.full(rim.shape, 1.0 - w.slip_ratio)
        if w.slip_coefficient != 0.0:
            # mismatch table 'wheel_slip': rim speed = ground speed (1 + c a)
            fac = fac / np.maximum(1.0 + w.slip_coefficient * acc, 0.1)
        for t0, t1, left, right in self.episodes:
            m = (t >= t0) & (t < t1)
            if np.any(m):
                if self.steered:
                    fac[m] *= 1.0 - 0.5 * (left + right)
                else:
                    fac[m, 0] *= 1.0 - left
                    fac[m, 1] *= 1.0 - right
        return fac

    def _integrate(self, t: np.ndarray, act: np.ndarray) -> None:
        g = self.geo
        dt = self.dt
        if self.steered:
            rim = np.column_stack((act[:, 1], act[:, 1])) * g['wheel_radius']
            ground = rim * self._slip_factors(t, rim)
            delta = act[:, 0] * g['steering_scale'] + g['steering_offset']
            v = ground[:, 0] * np.cos(delta)
            w = ground[:, 0] * np.sin(delta) / g['wheel_base']
            wheel_rate = np.column_stack((np.zeros(len(t)), act[:, 1]))
        else:
            rim = act * np.array([g['left_wheel_radius'], g['right_wheel_radius']])
            ground = rim * self._slip_factors(t, rim)
            v = 0.5 * (ground[:, 0] + ground[:, 1])
            w = (ground[:, 1] - ground[:, 0]) / g['track_width']
            delta = np.zeros(len(t))
            wheel_rate = act
        x0, y0, yaw0, v0, w0, al0, ar0 = self.last
        # trapezoidal integration from the previous sample
        vprev = np.concatenate(([v0], v[:-1]))
        wprev = np.concatenate(([w0], w[:-1]))
        yaw = yaw0 + np.cumsum(0.5 * (wprev + w) * dt)
        yawprev = np.concatenate(([yaw0], yaw[:-1]))
        ds = 0.5 * (vprev + v) * dt
        ym = 0.5 * (yawprev + yaw)
        x = x0 + np.cumsum(ds * np.cos(ym))
        y = y0 + np.cumsum(ds * np.sin(ym))
        rprev = np.vstack((self.last_act[None, :], wheel_rate[:-1]))
        ang = np.array([al0, ar0]) + np.cumsum(0.5 * (rprev + wheel_rate) * dt, axis=0)
        if self.steered:
            ang[:, 0] = act[:, 0]
        self.last = np.array([x[-1], y[-1], yaw[-1], v[-1], w[-1], ang[-1, 0], ang[-1, 1]])
        self.last_rim = rim[-1].copy()
        self.last_act = wheel_rate[-1].copy()
        self.chunks.append({'t': t, 'x': x, 'y': y, 'yaw': yaw, 'v': v, 'w': w,
                            'act1': act[:, 0], 'act2': act[:, 1], 'delta': delta,
                            'angle1': ang[:, 0], 'angle2': ang[:, 1],
                            'rate1': wheel_rate[:, 0], 'rate2': wheel_rate[:, 1]})

    def state(self) -> State:
        """Return the true state after the last integrated sample."""
        x, y, yaw, v, w = self.last[:5]
        return State(self.ticks * self.n_sub * self.dt, float(x), float(y), float(yaw),
                     float(v), float(w), self.world)

    def arrays(self) -> dict[str, np.ndarray]:
        """Return the concatenated internal-rate arrays and the control-rate commands."""
        out = {key: np.concatenate([c[key] for c in self.chunks]) for key in self.chunks[0]}
        cmd = np.vstack(self.cmd_chunks)
        out['cmd_t'], out['cmd_v'], out['cmd_w'] = cmd[:, 0], cmd[:, 1], cmd[:, 2]
        return out


def _rot_zyx(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Return (N, 3, 3) rotation matrices R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    r = np.empty(roll.shape + (3, 3))
    r[..., 0, 0] = cy * cp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 0] = sy * cp
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 0] = -sp
    r[..., 2, 1] = cp * sr
    r[..., 2, 2] = cp * cr
    return r


def rotation_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Return the 3x3 rotation R = Rz(yaw) Ry(pitch) Rx(roll) (rad)."""
    return _rot_zyx(np.array(roll), np.array(pitch), np.array(yaw))


def attitude(arr: dict[str, np.ndarray], params: SimParams, world: Any,
             tips: Optional[list] = None) -> dict[str, np.ndarray]:
    """
    Add z, roll, pitch, body rates and the specific force at the IMU to the true arrays.

    Adds ``z``, ``roll``, ``pitch`` (m, rad), ``gyro_body`` (N, 3) rad/s in
    base_link, ``accel_body`` (N, 3) m/s^2 specific force at the IMU point in
    base_link axes, ``vz`` (m/s) and ``tipped`` (bool, after a tip-over start).
    """
    dt = 1.0 / params.rate
    t, x, y, yaw = arr['t'], arr['x'], arr['y'], arr['yaw']
    n = t.size
    r = params.robot
    half = 0.5 * r.track_width
    roll = np.zeros(n)
    pitch = np.zeros(n)
    z = np.zeros(n)
    if world is not None and world.terrain:
        c, s = np.cos(yaw), np.sin(yaw)
        zl = world.height(x - s * half, y + c * half)
        zr = world.height(x + s * half, y - c * half)
        zf = world.height(x + c * r.wheel_base, y + s * r.wheel_base)
        z = 0.5 * (zl + zr)
        roll = np.arctan2(zl - zr, 2 * half)  # left side high -> positive roll (REP-103)
        pitch = -np.arctan2(zf - z, r.wheel_base)  # nose up is negative pitch (REP-103)
    tipped = np.zeros(n, dtype=bool)
    pos = np.column_stack((x, y, z))
    for tip in tips or []:
        i0 = int(np.searchsorted(t, tip.t))
        if i0 >= n:
            continue
        tipped[i0:] = True
        for key in ('x', 'y', 'yaw'):
            arr[key][i0:] = arr[key][i0]
        for key in ('v', 'w'):
            arr[key][i0:] = 0.0
        extra = tip.profile(t[i0:] - t[i0])
        if tip.axis == 'roll':
            pivot_b = np.array([0.0, -half * tip.direction, 0.0])
            roll0, pitch0 = roll[i0] + extra, np.full(extra.size, pitch[i0])
        else:
            lever = r.wheel_base if tip.direction > 0 else 0.5 * r.track_width
            pivot_b = np.array([lever * tip.direction, 0.0, 0.0])
            roll0, pitch0 = np.full(extra.size, roll[i0]), pitch[i0] + extra
        yaw0 = np.full(extra.size, yaw[i0])
        rot0 = rotation_matrix(roll[i0], pitch[i0], yaw[i0])
        pivot_w = pos[i0] + rot0 @ pivot_b
        rots = _rot_zyx(roll0, pitch0, yaw0)
        pos[i0:] = pivot_w - rots @ pivot_b
        roll[i0:], pitch[i0:] = roll0, pitch0
    yaw = arr['yaw']
    rot = _rot_zyx(roll, pitch, yaw)
    droll = np.gradient(roll, dt) if n > 1 else np.zeros(n)
    dpitch = np.gradient(pitch, dt) if n > 1 else np.zeros(n)
    dyaw = arr['w']
    # ZYX Euler rates -> body rates (Diebel 2006, eq. 2.7 / any rigid-body text)
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    gyro = np.column_stack((droll - dyaw * sp,
                            dpitch * cr + dyaw * cp * sr,
                            -dpitch * sr + dyaw * cp * cr))
    lever = np.array([params.imu.x, params.imu.y, params.imu.z])
    p_imu = pos + rot @ lever
    if n > 2:
        vel = np.gradient(p_imu, dt, axis=0)
        acc = np.gradient(vel, dt, axis=0)
    else:
        acc = np.zeros((n, 3))
    g_w = np.array([0.0, 0.0, -params.imu.gravity])
    # specific force f = R^T (a - g) (accelerometer at rest, level: +g on z)
    f = np.einsum('nji,nj->ni', rot, acc - g_w)
    if not params.imu.centripetal:
        f[:, 1] -= arr['v'] * arr['w']
    arr.update({'z': pos[:, 2], 'roll': roll, 'pitch': pitch, 'gyro_body': gyro,
                'accel_body': f, 'tipped': tipped, 'pos': pos})
    arr['x'], arr['y'] = pos[:, 0], pos[:, 1]
    return arr
