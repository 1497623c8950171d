# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Motion plans: what the robot is commanded to do, step by step.

A :class:`Plan` is a list of steps executed one after the other at the
control rate (``odom.cmd_vel_rate``). Open-loop steps (``stop``, ``twist``,
``straight``, ``turn``, ``arc``, ``wheels``, ``steer``, ``profile``) are turned
into command arrays at once; closed-loop steps (``goto``, ``follow_wall``,
``custom``) call a controller every control tick with the TRUE state (as if a
perfect localisation ran on the robot) and the world. ``tip_over`` is an
event. Every builder method returns the plan, so calls chain::

    plan = Plan().stop(1.0).straight(2.0, 0.3).turn(math.pi / 2, 0.6).arc(1.0, -math.pi, 0.3)

Commands are either a twist (v m/s, omega rad/s: converted to wheel commands
with the NOMINAL geometry, like a real base controller does) or wheel level
(differential: left/right wheel speeds rad/s; steered wheel: steering READING
rad and traction wheel speed rad/s). The wheels follow their commands with a
first-order lag (``robot.wheel_time_constant``), so an open-loop segment
followed by a stop covers exactly the commanded distance or angle.

A plan shorter than the scenario's duration is padded with a stop; a longer
one is cut at the duration. ``Plan.duration`` tells the open-loop length so
far (closed-loop steps count with their time limit).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Callable, Optional, Sequence

import numpy as np

from robot_calib.core.constants import GRAVITY
from robot_calib.core.geometry import wrap_angle

TWIST = 'twist'
WHEELS = 'wheels'


@dataclass
class State:
    """
    True robot state handed to closed-loop controllers (world frame).

    ``t`` (s, from the start), ``x``, ``y`` (m), ``yaw`` (rad), ``v`` (m/s),
    ``w`` (rad/s), and ``world`` (the :class:`~robot_calib.sim.world.World`).
    """

    t: float
    x: float
    y: float
    yaw: float
    v: float
    w: float
    world: Any = None


Controller = Callable[[State], Optional[tuple]]
"""A controller returns (v m/s, omega rad/s) for this tick, or None when it is done."""


@dataclass
class Step:
    """One plan step: open loop (``kind``, ``values`` per tick) or closed loop (``controller``)."""

    duration: float
    kind: str = TWIST
    values: Optional[Callable[[int, float], np.ndarray]] = None
    controller: Optional[Controller] = None
    event: Optional[dict] = None
    factory: Optional[Callable[[], Controller]] = None
    """Makes a fresh controller each time the step starts (stateful controllers, repeats)."""
    label: str = ''
    exact: bool = False
    """Scale the command so that its integral is exact despite whole control ticks."""


@dataclass
class TipOver:
    """
    A tip-over: the robot rotates about a wheel/edge until it lies at ``angle`` (rad).

    :param axis: 'pitch' (forward/backward) or 'roll' (sideways)
    :param direction: +1 or -1: sign of the added pitch/roll (ROS: +pitch is nose down,
        +roll is falling to the right)
    :param angle: final tilt added to the attitude (rad), pi/2 lies on the side
    :param mode: 'scripted' (smoothstep over ``duration`` s) or 'free' (an inverted pendulum
        of length ``length`` m about the edge, starting with ``start_rate`` rad/s, stopping
        at ``angle`` with a damped bounce of ``bounce`` (fraction of the impact rate))
    """

    t: float = 0.0
    axis: str = 'pitch'
    direction: int = 1
    angle: float = math.pi / 2
    mode: str = 'scripted'
    duration: float = 0.5
    length: float = 0.2
    start_rate: float = 0.3
    bounce: float = 0.2

    def profile(self, tau: np.ndarray) -> np.ndarray:
        """Return the added tilt (rad) at times ``tau`` (s) since the start of the tip."""
        tau = np.asarray(tau, dtype=float)
        if self.mode == 'scripted':
            s = np.clip(tau / max(self.duration, 1e-6), 0.0, 1.0)
            return self.direction * self.angle * s * s * (3.0 - 2.0 * s)
        # inverted pendulum about the edge: theta'' = g / l sin(theta) (free fall of a rod)
        dt = 1e-3
        n = int(np.ceil(max(tau.max(initial=0.0), 0.0) / dt)) + 2
        theta = np.zeros(n)
        rate = self.start_rate
        th = 0.0
        g_l = GRAVITY / max(self.length, 1e-3)
        for k in range(1, n):
            acc = g_l * math.sin(th)
            rate += acc * dt
            th += rate * dt
            if th >= self.angle:  # impact: bounce back a little, then settle
                th = self.angle
                rate = -self.bounce * rate
                if abs(rate) < 0.05:
                    rate = 0.0
            theta[k] = th
        return self.direction * np.interp(tau, np.arange(n) * dt, theta)


