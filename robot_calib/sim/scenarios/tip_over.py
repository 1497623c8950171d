# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenario ``tip_over``: drive up a ramp, stop on its top and fall over sideways.

The robot drives 1 m/s-class laps on the flat, climbs a 14 deg ramp onto a
plateau, stops, and tips over to its right side (a free inverted-pendulum
fall about the wheel edge, ending on its side at 90 deg with a small
bounce). ``truth.json`` gives the tip start ``tip_start`` and the time the
true tilt (base_link z vs up) crosses 45 deg, ``tilt_crossing`` (both s from
the start of the run; add ``start_time`` for bag time); ``ground_truth/odom``
carries the true roll and pitch.
"""

from __future__ import annotations

import math

import numpy as np

from robot_calib.sim.motion import Plan, TipOver
from robot_calib.sim.scenario import BuildContext, Scenario, Setup
from robot_calib.sim.world import Ramp, World

START = (1.0, 3.0, 0.0)
FALL_ANGLE = math.pi / 4


def tip() -> TipOver:
    """Return the tip-over: sideways to the right onto the side, free fall about the edge."""
    return TipOver(axis='roll', direction=1, angle=math.pi / 2, mode='free', length=0.15,
                   start_rate=0.4, bounce=0.2)


def crossing_delay(event: TipOver, angle: float = FALL_ANGLE) -> float:
    """Return the time (s) from the tip start until the added tilt exceeds ``angle`` (rad)."""
    tau = np.arange(0.0, 5.0, 1e-4)
    tilt = np.abs(event.profile(tau))
    above = np.nonzero(tilt > angle)[0]
    return float(tau[above[0]]) if above.size else math.nan


def build(ctx: BuildContext) -> Setup:
    """Return the ramp world and a plan that ends in a tip-over (the rest is lying still)."""
    world = World().add_room(12.0, 6.0)
    world.add_terrain(Ramp(3.0, 3.0, 0.0, 1.0, math.tan(math.radians(14.0)), width=3.0,
                           plateau=4.0))
    plan = Plan().stop(2.0)
    plan.straight(3.8, 0.5).stop(1.0)                       # up the ramp onto its plateau
    t_tip = plan.duration
    event = tip()
    plan.tip_over(event)
    truth = {'fall_expected': True, 'tip_start': t_tip,
             'tilt_crossing': t_tip + crossing_delay(event),
             'fall_angle': FALL_ANGLE}
    return Setup(world=world, plan=plan, start=START, truth=truth)


SCENARIO = Scenario(
    name='tip_over',
    description='Climb a 14 deg ramp, stop on the plateau and tip over sideways onto the '
                'right side (true 45 deg crossing in truth.json).',
    build=build,
    duration=20.0,
    defaults={
        'imu.gyro_bias': [0.003, -0.002, 0.002],
        'imu.gyro_noise': 3e-4,
        'imu.accel_bias': [0.05, -0.05, 0.08],
        'imu.accel_noise': 4e-3,
    })
