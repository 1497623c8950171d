# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A holonomic robot (mecanum or omni wheels): its odometry's twist has a sideways speed.

Fusion must move the robot along base_link y as its odometry says (before, the
sideways speed was dropped: a robot sliding 4.5 m sideways stood still in the
fused odometry, and its standstill update taught the gyro bias from the slide);
wheel calibration, whose drives roll without sliding, must refuse it.
"""

import dataclasses
import math

import numpy as np
import pytest
from robot_calib.core import types as T
from robot_calib.core.constants import GRAVITY
from robot_calib.core.frames import constant_motion
from robot_calib.methods.odometry_fusion.params import FusionParams
from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline


def _ramp(t, t0, t1, rise=1.0):
    """Return 0 outside (t0, t1), 1 from t0 + rise to t1 - rise, with cosine edges."""
    if t <= t0 or t >= t1:
        return 0.0
    edge = min(1.0, (t - t0) / rise, (t1 - t) / rise)
    return 0.5 - 0.5 * math.cos(math.pi * edge)


def holonomic_drive(duration=32.0, dt=0.005, pose_only=False, odom_late=0.0):
    """
    Return the truth (rows t, x, y, yaw, vx, vy) and the (key, sample) inputs of a drive.

    At rest 3 s, 4.5 m straight sideways (0.5 m/s), at rest, then 14 s forward and
    sideways at once while turning (0.3, -0.3 m/s, 0.3 rad/s), at rest. IMU 100 Hz
    (level, gravity on z), odometry 20 Hz; ``pose_only``: the driver leaves the
    twist at zero; ``odom_late`` (s): the odometry stamped that much after its motion.
    """
    n = int(duration / dt) + 1
    t = np.arange(n) * dt
    vx = np.array([0.3 * _ramp(s, 16.0, 30.0) for s in t])
    vy = np.array([0.5 * _ramp(s, 3.0, 13.0) - 0.3 * _ramp(s, 16.0, 30.0) for s in t])
    w = np.array([0.3 * _ramp(s, 16.0, 30.0) for s in t])
    yaw = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)))
    c, s = np.cos(yaw), np.sin(yaw)
    vxw, vyw = vx * c - vy * s, vx * s + vy * c
    x = np.concatenate(([0.0], np.cumsum(0.5 * (vxw[1:] + vxw[:-1]) * dt)))
    y = np.concatenate(([0.0], np.cumsum(0.5 * (vyw[1:] + vyw[:-1]) * dt)))
    # specific force in base_link: the rotating frame's a_x = vx' - w vy, a_y = vy' + w vx
    ax = np.gradient(vx, dt) - w * vy
    ay = np.gradient(vy, dt) + w * vx
    rng = np.random.default_rng(3)
    inputs = []
    for i in range(0, n, 2):
        gyro = np.array([0.0, 0.0, w[i]]) + rng.normal(0.0, 0.002, 3)
        acc = np.array([ax[i], ay[i], GRAVITY]) + rng.normal(0.0, 0.02, 3)
        inputs.append((t[i], 'imu', T.ImuSample(t[i], gyro, acc)))
        if i % 10 == 0:
            twist = (0.0, 0.0, 0.0) if pose_only else (vx[i], vy[i], w[i])
            stamp = t[i] + odom_late
            inputs.append((stamp, 'odom', T.OdomSample(stamp, x[i], y[i], yaw[i], *twist)))
    inputs.sort(key=lambda row: row[0])
    truth = np.column_stack((t, x, y, yaw, vx, vy))
    return truth, [(key, sample) for _, key, sample in inputs]


def _fuse(inputs, **params):
    """Return the fused odometry (rows t, x, y, yaw, vx, vy) and the pipeline."""
    pipe = FusionPipeline(FusionParams(**params))
    rows = []
    for key, sample in inputs:
        for out_key, out in pipe.process(key, sample):
            if out_key == 'odom':
                rows.append((out.t, out.x, out.y, out.yaw, out.vx, out.vy))
    return np.array(rows), pipe


def _at(truth, t):
    """Return the truth row nearest ``t`` (s)."""
    return truth[min(np.searchsorted(truth[:, 0], t), len(truth) - 1)]


@pytest.mark.parametrize('pose_only', [False, True])
def test_fusion_follows_a_sideways_slide(pose_only):
    truth, inputs = holonomic_drive(pose_only=pose_only)
    est, pipe = _fuse(inputs)
    after_slide = est[np.searchsorted(est[:, 0], 14.0)]
    assert after_slide[2] == pytest.approx(_at(truth, after_slide[0])[2], abs=0.05)  # 4.5 m
    assert np.hypot(*(est[-1, 1:3] - truth[-1, 1:3])) < 0.1
    mid = est[np.searchsorted(est[:, 0], 20.0)]
    assert mid[5] == pytest.approx(-0.3, abs=0.02)  # the sideways speed is published
    # the slide is motion: no standstill update taught the gyro bias from it
    result = pipe.estimator.result()
    assert abs(result.estimates['gyro_bias']) < 0.002
    assert result.counts['odometry_sideways'] > 200


def test_fusion_carries_the_sideways_speed_over_an_odometry_delay():
    truth, inputs = holonomic_drive(odom_late=0.2)
    est, _ = _fuse(inputs, odometry_delay=0.2)
    assert np.hypot(*(est[-1, 1:3] - truth[-1, 1:3])) < 0.1
    # within the slide, the estimate carried to the odometry's stamp is 0.2 s further on
    row = est[np.searchsorted(est[:, 0], 8.0)]
    assert row[2] == pytest.approx(_at(truth, row[0])[2], abs=0.05)


def test_constant_motion_deskews_a_sideways_speed():
    points = np.array([[2.0, 0.0], [0.0, 3.0]])
    dt = np.array([0.1, 0.05])
    moved = constant_motion(0.0, 0.0, 0.5).apply(points, dt)
    assert np.allclose(moved, [[2.0, 0.05], [0.0, 3.025]])
    assert np.allclose(constant_motion(0.2, 0.0, -0.5)(dt), [[0.02, -0.05, 0.0],
                                                             [0.01, -0.025, 0.0]])


def _wheel_verdict(inputs):
    from robot_calib.methods.wheel_odometry_calibration.params import WheelCalibParams
    from robot_calib.methods.wheel_odometry_calibration.pipeline import \
        WheelCalibrationPipeline
    pipe = WheelCalibrationPipeline(WheelCalibParams(drive_type='differential'))
    for key, sample in inputs:
        pipe.process(key, sample)
    pipe.finish()
    return pipe.result.verdict


def test_wheel_calibration_refuses_a_holonomic_odometry():
    _, inputs = holonomic_drive()
    verdict = _wheel_verdict([(k, s) for k, s in inputs if k == 'odom'])
    assert 'sideways' in verdict and 'holonomic' in verdict


@pytest.mark.parametrize('scenario, rate', [('diff_segments', 50.0), ('agv_segments', 10.0)])
def test_wheel_calibration_takes_rolling_odometry_as_rolling(scenario, rate):
    """Differential and steered drives, their odometry at 50 and 10 Hz: no sideways motion."""
    from robot_calib.sim import run_scenario
    res = run_scenario(scenario, seed=2, duration=60.0, overrides={'odom.rate': rate})
    odom = [('odom', s) for topic, s in res.messages if topic == '/odom']
    assert 'sideways' not in _wheel_verdict(odom)
    # the same odometry with a sideways slip of 0.2 m/s added is told
    slid = [(k, dataclasses.replace(s, x=s.x - 0.2 * s.t * math.sin(s.yaw),
                                    y=s.y + 0.2 * s.t * math.cos(s.yaw))) for k, s in odom]
    assert 'sideways' in _wheel_verdict(slid)


def test_replay_of_a_holonomic_bag(tmp_path):
    """The bag round trip keeps the sideways speed, in and out of the fusion node."""
    from robot_calib.io.bags import BagWriter, read_messages
    from robot_calib.replay import replay
    truth, inputs = holonomic_drive()
    bag = tmp_path / 'holonomic'
    base = 10 ** 9
    with BagWriter(bag) as w:
        for key, s in inputs:
            ns = base + int(round(s.t * 1e9))
            w.write('/imu' if key == 'imu' else '/odom', dataclasses.replace(s, stamp_ns=ns), ns)
    summary = replay(bag, tmp_path / 'out', nodes='odometry_fusion', progress=False,
                     plots=False)
    fused = [s for m in read_messages([tmp_path / 'out' / 'output.mcap'],
                                      topics=['/odometry/fused']) for s in m.samples]
    end = fused[-1]
    assert math.hypot(end.x - truth[-1, 1], end.y - truth[-1, 2]) < 0.1
    assert min(s.vy for s in fused) == pytest.approx(-0.3, abs=0.02)
    assert summary['nodes']['odometry_fusion']['inputs']['odom']['accepted'] == 641
