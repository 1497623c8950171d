# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenario ``vacuum``: a robot vacuum cleans a furnished room, then follows the walls.

The room is one of :data:`robot_calib.sim.rooms.LAYOUTS` (``rect``,
``chamfer``, ``l_shape``, ``slanted``, ``parallel``), chosen by the seed
(``seed % 5``) and drawn with the scenario's random generator: sizes 4.5-7 m
by 3.5-5.5 m, furniture, non-Manhattan walls at 30-60 deg in ``chamfer`` and
``slanted``, a shelf parallel to a wall in ``parallel``.

Motion: boustrophedon cleaning passes (lanes 0.3 m apart along x, then along
y, repeated) for about half the duration, then wall following (right side,
0.3 m) until the end. ``truth.json`` gets ``phase_switch_time`` (s from the
start: when wall following began), ``layout``, the room ``outline`` and
``obstacles`` (polygons, m), and ``walls`` (every segment, m).

Sensors (robot-vacuum grade, all changeable with ``--set``): IMU 100 Hz with a
gyro z bias of 20 deg/h (``imu.gyro_bias``; the benchmark draws 10-30 deg/h
per run), a bias drift of 10 deg/h per hour, a warm-up of 5 deg/h decaying
over 10 min, a bias random walk, 0.2 % scale error; wheel radius and track
errors; a 360-beam lidar at 10 Hz with 1 cm noise and 1 % dropouts (NaN).
"""

from __future__ import annotations

import math

import numpy as np

from robot_calib.sim.motion import Plan, State
from robot_calib.sim.rooms import boustrophedon, LAYOUTS, make_room, route
from robot_calib.sim.scenario import BuildContext, Scenario, Setup

DEG_H = math.pi / 180.0 / 3600.0
"""One degree per hour in rad/s."""

SPEED = 0.25
"""Cleaning speed (m/s)."""

TURN_RATE = 0.8
"""Turn rate (rad/s)."""


def _pass_time(points: list) -> float:
    """Return an estimate (s) of the time to drive through waypoints."""
    p = np.asarray(points, dtype=float)
    if p.shape[0] < 2:
        return 0.0
    length = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
    return length / SPEED + p.shape[0] * (math.pi / 2) / TURN_RATE * 1.5


def build(ctx: BuildContext) -> Setup:
    """Return a furnished room, cleaning passes then wall following until the duration."""
    layout = LAYOUTS[ctx.seed % len(LAYOUTS)]
    room = make_room(layout, ctx.rng)
    lanes_x = boustrophedon(room, 0.3, 0.25, axis=0)
    lanes_y = boustrophedon(room, 0.3, 0.25, axis=1)
    start = (lanes_x[0][0], lanes_x[0][1], 0.0)
    truth = {'layout': layout, 'outline': room.outline.tolist(),
             'obstacles': [ob.tolist() for ob in room.obstacles],
             'walls': room.world.segments.tolist(), 'phase_switch_time': None,
             'room': room.facts}
    plan = Plan().stop(2.0)
    work = 0.5 * ctx.duration
    planned = 2.0
    passes = [lanes_x, lanes_y]
    here = start[:2]
    k = failed = 0
    while planned < work and failed < len(passes):
        pts = passes[k % 2]
        k += 1
        # reach the first lane around the furniture, never through it
        way = route(room, here, pts[0], 0.2) if len(pts) >= 2 else None
        if way is None:
            failed += 1
            continue
        failed = 0
        pts = way[:-1] + list(pts)
        est = _pass_time(pts)
        plan.goto(pts, speed=SPEED, turn_rate=TURN_RATE, tolerance=0.05,
                  timeout=2.0 * est + 30.0)
        planned += est
        here = pts[-1]

    def mark(s: State):
        if truth['phase_switch_time'] is None:
            truth['phase_switch_time'] = float(s.t)
        return None

    plan.custom(mark, 1.0, 'phase_switch')
    plan.follow_wall(max(ctx.duration, 1.0), side='right', distance=0.3, speed=SPEED,
                     turn_rate=TURN_RATE)
    return Setup(world=room.world, plan=plan, start=start, truth=truth)


SCENARIO = Scenario(
    name='vacuum',
    description='Robot vacuum: boustrophedon cleaning of a furnished room (5 layouts, some '
                'non-Manhattan walls), then wall following; drifting gyro bias.',
    build=build,
    duration=3600.0,
    defaults={
        'imu.rate': 100.0,
        'imu.gyro_bias': [0.0, 0.0, 20.0 * DEG_H],
        'imu.gyro_bias_drift': [0.0, 0.0, 10.0 * DEG_H / 3600.0],
        'imu.gyro_warmup': [0.0, 0.0, 5.0 * DEG_H],
        'imu.gyro_warmup_tau': 600.0,
        'imu.gyro_random_walk': 2.0e-6,
        'imu.gyro_noise': 1.0e-4,
        'imu.gyro_scale': [0.0, 0.0, 0.002],
        'imu.accel_noise': 2e-3,
        'wheels.left_radius_error': 0.004,
        'wheels.right_radius_error': -0.003,
        'wheels.track_width_error': 0.01,
        'wheels.velocity_noise': 0.02,
        'lidar.noise': 0.01,
        'lidar.dropout': 0.01,
        'lidar.range_max': 8.0,
    })
