# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Gravity on slopes in the fusion filter: the up direction tracker and a ramp drive."""

import math

import numpy as np
import pytest
from robot_calib.core.constants import GRAVITY
from robot_calib.methods.odometry_fusion.gravity import GravityTracker


def force_on_slope(pitch, roll, accel=0.0):
    """Return the specific force (m/s^2) in base_link, nose up ``pitch``, REP-103 ``roll``."""
    up = (math.sin(pitch), math.sin(roll) * math.cos(pitch), math.cos(roll) * math.cos(pitch))
    return (accel + GRAVITY * up[0], GRAVITY * up[1], GRAVITY * up[2])


def test_at_rest_on_a_slope_the_motion_is_zero():
    g = GravityTracker(1.0)
    rng = np.random.default_rng(0)
    out = []
    for i in range(2000):
        f = np.array(force_on_slope(math.radians(12.0), math.radians(-5.0)))
        out.append(g.update(i * 0.01, tuple(rng.normal(0, 0.002, 3)),
                            tuple(f + rng.normal(0, 0.02, 3)), 0.0, 0.0))
    assert abs(np.mean(out[-500:])) < 0.01
    assert math.degrees(math.asin(g.up[0])) == pytest.approx(12.0, abs=0.2)


def test_a_ramp_entry_is_carried_by_the_gyro():
    """Driving at constant speed onto a 15 deg ramp in 0.4 s: no phantom acceleration."""
    g = GravityTracker(1.0)
    dt = 0.005
    pitch = 0.0
    worst = 0.0
    naive = 0.0
    for i in range(int(20.0 / dt)):
        t = i * dt
        rate = math.radians(15.0) / 0.4 if 5.0 <= t < 5.4 else 0.0
        rate -= math.radians(15.0) / 0.4 if 12.0 <= t < 12.4 else 0.0
        pitch += rate * dt
        f = force_on_slope(pitch, 0.0)
        # REP-103: the nose-up pitch rate is negative about the body y axis
        a = g.update(t, (0.0, -rate, 0.0), f, 0.0, 0.0)
        if t > 1.0:
            worst = max(worst, abs(a))
            naive = max(naive, abs(f[0]))
    assert naive > 2.5
    assert worst < 0.05


def test_the_pitch_gyro_bias_is_learnt_and_acceleration_passes():
    g = GravityTracker(1.0)
    dt = 0.01
    out = []
    for i in range(int(120.0 / dt)):
        t = i * dt
        accel = 0.8 if (i // 300) % 2 else -0.8  # speeding up and braking every 3 s
        out.append((t, accel, g.update(t, (0.0, 0.01, 0.0), force_on_slope(0.0, 0.0, accel),
                                       accel, 0.0)))
    assert g.bias[1] == pytest.approx(0.01, abs=0.001)
    late = np.array([o for o in out if o[0] > 60.0])
    assert np.max(np.abs(late[:, 2] - late[:, 1])) < 0.05


@pytest.mark.parametrize('compensate', [True, False])
def test_ramps_through_the_filter(compensate):
    """
    bumpy_drive's 15 and 8 deg ramps: the fused speed follows the truth.

    Without the compensation gravity's 2.5 m/s^2 on the ramp was taken for acceleration:
    the speed ran off by more than 1 m/s and the wheels were rejected as slip.
    """
    from robot_calib.methods.odometry_fusion.params import FusionParams
    from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
    from robot_calib.sim import run_scenario
    r = run_scenario('bumpy_drive', seed=1, duration=150.0)
    pipe = FusionPipeline(FusionParams(gravity_compensation=compensate))
    est = []
    for topic, m in r.messages:
        if topic == '/tf_static':
            for tf in m:
                pipe.on_static_transform(tf)
        elif topic in ('/imu', '/odom'):
            est += [(o.t, o.vx) for k, o in pipe.process(topic[1:], m) if k == 'odom']
    est = np.array(est)
    err = np.abs(est[:, 1] - np.interp(est[:, 0], r.sensors['gt_t'], r.sensors['gt_v']))
    counts = pipe.estimator.result().counts
    if compensate:
        assert err.max() < 0.2
        assert counts.get('rejected_slip_speed', 0) == 0
    else:
        assert err.max() > 1.0 and counts['rejected_slip_speed'] > 100


def test_the_heading_turns_at_the_yaw_euler_rate_on_a_slope():
    """Turning on a 15 deg cross slope: the body z rate is not the heading's rate."""
    g = GravityTracker(5.0)
    roll, pitch, yaw_rate = math.radians(-15.0), math.radians(6.0), 0.4
    # ZYX Euler rates (roll, pitch constant) -> body rates, REP-103 (pitch nose down)
    p_ros = -pitch
    gyro = (-yaw_rate * math.sin(p_ros), yaw_rate * math.cos(p_ros) * math.sin(roll),
            yaw_rate * math.cos(p_ros) * math.cos(roll))
    for i in range(500):
        g.update(i * 0.01, gyro, force_on_slope(pitch, roll), 0.0, 0.0)
    rate, share = g.level(gyro)
    assert rate == pytest.approx(yaw_rate, rel=2e-3)
    assert abs(gyro[2] - yaw_rate) > 0.03 * yaw_rate  # what the body rate would have said
    assert share == pytest.approx(math.cos(pitch), rel=1e-3)
