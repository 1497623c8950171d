# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenario ``diff_segments``: a differential-drive calibration drive in a room.

In a 12 m x 9 m room with a few boxes: a rectangle of 6 m and 4 m straight
segments counter-clockwise, then clockwise (waypoint following), a full turn
on the spot each way, and arcs of 1 m radius both ways, repeated until the
duration ends.

True errors (defaults, change them with ``--set``): left wheel radius
``wheels.left_radius_error`` +0.8 %, right wheel radius
``wheels.right_radius_error`` -0.5 %, track width
``wheels.track_width_error`` +2 %. Nominal robot: wheel radius 0.05 m,
track width 0.30 m, lidar at (0.1, 0.0) m. ``truth.json`` holds the true
``left_wheel_radius``, ``right_wheel_radius`` and ``track_width``.
"""

import math

from robot_calib.sim.motion import Plan
from robot_calib.sim.scenario import BuildContext, Scenario, Setup
from robot_calib.sim.world import World


def _lap(speed: float) -> Plan:
    """Return one calibration lap starting and ending at (2, 2) (m)."""
    lap = Plan()
    lap.goto([(8.0, 2.0), (8.0, 6.0), (2.0, 6.0), (2.0, 2.0)], speed=speed, timeout=90.0)
    lap.goto([(2.0, 6.0), (8.0, 6.0), (8.0, 2.0), (2.0, 2.0)], speed=speed, timeout=90.0)
    lap.face(0.0)
    lap.turn(2 * math.pi, 0.6).stop(0.5).turn(-2 * math.pi, 0.6).stop(0.5)
    lap.arc(1.0, math.pi / 2, speed).arc(1.0, -math.pi / 2, speed).stop(0.5)
    lap.goto([(2.0, 2.0)], speed=speed, timeout=60.0)
    return lap


def build(ctx: BuildContext) -> Setup:
    """Return the room, the start pose and the calibration plan."""
    world = World().add_room(12.0, 9.0)
    world.add_box(5.0, 4.0, 1.0, 0.6).add_box(10.5, 7.5, 0.8, 0.8)
    world.add_box(1.0, 8.0, 0.6, 0.6, 0.4).add_circle(10.5, 1.0, 0.3)
    plan = Plan().stop(1.0).repeat(_lap(0.3), until=ctx.duration)
    truth = {'calibration_drive': 'straight segments 6 m / 4 m both ways, full turns on the '
                                  'spot both ways, arcs of 1 m radius both ways'}
    return Setup(world=world, plan=plan, start=(2.0, 2.0, 0.0), truth=truth)


SCENARIO = Scenario(
    name='diff_segments',
    description='Differential-drive calibration drive: straight segments, turns on the spot '
                'and arcs both ways in a room (true wheel radius and track width errors).',
    build=build,
    duration=180.0,
    defaults={'wheels.left_radius_error': 0.008, 'wheels.right_radius_error': -0.005,
              'wheels.track_width_error': 0.02, 'lidar.range_max': 15.0})