def _goto(s: State, points: list, index: list, speed: float, turn_rate: float,
          tolerance: float, turn_first: float) -> Optional[tuple]:
    """Waypoint controller step (see :meth:`Plan.goto`); ``index`` holds the progress."""
    while index[0] < len(points):
        gx, gy = points[index[0]]
        dist = math.hypot(gx - s.x, gy - s.y)
        if dist > tolerance:
            break
        index[0] += 1
    else:
        return None
    err = wrap_angle(math.atan2(gy - s.y, gx - s.x) - s.yaw)
    w = max(-turn_rate, min(turn_rate, 2.5 * err))
    if abs(err) > turn_first:
        return 0.0, w
    last = index[0] == len(points) - 1
    v = min(speed, 1.2 * dist) if last else speed
    return v * math.cos(err), w


@dataclass
class Plan:
    """A sequence of motion steps (see the module docstring)."""

    steps: list = field(default_factory=list)

    @property
    def open_loop_duration(self) -> float:
        """Return the length (s) of the open-loop steps only (closed-loop steps count 0)."""
        return float(sum(s.duration for s in self.steps
                         if s.controller is None and s.factory is None))

    @property
    def duration(self) -> float:
        """Return the planned length (s): open-loop durations plus closed-loop time limits."""
        return float(sum(s.duration for s in self.steps))

    # -- open loop -----------------------------------------------------------------------
    def twist(self, v: float, w: float, duration: float, label: str = 'twist',
              exact: bool = False) -> 'Plan':
        """
        Command a constant twist: ``v`` (m/s) and ``w`` (rad/s) for ``duration`` (s).

        The duration is rounded to whole control ticks; with ``exact`` the
        command is scaled so that v * duration and w * duration are kept.
        """
        cmd = np.array([float(v), float(w)])
        self.steps.append(Step(max(0.0, duration), TWIST,
                               lambda n, dt: np.tile(cmd, (n, 1)), label=label, exact=exact))
        return self

    def stop(self, duration: float) -> 'Plan':
        """Stand still for ``duration`` (s)."""
        return self.twist(0.0, 0.0, duration, 'stop')

    def straight(self, distance: float, speed: float) -> 'Plan':
        """Drive ``distance`` (m, negative: backwards) at ``speed`` (m/s, > 0)."""
        speed = abs(speed)
        return self.twist(math.copysign(speed, distance), 0.0, abs(distance) / speed,
                          'straight', True)

    def turn(self, angle: float, rate: float) -> 'Plan':
        """Turn in place by ``angle`` (rad, positive: counter-clockwise) at ``rate`` (rad/s)."""
        rate = abs(rate)
        return self.twist(0.0, math.copysign(rate, angle), abs(angle) / rate, 'turn', True)

    def arc(self, radius: float, angle: float, speed: float) -> 'Plan':
        """Drive an arc of ``radius`` (m) turning by ``angle`` (rad, + left) at ``speed`` (m/s)."""
        speed = abs(speed)
        radius = abs(radius)
        length = radius * abs(angle)
        return self.twist(speed, math.copysign(speed / radius, angle), length / speed, 'arc',
                          True)

    def wheels(self, left: float, right: float, duration: float) -> 'Plan':
        """Differential drive: wheel speeds ``left``, ``right`` (rad/s) for ``duration`` (s)."""
        cmd = np.array([float(left), float(right)])
        self.steps.append(Step(max(0.0, duration), WHEELS,
                               lambda n, dt: np.tile(cmd, (n, 1)), label='wheels'))
        return self

    def steer(self, angle: float, speed: float, duration: float) -> 'Plan':
        """
        Steered wheel: steering READING ``angle`` (rad) and traction speed ``speed`` (m/s).

        The traction speed is converted with the nominal wheel radius (rad/s =
        speed / robot.wheel_radius) by the engine.
        """
        cmd = np.array([float(angle), float(speed)])
        self.steps.append(Step(max(0.0, duration), 'steer',
                               lambda n, dt: np.tile(cmd, (n, 1)), label='steer'))
        return self

    def profile(self, times: Sequence[float], v: Sequence[float], w: Sequence[float]) -> 'Plan':
        """
        Command a twist profile: v (m/s), w (rad/s) at ``times`` (s from the step start).

        Values between the times are linearly interpolated.
        """
        times = np.asarray(times, dtype=float)
        v = np.asarray(v, dtype=float)
        w = np.asarray(w, dtype=float)

        def values(n: int, dt: float) -> np.ndarray:
            tt = np.arange(n) * dt
            return np.column_stack((np.interp(tt, times, v), np.interp(tt, times, w)))
        self.steps.append(Step(float(times[-1] - min(times[0], 0.0)), TWIST, values,
                               label='profile'))
        return self

    # -- closed loop ---------------------------------------------------------------------
    def custom(self, controller: Controller, timeout: float, label: str = 'custom',
               factory: bool = False) -> 'Plan':
        """
        Run ``controller(state) -> (v, w) | None`` each tick until None or ``timeout`` (s).

        With ``factory=True``, ``controller`` is a zero-argument callable that
        returns a fresh controller each time the step starts: use this for
        controllers with internal state in plans that are repeated.
        """
        if factory:
            self.steps.append(Step(float(timeout), TWIST, factory=controller, label=label))
        else:
            self.steps.append(Step(float(timeout), TWIST, controller=controller, label=label))
        return self

    def goto(self, waypoints: Sequence[Sequence[float]], speed: float = 0.3,
             turn_rate: float = 0.8, tolerance: float = 0.05, timeout: float = 120.0,
             turn_first: float = 0.6) -> 'Plan':
        """
        Follow waypoints (x, y world, m) with a simple heading controller.

        Turns in place while the heading error exceeds ``turn_first`` (rad),
        else drives at up to ``speed`` (m/s) steering towards the waypoint;
        a waypoint is reached within ``tolerance`` (m). Stops after ``timeout`` (s).
        """
        points = [tuple(map(float, p[:2])) for p in waypoints]

        def make() -> Controller:
            index = [0]
            return lambda s: _goto(s, points, index, speed, turn_rate, tolerance, turn_first)
        return self.custom(make, timeout, 'goto', factory=True)

    def face(self, yaw: float, rate: float = 0.8, tolerance: float = 0.01,
             timeout: float = 20.0) -> 'Plan':
        """Turn in place until the heading is ``yaw`` (rad, world) within ``tolerance`` (rad)."""
        def control(s: State) -> Optional[tuple]:
            err = wrap_angle(yaw - s.yaw)
            if abs(err) < tolerance and abs(s.w) < 0.05:
                return None
            return 0.0, max(-rate, min(rate, 2.5 * err))
        return self.custom(control, timeout, 'face')

    def follow_wall(self, duration: float, side: str = 'right', distance: float = 0.3,
                    speed: float = 0.25, turn_rate: float = 0.8, gain: float = 3.0) -> 'Plan':
        """
        Follow the wall on ``side`` (left/right) at ``distance`` (m) for ``duration`` (s).

        Uses ray casts from base_link in the world (an ideal side range
        sensor): a PD-like law on the side distance and heading to the wall,
        turning in place away from obstacles ahead.
        """
        sign = -1.0 if side == 'right' else 1.0

        def control(s: State) -> Optional[tuple]:
            world = s.world
            rays = s.yaw + np.array([0.0, sign * math.pi / 4, sign * math.pi / 2])
            front, diag, lateral = world.raycast(s.x, s.y, rays)
            if front < distance + 0.15:
                return 0.0, -sign * turn_rate
            side_d = min(lateral, diag * math.cos(math.pi / 4))
            if not math.isfinite(side_d):
                side_d = 2 * distance
            err = max(-0.5, min(0.5, side_d - distance))
            w = sign * gain * err
            return speed, max(-turn_rate, min(turn_rate, w))
        return self.custom(control, duration, 'follow_wall')

    # -- events --------------------------------------------------------------------------
    def tip_over(self, tip: Optional[TipOver] = None, **kwargs: Any) -> 'Plan':
        """
        Tip the robot over at this point of the plan (a :class:`TipOver`, or its fields).

        After the tip starts the body no longer moves in the plane (the wheels
        may keep turning in the air); add steps after it to keep commanding.
        """
        tip = tip if tip is not None else TipOver(**kwargs)
        self.steps.append(Step(0.0, TWIST, event={'tip': tip}, label='tip_over'))
        return self

    def repeat(self, other: 'Plan', until: float) -> 'Plan':
        """
        Append ``other``'s steps again and again until this plan surely lasts ``until`` (s).

        Laps are appended until both the open-loop time (closed-loop steps
        counted as instant: they usually end well before their time limit)
        and :attr:`duration` (closed-loop steps counted with their limit)
        reach ``until``; the engine cuts the plan at the run's duration.
        """
        if other.duration <= 0:
            return self
        lap = other.open_loop_duration
        while self.duration < until or (lap > 0 and self.open_loop_duration < until):
            self.steps.extend(other.steps)
        return self
