# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Drive dynamics: how a real base turns a velocity command into body motion.

:class:`DriveDynamics` filters the commanded twist (v m/s, omega rad/s), given
at the simulator's internal rate, into the twist the base actually aims for,
per axis in this order (:class:`~robot_calib.sim.params.DriveParams`):

1. deadband: ``|u| < band`` gives 0 (a motor that does not start);
2. dead time ``T``: ``u(t - T)`` (transport delay: bus, controller cycle);
3. steady-state gain: ``(1 + g) u``;
4. rate limit: ``|du/dt| <= a_max`` (acceleration saturation, as a controller's
   speed limiter does);
5. first-order lag ``tau``: ``tau y' + y = u`` (exact for a held sample), or,
   with a damping ``zeta > 0``, the second-order response
   ``y'' + 2 zeta wn y' + wn^2 y = wn^2 u`` of the same mean delay
   ``tau = 2 zeta / wn`` (overshoot for ``zeta < 1``);

then the couplings between the axes:

6. turn speed loss: ``v = v (1 - k |omega|)`` (floored at 0), with the turn rate
   after its own dynamics;
7. wheel-speed saturation (differential drive): when the faster wheel would
   exceed ``max_wheel_speed`` (rad/s, nominal radius), both wheels are scaled
   alike, so speed and turn rate shrink together and the path keeps its
   curvature.

Each stage is the model of the mismatch effect of the same name (``real =
f(sim)``), so a simulation carrying the reported parameters reproduces what
the analyser found. The filter keeps its state between calls (closed-loop plans
advance one control tick at a time). All stages off is the identity.
"""

from __future__ import annotations

from functools import lru_cache
import math

import numpy as np

from robot_calib.sim.params import DriveParams


@lru_cache(maxsize=512)
def second_order_coefficients(dt: float, tau: float, zeta: float) -> tuple:
    """
    Return (b, a) of the discrete second-order response, mean delay ``tau`` (s), damping ``zeta``.

    ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` with ``wn = 2 zeta / tau`` (the mean
    delay of its step response is ``tau``, as a first-order lag's), held
    between samples ``dt`` (s) apart (zero-order hold, exact), read one sample
    earlier as the first-order lag ``y[k] = a y[k-1] + (1 - a) u[k]`` is.
    """
    from scipy.signal import cont2discrete

    wn = 2.0 * zeta / tau
    num, den, _ = cont2discrete(([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn]), dt, method='zoh')
    return tuple(np.ravel(num)[1:]), tuple(np.ravel(den))


class DriveDynamics:
    """
    Stateful per-axis drive filter at a fixed sample period (see the module docstring).

    :param params: the drive parameters
    :param dt: sample period (s), the simulator's internal step
    :param track_width: nominal track width (m), for the wheel-speed saturation
    :param wheel_radius: nominal wheel radius (m), for the wheel-speed saturation
    """

    def __init__(self, params: DriveParams, dt: float, track_width: float,
                 wheel_radius: float):
        """Start at rest."""
        self.p = params
        self.dt = float(dt)
        self.track_width = float(track_width)
        self.wheel_radius = float(wheel_radius)
        p = params
        self.band = np.array([p.linear_deadband, p.angular_deadband])
        self.delay = [int(round(p.linear_dead_time / self.dt)),
                      int(round(p.angular_dead_time / self.dt))]
        self.gain = 1.0 + np.array([p.linear_gain, p.angular_gain])
        self.rate = np.array([p.linear_rate_limit, p.angular_rate_limit]) * self.dt
        taus = (p.linear_time_constant, p.angular_time_constant)
        self.alpha = [math.exp(-self.dt / tau) if tau > 0 else 0.0 for tau in taus]
        zetas = (p.linear_damping, p.angular_damping)
        self.second = [second_order_coefficients(self.dt, tau, z) if tau > 0 and z > 0
                       else None for tau, z in zip(taus, zetas)]
        self.state2 = [np.zeros(2), np.zeros(2)]
        self.history = [np.zeros(n) for n in self.delay]
        self.limited = np.zeros(2)
        self.lagged = np.zeros(2)

    def _delayed(self, j: int, u: np.ndarray) -> np.ndarray:
        """Return ``u`` delayed by the axis' dead time, keeping the tail for the next call."""
        n = self.delay[j]
        if n == 0:
            return u
        both = np.concatenate((self.history[j], u))
        self.history[j] = both[-n:]
        return both[:u.size]

    def _rate_limited(self, j: int, u: np.ndarray) -> np.ndarray:
        """Return ``u`` with its change per sample clipped to the axis' rate limit."""
        step = float(self.rate[j])
        if step <= 0.0:
            return u
        out = np.empty_like(u)
        y = float(self.limited[j])
        for i, target in enumerate(u.tolist()):
            d = target - y
            if d > step:
                d = step
            elif d < -step:
                d = -step
            y += d
            out[i] = y
        self.limited[j] = y
        return out

    def _lag(self, j: int, u: np.ndarray) -> np.ndarray:
        """Return the first-order lag of ``u`` (y[k] = a y[k-1] + (1 - a) u[k])."""
        a = self.alpha[j]
        if a == 0.0:
            return u
        from scipy.signal import lfilter
        if self.second[j] is not None:
            b2, a2 = self.second[j]
            y, self.state2[j] = lfilter(b2, a2, u, zi=self.state2[j])
            return y
        y, _ = lfilter([1.0 - a], [1.0, -a], u, zi=[a * float(self.lagged[j])])
        self.lagged[j] = y[-1]
        return y

    def __call__(self, twist: np.ndarray) -> np.ndarray:
        """
        Return the realised twist (N, 2) (v m/s, omega rad/s) for commands ``twist`` (N, 2).

        One row per internal sample, in time order; successive calls continue the run.
        """
        twist = np.asarray(twist, dtype=float).reshape(-1, 2)
        out = np.empty_like(twist)
        for j in range(2):
            u = twist[:, j]
            if self.band[j] > 0:
                u = np.where(np.abs(u) < self.band[j], 0.0, u)
            u = self._delayed(j, u) * self.gain[j]
            out[:, j] = self._lag(j, self._rate_limited(j, u))
        if self.p.turn_speed_loss > 0:
            out[:, 0] = out[:, 0] * np.maximum(1.0 - self.p.turn_speed_loss * np.abs(out[:, 1]),
                                               0.0)
        if self.p.max_wheel_speed > 0:
            half = 0.5 * out[:, 1] * self.track_width
            fastest = np.maximum(np.abs(out[:, 0] - half), np.abs(out[:, 0] + half)) \
                / self.wheel_radius
            scale = np.where(fastest > self.p.max_wheel_speed,
                             self.p.max_wheel_speed / np.maximum(fastest, 1e-12), 1.0)
            out = out * scale[:, None]
        return out
