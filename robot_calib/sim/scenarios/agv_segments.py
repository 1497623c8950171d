# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenario ``agv_segments``: a steered-drive-wheel AGV drives straight stages and turns.

The calibration drive of seed 003 in a 16 m x 12 m room with a few boxes:
rectangles of 8 m and 6 m straight stages driven counter-clockwise and then
clockwise (waypoint following, so the controller holds the straight line
whatever the steering offset is), corners turned on the spot (steering at
about 90 deg), and arcs of 2 m and 3 m radius both ways (medium steering
angles, which make the steering scale and the wheel base observable), repeated
until the duration ends.

True errors (defaults, change them with ``--set``): steering zero offset
``wheels.steering_offset`` 0.0175 rad (1 deg), traction wheel radius
``wheels.radius_error`` +1.2 %, wheel base ``wheels.wheel_base_error`` +1 %,
steering scale ``wheels.steering_scale`` 1.0. Nominal robot: traction wheel
radius 0.1 m, wheel base 1.0 m, lidar 0.5 m ahead of the rear axle.
``truth.json`` holds the true values under the result keys of
``wheel_odometry_calibration`` (``steering_offset``, ``wheel_radius``, ...).
"""

import math

from robot_calib.sim.motion import Plan
from robot_calib.sim.scenario import BuildContext, Scenario, Setup
from robot_calib.sim.world import World


def _lap(speed: float) -> Plan:
    """Return one calibration lap starting and ending at (3, 3) (m)."""
    lap = Plan()
    lap.goto([(11.0, 3.0), (11.0, 9.0), (3.0, 9.0), (3.0, 3.0)], speed=speed, timeout=120.0)
    lap.goto([(3.0, 9.0), (11.0, 9.0), (11.0, 3.0), (3.0, 3.0)], speed=speed, timeout=120.0)
    lap.face(0.0)
    lap.arc(2.0, math.pi / 2, speed).arc(2.0, -math.pi / 2, speed).stop(0.5)
    lap.arc(3.0, -math.pi / 3, speed).arc(3.0, math.pi / 3, speed).stop(0.5)
    lap.goto([(3.0, 3.0)], speed=speed, timeout=60.0)
    return lap


def build(ctx: BuildContext) -> Setup:
    """Return the room, the start pose and the stage plan."""
    world = World().add_room(16.0, 12.0)
    world.add_box(7.0, 6.0, 1.2, 0.8).add_box(14.5, 10.5, 1.0, 1.0)
    world.add_box(1.0, 11.0, 0.8, 0.8, 0.3).add_circle(14.0, 1.5, 0.4)
    plan = Plan().stop(1.0).repeat(_lap(0.4), until=ctx.duration)
    truth = {'calibration_drive': 'straight stages 8 m / 6 m both ways, on-the-spot corners, '
                                  'arcs of 2 m and 3 m radius both ways'}
    return Setup(world=world, plan=plan, start=(3.0, 3.0, 0.0), truth=truth)


SCENARIO = Scenario(
    name='agv_segments',
    description='Steered-wheel AGV calibration drive: straight stages, corners and arcs both '
                'ways in a room (true steering offset, radius and wheel base errors).',
    build=build,
    duration=240.0,
    defaults={'robot.drive_type': 'steered_wheel', 'robot.wheel_radius': 0.1,
              'robot.wheel_base': 1.0, 'robot.max_steering_angle': 1.6,
              'wheels.steering_offset': 0.0175, 'wheels.radius_error': 0.012,
              'wheels.wheel_base_error': 0.01, 'lidar.x': 0.5, 'lidar.range_max': 20.0})
