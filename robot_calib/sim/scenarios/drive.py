# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenario ``drive``: general mixed driving in a furnished room (differential drive).

A 10 m x 8 m room with boxes and a pillar. Each lap: straight runs at two
speeds, turns in place both ways (including a full turn), arcs left and
right, a short reverse, stops; closed-loop ``goto``/``face`` steps anchor the
route (so wheel errors never drive the robot into a wall). Laps repeat until
the duration (default 120 s). Sensors: IMU 200 Hz, lidar 360 beams 10 Hz,
odom and joint_states 50 Hz, with moderate, realistic errors (see
``SCENARIO.defaults``; all can be changed with ``--set``).
"""

from __future__ import annotations

import math

from robot_calib.sim.motion import Plan
from robot_calib.sim.scenario import BuildContext, Scenario, Setup
from robot_calib.sim.world import World

START = (1.5, 1.5, 0.0)


def room() -> World:
    """Return the furnished 10 m x 8 m room: walls and obstacles."""
    world = World().add_room(10.0, 8.0)
    world.add_box(5.2, 3.0, 1.0, 0.6)
    world.add_box(3.0, 6.9, 0.8, 0.8, yaw=0.3)
    world.add_box(8.8, 3.0, 0.6, 1.2)
    world.add_circle(8.5, 6.2, 0.3)
    world.add_polygon([[0.0, 4.0], [0.6, 4.0], [0.6, 4.4], [0.0, 4.4]])  # a shelf on the wall
    return world


def lap() -> Plan:
    """
    Return one lap starting at START (heading east) and returning to it.

    Open-loop manoeuvres are anchored by closed-loop ``goto``/``face`` steps
    (perfect localisation), so the wheel errors change the details of each
    lap but never the route.
    """
    plan = Plan().stop(1.0).face(0.0)
    plan.straight(6.0, 0.4).stop(0.5)                       # (7.5, 1.5)
    plan.goto([(7.5, 1.5)], speed=0.2).face(math.pi / 2)    # heading north
    plan.straight(2.0, 0.3)                                 # (7.5, 3.5)
    plan.arc(1.0, math.pi / 2, 0.3).stop(1.0)               # (6.5, 4.5) heading west
    plan.goto([(3.5, 4.5)], speed=0.5).face(math.pi)
    plan.arc(0.8, -math.pi / 2, 0.25)                       # (2.7, 5.3) heading north
    plan.turn(-math.pi, 0.8).stop(0.5)                      # heading south (right turn)
    plan.straight(1.5, 0.3)                                 # (2.7, 3.8)
    plan.straight(-0.4, 0.2).stop(0.5)                      # short reverse to (2.7, 4.2)
    plan.arc(1.2, math.pi / 2, 0.35)                        # (3.9, 3.0) heading east
    plan.goto([START[:2]], speed=0.4).face(START[2])        # back to the start
    plan.turn(2 * math.pi, 0.7).stop(1.0)                   # a full turn to the left
    return plan


def build(ctx: BuildContext) -> Setup:
    """Return the room, the start pose and laps covering the duration."""
    return Setup(world=room(), plan=Plan().repeat(lap(), until=ctx.duration), start=START)


SCENARIO = Scenario(
    name='drive',
    description='General mixed driving in a furnished room: straight runs, turns both ways, '
                'arcs, stops (differential drive).',
    build=build,
    duration=120.0,
    defaults={
        'imu.gyro_bias': [0.002, -0.0015, 0.003],
        'imu.gyro_noise': 2e-4,
        'imu.gyro_random_walk': 2e-5,
        'imu.gyro_scale': [0.0, 0.0, 0.005],
        'imu.accel_bias': [0.05, -0.03, 0.08],
        'imu.accel_noise': 2e-3,
        'wheels.left_radius_error': 0.004,
        'wheels.right_radius_error': -0.003,
        'wheels.track_width_error': 0.015,
        'wheels.velocity_noise': 0.02,
        'lidar.noise': 0.01,
    })
