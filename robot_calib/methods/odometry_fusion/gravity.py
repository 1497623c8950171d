# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Gravity in the forward accelerometer on slopes: the up direction tracked in ``base_link``.

On a slope of pitch ``theta`` the forward specific force is the forward
acceleration plus ``g sin(theta)``: 2.5 m/s^2 on a 15 deg ramp, which the
planar filter took for acceleration (its fused speed ran 2-2.5 m/s off for
seconds, the wheels were rejected as slip). :class:`GravityTracker` keeps the
unit up vector ``u`` in ``base_link`` with a complementary filter of the
Mahony form (Mahony, Hamel, Pflimlin, *Nonlinear complementary filters on the
special orthogonal group*, IEEE TAC 2008, eq. 32-33 reduced to one vector):

    e = u_meas x u                                                     (1)
    du/dt = -(w - b + k_p e) x u,    db/dt = -k_i e                    (2)

where ``w`` is the gyro (rad/s) and ``u_meas`` the direction of the specific
force less the motion's own acceleration (forward: the wheel speed's rate of
change; sideways: speed times turn rate), used only when its magnitude is
within ``GATE`` of g (not during bumps and impacts). The gyro carries the
ramp's entry (fast), the accelerometer holds the drift (``k_p = 1 / tau``,
``k_i = k_p^2 / 4``, critically damped). The motion's forward acceleration is
then ``f_x - g u_x``; the heading turns at the yaw Euler rate, not the body z
rate (on bumpy_drive's ramps the body rate put the heading 9 deg off in 300 s),
and the position advances by the horizontal share of the speed (:meth:`level`).
"""

from __future__ import annotations

import math

from robot_calib.core.constants import GRAVITY

GATE = 0.1
"""Largest relative difference of |f - a_motion| from g at which the accelerometer corrects."""

MAX_STEP = 0.5
"""Longest time step integrated (s); a longer gap restarts from the next reading."""

WHEEL_ACCEL_TIME = 0.1
"""Low-pass time constant of the wheel acceleration the tracker subtracts (s)."""


class WheelAcceleration:
    """The motion's own acceleration from the wheel speeds, low-passed over WHEEL_ACCEL_TIME."""

    def __init__(self, timeout: float) -> None:
        """Restart after wheel speeds more than ``timeout`` (s) apart."""
        self.timeout = timeout
        self.forward = 0.0
        self.lateral = 0.0
        self._last: tuple = ()

    def update(self, t: float, v: float, vl: float) -> None:
        """Add the forward and sideways wheel speeds (m/s; vl a holonomic robot's) at ``t``."""
        last, self._last = self._last, (t, v, vl)
        if not last or not 0.0 < t - last[0] <= self.timeout:
            self.forward = self.lateral = 0.0
            return
        dt = t - last[0]
        k = dt / (WHEEL_ACCEL_TIME + dt)
        self.forward += k * ((v - last[1]) / dt - self.forward)
        if vl or last[2]:
            self.lateral += k * ((vl - last[2]) / dt - self.lateral)
        else:
            self.lateral = 0.0

    def in_base(self, v: float, vl: float, w: float) -> tuple[float, float]:
        """
        Return the acceleration (m/s^2) along base_link x and y at speeds ``v``, ``vl``.

        In the frame turning at ``w`` (rad/s): ``a_x = v' - w vl``, ``a_y = vl' + w v``.
        """
        if vl:
            return self.forward - w * vl, self.lateral + w * v
        return self.forward, v * w + self.lateral


class GravityTracker:
    """Up direction and pitch/roll gyro bias in ``base_link`` (see the module)."""

    def __init__(self, time_constant: float) -> None:
        """Correct towards the accelerometer with ``time_constant`` (s)."""
        self.k_p = 1.0 / time_constant
        self.k_i = 0.25 * self.k_p * self.k_p
        self.up = (0.0, 0.0, 1.0)
        self.bias = [0.0, 0.0, 0.0]
        self.started = False
        self.t = 0.0

    def update(self, t: float, gyro: tuple, force: tuple, accel_forward: float,
               accel_lateral: float) -> float:
        """
        Advance to ``t`` (s) and return the forward motion acceleration (m/s^2).

        :param gyro: angular rate in base_link (rad/s)
        :param force: specific force in base_link (m/s^2)
        :param accel_forward: the motion's forward acceleration from the wheels (m/s^2)
        :param accel_lateral: its sideways (centripetal) acceleration (m/s^2)
        """
        fx, fy, fz = force
        mx, my, mz = fx - accel_forward, fy - accel_lateral, fz
        norm = math.sqrt(mx * mx + my * my + mz * mz)
        ok = abs(norm - GRAVITY) < GATE * GRAVITY
        if not self.started or t - self.t > MAX_STEP or t <= self.t:
            if not self.started or t - self.t > MAX_STEP:
                if ok:
                    self.up = (mx / norm, my / norm, mz / norm)
                    self.started = True
            self.t = t
            return fx - GRAVITY * self.up[0] if self.started else fx
        dt = t - self.t
        self.t = t
        ux, uy, uz = self.up
        b = self.bias
        wx, wy, wz = gyro[0] - b[0], gyro[1] - b[1], gyro[2] - b[2]
        if ok:
            # eq. (1): the rotation that turns the estimate towards the measurement
            ax, ay, az = mx / norm, my / norm, mz / norm
            ex, ey, ez = ay * uz - az * uy, az * ux - ax * uz, ax * uy - ay * ux
            kp, ki = self.k_p, self.k_i * dt
            wx, wy, wz = wx + kp * ex, wy + kp * ey, wz + kp * ez
            b[0] -= ki * ex
            b[1] -= ki * ey
            b[2] -= ki * ez
        # eq. (2): du/dt = -w x u, then back onto the unit sphere
        dx = -(wy * uz - wz * uy) * dt
        dy = -(wz * ux - wx * uz) * dt
        dz = -(wx * uy - wy * ux) * dt
        ux, uy, uz = ux + dx, uy + dy, uz + dz
        n = math.sqrt(ux * ux + uy * uy + uz * uz)
        self.up = (ux / n, uy / n, uz / n)
        return fx - GRAVITY * self.up[0]

    def level(self, gyro: tuple) -> tuple[float, float]:
        """
        Return (the heading's rate of change rad/s, the horizontal share of the speed).

        ``gyro`` is the reading in base_link (rad/s). The rate is the ZYX yaw Euler rate
        ``(w_y sin(roll) + w_z cos(roll)) / cos(pitch)`` (Diebel 2006, eq. 2.7 inverted)
        written with the up vector, ``(w_y u_y + w_z u_z) / (1 - u_x^2)``; the share is
        ``cos(pitch) = sqrt(1 - u_x^2)`` (the wheels measure along the ground). Before the
        first reading they are ``w_z`` and 1.
        """
        if not self.started:
            return gyro[2], 1.0
        ux, uy, uz = self.up
        c2 = max(1.0 - ux * ux, 0.25)  # |pitch| <= 60 deg: a robot on its wheels
        return ((gyro[1] - self.bias[1]) * uy + gyro[2] * uz) / c2, math.sqrt(c2)
