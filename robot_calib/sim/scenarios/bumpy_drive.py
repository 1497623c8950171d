# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenario ``bumpy_drive``: rough driving that must never raise a fall alert.

A 24 m x 12 m hall with a 15 deg ramp (up, plateau, down) crossed straight
and diagonally, an 8 deg ramp, a row of 3-5 cm bumps, hard braking from 1 m/s
(wheel lag 0.34 s: decelerations up to about 3 m/s^2), fast arcs (centripetal
acceleration about 1 m/s^2) and turns in place. Laps repeat until the
duration (default 600 s; the benchmark runs one hour). The true tilt stays
below about 16 deg throughout (``truth['max_true_tilt_deg']`` is the design
bound); ``ground_truth/odom`` carries the true roll and pitch.
"""

from __future__ import annotations

import math

from robot_calib.sim.motion import Plan
from robot_calib.sim.scenario import BuildContext, Scenario, Setup
from robot_calib.sim.world import Bump, Ramp, World

START = (2.0, 3.0, 0.0)
RAMP_DEG = 15.0


def hall() -> World:
    """Return the hall with its ramps and bumps."""
    world = World().add_room(24.0, 12.0)
    steep = math.tan(math.radians(RAMP_DEG))
    world.add_terrain(Ramp(6.0, 3.0, 0.0, 1.2, 1.2 * steep, width=8.0, plateau=2.0))
    gentle = math.tan(math.radians(8.0))
    world.add_terrain(Ramp(14.0, 3.0, 0.0, 2.0, 2.0 * gentle, width=4.0, plateau=1.0))
    for i, x in enumerate((5.0, 7.5, 10.0, 12.5, 15.0, 17.5)):
        world.add_terrain(Bump(x, 9.0 + 0.1 * (i % 2), 0.2 + 0.05 * (i % 3),
                               0.03 + 0.01 * (i % 3)))
    return world


def lap() -> Plan:
    """Return one lap from START back to START."""
    plan = Plan().stop(1.0).face(0.0)
    plan.straight(18.0, 1.0).stop(1.5)                      # both ramps, then a hard stop
    plan.goto([(20.0, 6.0), (20.0, 9.0)], speed=0.6).face(math.pi)
    plan.straight(16.0, 0.8).stop(1.0)                      # the bumps, hard stop
    plan.arc(1.0, math.pi / 2, 1.0)                          # fast arc (about 1 m/s^2)
    plan.goto([(3.0, 4.5)], speed=0.5)
    plan.goto([(5.2, 2.0), (9.0, 4.5)], speed=0.7)          # diagonal over the 15 deg ramp
    plan.turn(-2.0 * math.pi, 1.5).stop(0.5)                # a quick full turn
    plan.goto([(11.0, 6.0), (2.0, 6.0), START[:2]], speed=0.8).face(START[2])
    plan.turn(math.pi, 2.0).turn(-math.pi, 2.0).stop(1.0)
    return plan


def build(ctx: BuildContext) -> Setup:
    """Return the hall, the start pose and laps covering the duration."""
    return Setup(world=hall(), plan=Plan().repeat(lap(), until=ctx.duration), start=START,
                 truth={'fall_expected': False, 'max_ramp_deg': RAMP_DEG,
                        'max_true_tilt_deg': 16.0})


SCENARIO = Scenario(
    name='bumpy_drive',
    description='Rough driving without a fall: 15 and 8 deg ramps (straight and diagonal), '
                'bumps, hard braking (about 3 m/s^2), fast arcs and turns.',
    build=build,
    duration=600.0,
    defaults={
        'robot.wheel_time_constant': 0.34,
        'imu.gyro_bias': [0.004, -0.003, 0.002],
        'imu.gyro_noise': 3e-4,
        'imu.gyro_random_walk': 2e-5,
        'imu.gyro_scale': [0.005, -0.005, 0.005],
        'imu.accel_bias': [0.08, -0.05, 0.1],
        'imu.accel_noise': 4e-3,
        'wheels.velocity_noise': 0.02,
    })
