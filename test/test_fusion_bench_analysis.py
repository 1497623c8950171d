# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The fusion benchmark's analysis: hindsight bounds and sensor evidence on a synthetic drive."""

from pathlib import Path
import sys

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'benchmarks'))

import fusion_analysis as FA  # noqa: E402,I100

GYRO_BIAS = 0.0015
"""True gyro z bias of the synthetic drive (rad/s)."""
WHEEL_SCALE = 1.03
"""The synthetic wheels over-read the speed by 3 %: true / wheel = 1 / 1.03."""


def synthetic_drive(seed: int = 0):
    """
    Return (gyro (t, rad/s), accel (t, m/s^2), wheels (t, v, w), reference (t, x, y)).

    A 300-s drive of straights, stops and arcs; the reference is the true position
    at 2 Hz with 0.3 m of noise (a GPS).
    """
    rng = np.random.default_rng(seed)
    dt = 0.02
    t = np.arange(0.0, 300.0, dt)
    v_cmd = np.zeros_like(t)
    w_cmd = np.zeros_like(t)
    seg = 5.0
    while seg < t[-1]:
        length = rng.uniform(8.0, 20.0)
        m = (t >= seg) & (t < seg + length)
        v_cmd[m] = rng.choice([0.0, 0.6, 1.0])
        w_cmd[m] = rng.choice([0.0, 0.0, 0.3, -0.3]) * (v_cmd[m] > 0)
        seg += length
    v, w = np.zeros_like(t), np.zeros_like(t)
    for i in range(1, len(t)):  # first-order response, 0.5 s
        v[i] = v[i - 1] + dt / 0.5 * (v_cmd[i] - v[i - 1])
        w[i] = w[i - 1] + dt / 0.5 * (w_cmd[i] - w[i - 1])
    yaw = np.cumsum(w) * dt
    x = np.cumsum(v * np.cos(yaw)) * dt
    y = np.cumsum(v * np.sin(yaw)) * dt
    gyro = np.column_stack([t, w + GYRO_BIAS + rng.normal(0, 0.002, len(t))])
    accel = np.column_stack([t, np.gradient(v, dt) + 0.05 + rng.normal(0, 0.02, len(t))])
    k = slice(None, None, 5)
    wheels = np.column_stack([t[k], v[k] * WHEEL_SCALE, w[k]])
    r = slice(None, None, 25)
    ref = np.column_stack([t[r], x[r] + rng.normal(0, 0.3, len(t[r])),
                           y[r] + rng.normal(0, 0.3, len(t[r]))])
    return gyro, accel, wheels, ref


def test_hindsight_bounds_recover_the_true_bias_and_wheel_speed_scale():
    gyro, _, wheels, ref = synthetic_drive()
    bounds = FA.hindsight_bounds(gyro, wheels[:, :2], ref)
    both = bounds['bias_scale']
    assert both['bias'] == pytest.approx(GYRO_BIAS, abs=1e-4)
    assert both['scale'] == pytest.approx(1 / WHEEL_SCALE, abs=0.005)
    assert both['ate'] < 0.5 < bounds['bias']['ate']  # the scale matters on this drive
    assert bounds['bias']['scale'] == 1.0


def test_standstill_bias_and_accelerometer_speed_ratio_tell_the_truth_on_flat_ground():
    gyro, accel, wheels, _ = synthetic_drive()
    bias, sem, first, still = FA.standstill_gyro_bias(gyro, wheels)
    assert bias == pytest.approx(GYRO_BIAS, abs=4 * sem + 1e-5)
    assert first == pytest.approx(0.5, abs=0.1) and still > 4.0
    events = FA.accel_speed_events(accel, wheels[:, :2])
    assert len(events) >= 5
    ratio = float(np.median([e[3] for e in events]))
    # within 3 %: the settling tail of each speed change (0.5 s time constant here) leaks a
    # little acceleration into the baseline after it (about 1.5 % on this drive)
    assert ratio == pytest.approx(1 / WHEEL_SCALE, abs=0.03)
    # a slope reached early in each speed change (0.3 m/s^2 of g sin(pitch)) spoils the ratio
    tilted = accel.copy()
    for ta, dur, *_ in events:
        tilted[tilted[:, 0] > ta + dur / 4, 1] += 0.3
    spoilt = [e[3] for e in FA.accel_speed_events(tilted, wheels[:, :2])]
    assert max(abs(r - 1 / WHEEL_SCALE) for r in spoilt) > 0.1


def test_dead_reckoning_applies_the_bias_only_from_its_time():
    gyro = np.column_stack([np.arange(0.0, 10.0, 0.1), np.full(100, 0.01)])
    wheels = np.column_stack([np.arange(0.0, 10.0, 0.1), np.ones(100)])
    full = FA.dead_reckoning(gyro, wheels, 0.01)
    late = FA.dead_reckoning(gyro, wheels, 0.01, bias_until=5.0)
    assert abs(full['yaw'][-1]) < 1e-12
    assert late['yaw'][-1] == pytest.approx(0.01 * 5.0, abs=0.002)
