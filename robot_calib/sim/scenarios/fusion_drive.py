# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Scenario ``fusion_drive``: 10 minutes of mixed driving for IMU + wheel-odometry fusion.

A differential-drive robot drives a random (seeded) sequence of straight runs,
arcs, turns on the spot and short stops in an open yard (walls 200 m away), with the
errors a fusion filter must cope with:

- gyro z bias (0.005 rad/s plus a per-seed turn-on bias, 1 sigma 0.003 rad/s)
  drifting linearly (2e-6 rad/s^2, i.e. 0.0012 rad/s over 10 min) plus a bias
  random walk, gyro white noise;
- a wheel radius error (left +1.0 %, right -0.5 %) and a track width error
  (+4 %), so raw odometry drifts in heading and scale;
- three wheel slip episodes (one wheel or both losing 20-50 % of their speed
  for 2-4 s);
- wheel speed noise and 4096-tick encoders; a 100 Hz IMU, 50 Hz odometry.

Ground truth is in the bag (``ground_truth/odom``), the true parameters in
``truth.json`` (``slip_episodes`` as [t0, t1, left, right] lists).
"""

import math

from robot_calib.sim.motion import Plan
from robot_calib.sim.scenario import BuildContext, Scenario, Setup
from robot_calib.sim.world import World

SLIP_EPISODES = [60.0, 63.0, 0.4, 0.0,
                 250.0, 254.0, 0.2, 0.2,
                 430.0, 432.0, 0.0, 0.5]
"""Slip episodes: [t0, t1, left ratio, right ratio] repeated (s, s, -, -)."""


def build(ctx: BuildContext) -> Setup:
    """Return the world, the start pose and a random mixed-driving plan (seeded)."""
    rng = ctx.rng
    world = World().add_room(400.0, 400.0)
    plan = Plan().stop(3.0)
    total = 3.0
    while total < ctx.duration:
        kind = rng.choice(['straight', 'arc', 'turn', 'stop'], p=[0.45, 0.3, 0.15, 0.1])
        before = plan.duration
        if kind == 'straight':
            plan.straight(float(rng.uniform(3.0, 12.0)), float(rng.uniform(0.3, 1.0)))
        elif kind == 'arc':
            angle = float(rng.uniform(0.5, 2.5)) * float(rng.choice([-1.0, 1.0]))
            plan.arc(float(rng.uniform(1.0, 5.0)), angle, float(rng.uniform(0.3, 0.8)))
        elif kind == 'turn':
            angle = float(rng.uniform(0.5, math.pi)) * float(rng.choice([-1.0, 1.0]))
            plan.turn(angle, float(rng.uniform(0.3, 0.8)))
        else:
            plan.stop(float(rng.uniform(1.0, 4.0)))
        total += plan.duration - before
    return Setup(world=world, plan=plan, start=(0.0, 0.0, 0.0),
                 truth={'slip_episodes': [SLIP_EPISODES[i:i + 4]
                                          for i in range(0, len(SLIP_EPISODES), 4)]})


SCENARIO = Scenario(
    name='fusion_drive',
    description='10 min mixed driving: gyro bias drift, wheel slip episodes, wheel radius and '
                'track errors (IMU + wheel odometry fusion).',
    build=build,
    duration=600.0,
    defaults={
        'imu.rate': 100.0,
        'imu.gyro_bias': [0.0, 0.0, 0.005],
        'imu.gyro_bias_sigma': 0.003,
        'imu.gyro_bias_drift': [0.0, 0.0, 2e-6],
        'imu.gyro_noise': 0.002,
        'imu.gyro_random_walk': 2e-5,
        'imu.accel_noise': 0.02,
        'imu.accel_bias': [0.05, -0.03, 0.0],
        'wheels.left_radius_error': 0.01,
        'wheels.right_radius_error': -0.005,
        'wheels.track_width_error': 0.04,
        'wheels.slip_episodes': SLIP_EPISODES,
        'wheels.velocity_noise': 0.05,
    })
