# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenario ``revisit``: a route through three rooms and a corridor that keeps coming back.

The floor: a 24 m x 2 m corridor (a few niches and pillars, and a bare
stretch in the middle where along-corridor position is hard to see) with
three furnished rooms off it: room A (8 m x 8 m) and room B (8 m x 7 m)
north of the corridor, room C (8 m x 8 m) south of it, each through a
1.5 m door. Each lap: corridor east, a tour of each room returning to its
door, then corridor back west to the start; every room tour closes a loop,
the corridor is driven both ways, and later laps revisit everything.
Closed-loop ``goto`` steps keep the route the same whatever the sensor
errors (the robot itself does not use them: its gyro and wheels drift).

Errors (``SCENARIO.defaults``, all changeable with ``--set``): gyro bias
(turn-on bias per seed), linear bias drift and random walk, gyro noise and
scale, wheel radius and track errors, a small constant slip and slip
episodes (the wheels spin on a slippery patch), lidar noise. Default 600 s,
about one and a half laps (about 140 m).
"""

from __future__ import annotations

from robot_calib.sim.motion import Plan
from robot_calib.sim.scenario import BuildContext, Scenario, Setup
from robot_calib.sim.world import World

START = (1.5, 5.0, 0.0)
DOORS = {'A': 3.75, 'B': 13.75, 'C': 19.75}
"""x (m) of the centre of each room's door on the corridor."""


def floor() -> World:
    """Return the corridor, the three rooms, their furniture and the corridor features."""
    w = World()
    # Corridor y in [4, 6], x in [0, 24]; doors 1.5 m wide.
    w.add_polyline([[0.0, 6.0], [3.0, 6.0]])
    w.add_polyline([[4.5, 6.0], [13.0, 6.0]])
    w.add_polyline([[14.5, 6.0], [24.0, 6.0]])
    w.add_polyline([[0.0, 4.0], [19.0, 4.0]])
    w.add_polyline([[20.5, 4.0], [24.0, 4.0]])
    w.add_segment(0.0, 4.0, 0.0, 6.0)
    w.add_segment(24.0, 4.0, 24.0, 6.0)
    # Room A: x [0, 8], y [6, 14].
    w.add_polyline([[0.0, 6.0], [0.0, 14.0], [8.0, 14.0], [8.0, 6.0]])
    w.add_box(4.0, 10.5, 1.2, 0.8)
    w.add_circle(1.0, 13.2, 0.3)
    w.add_box(7.6, 12.5, 0.6, 1.5)
    # Room B: x [10, 18], y [6, 13].
    w.add_polyline([[10.0, 6.0], [10.0, 13.0], [18.0, 13.0], [18.0, 6.0]])
    w.add_box(12.5, 12.4, 1.5, 0.6)
    w.add_box(17.2, 7.2, 0.6, 0.6, yaw=0.4)
    w.add_circle(14.0, 10.2, 0.35)
    # Room C: x [16, 24], y [-4, 4].
    w.add_polyline([[16.0, 4.0], [16.0, -4.0], [24.0, -4.0], [24.0, 4.0]])
    w.add_box(20.0, -0.8, 1.0, 1.0, yaw=0.2)
    w.add_circle(23.2, -3.3, 0.25)
    w.add_box(16.4, 2.5, 0.8, 0.5)
    # Corridor features (x in [8.5, 12.5] stays bare).
    w.add_box(7.0, 4.15, 0.4, 0.3)
    w.add_box(15.5, 5.85, 0.3, 0.3)
    w.add_box(22.5, 4.2, 0.5, 0.4)
    return w


def lap() -> Plan:
    """Return one lap from START through the three rooms and back."""
    a, b, c = DOORS['A'], DOORS['B'], DOORS['C']
    plan = Plan().stop(1.0)
    plan.goto([(a, 5.0), (a, 8.0), (6.0, 9.0), (6.0, 12.0), (2.0, 12.0), (2.0, 9.0),
               (a, 8.0), (a, 5.0)], speed=0.4)
    plan.stop(0.5)
    plan.goto([(b, 5.0), (b, 8.0), (16.0, 9.0), (16.0, 11.5), (11.5, 11.5), (11.5, 9.0),
               (b, 8.0), (b, 5.0)], speed=0.4)
    plan.stop(0.5)
    plan.goto([(c, 5.0), (c, 2.0), (22.0, 1.0), (22.0, -2.5), (17.5, -2.5), (17.5, 1.0),
               (c, 2.0), (c, 5.0)], speed=0.4)
    plan.stop(0.5)
    plan.goto([(10.0, 5.0), (START[0], START[1])], speed=0.45).face(START[2]).stop(1.0)
    return plan


def build(ctx: BuildContext) -> Setup:
    """Return the floor, the start pose and laps covering the duration."""
    return Setup(world=floor(), plan=Plan().repeat(lap(), until=ctx.duration), start=START,
                 truth={'doors_x': dict(DOORS), 'corridor_bare_x': [8.5, 12.5]})


SCENARIO = Scenario(
    name='revisit',
    description='A route through three rooms and a corridor that revisits every place '
                '(loop closure): gyro bias drift, wheel slip (differential drive).',
    build=build,
    duration=600.0,
    defaults={
        'imu.gyro_bias': [0.001, -0.001, 0.0015],
        'imu.gyro_bias_sigma': 0.001,
        'imu.gyro_bias_drift': [0.0, 0.0, 4e-6],
        'imu.gyro_noise': 2e-4,
        'imu.gyro_random_walk': 2e-5,
        'imu.gyro_scale': [0.0, 0.0, 0.003],
        'imu.accel_bias': [0.05, -0.03, 0.08],
        'imu.accel_noise': 2e-3,
        'wheels.left_radius_error': 0.004,
        'wheels.right_radius_error': -0.003,
        'wheels.track_width_error': 0.015,
        'wheels.slip_ratio': 0.01,
        'wheels.slip_episodes': [60.0, 64.0, 0.3, 0.05, 250.0, 253.0, 0.05, 0.4],
        'wheels.velocity_noise': 0.02,
        'lidar.noise': 0.01,
    })
