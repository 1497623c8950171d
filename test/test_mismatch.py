# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Tests of the mismatch analyser's core: effect models, detectors, selection, abstention."""

from pathlib import Path
import sys

import numpy as np
import pytest

from robot_calib.core.constants import GRAVITY
from robot_calib.mismatch import analyse_recordings
from robot_calib.mismatch.align import xcorr_lag
from robot_calib.mismatch.channels import (IMU_FIELDS, IMU_TYPE, loo_derivative, ODOM_FIELDS,
                                           ODOM_TYPE, regressor_signal, Topic)
from robot_calib.mismatch.effects import tilt_rotate
from robot_calib.mismatch.locate import active_windows, noise_level, scan_window

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'benchmarks'))
import mismatch_suite as M  # noqa: E402,I100


def _smooth_run(duration=120.0, rate=100.0, odom_rate=50.0):
    """Return a noiseless, smooth simulated recording (sinusoidal driving)."""
    t = np.arange(0.0, duration, 1.0 / rate)
    w = 0.6 * np.sin(0.21 * t) + 0.3 * np.sin(0.73 * t + 1.0)
    v = 0.5 + 0.3 * np.sin(0.13 * t)
    a = np.gradient(v, t)
    imu = {IMU_FIELDS[0]: 0.05 * np.sin(1.7 * t), IMU_FIELDS[1]: 0.04 * np.cos(1.3 * t),
           IMU_FIELDS[2]: w, IMU_FIELDS[3]: a, IMU_FIELDS[4]: np.zeros_like(t),
           IMU_FIELDS[5]: GRAVITY + 0.2 * np.sin(2.1 * t)}
    to = np.arange(0.0, duration, 1.0 / odom_rate)
    odom = {ODOM_FIELDS[0]: np.interp(to, t, v), ODOM_FIELDS[1]: np.interp(to, t, w)}
    tc = np.arange(0.0, duration, 0.1)
    cmd = {'linear.x': np.interp(tc, t, v), 'angular.z': np.interp(tc, t, w)}
    return {'/imu': Topic('/imu', IMU_TYPE, t, imu), '/odom': Topic('/odom', ODOM_TYPE, to, odom),
            '/cmd_vel': Topic('/cmd_vel', 'geometry_msgs/msg/Twist', tc, cmd)}


def _copy(rec):
    return {k: Topic(v.name, v.msgtype, v.t.copy(), {f: x.copy() for f, x in v.fields.items()})
            for k, v in rec.items()}


def _apply(sim, effect, p):
    """Apply an effect model of the contract table to a copy of ``sim``."""
    real = _copy(sim)
    imu, odom = real['/imu'].fields, real['/odom'].fields
    t = real['/imu'].t
    if effect == 'gyro_bias':
        imu['angular_velocity.z'] += p['bias']
    elif effect == 'gyro_scale':
        imu['angular_velocity.z'] *= 1 + p['scale']
    elif effect == 'gyro_bias_drift':
        imu['angular_velocity.z'] += p['bias'] + p['drift'] * t
    elif effect == 'time_offset':
        for f in IMU_FIELDS:
            imu[f] = np.interp(t - p['tau'], t, sim['/imu'].fields[f])
        # the real recording covers only times the shifted simulation covers
        keep = (t - p['tau'] >= t[0]) & (t - p['tau'] <= t[-1])
        real['/imu'] = Topic('/imu', IMU_TYPE, t[keep], {f: x[keep] for f, x in imu.items()})
    elif effect == 'accel_bias':
        imu['linear_acceleration.x'] += p['bias']
    elif effect == 'centripetal_acceleration':
        v = np.interp(t, sim['/odom'].t, sim['/odom'].fields[ODOM_FIELDS[0]])
        imu['linear_acceleration.y'] += p['gain'] * v * imu['angular_velocity.z']
    elif effect == 'imu_mounting_tilt':
        fx, fy, fz = IMU_FIELDS[3:]
        imu[fx], imu[fy], imu[fz] = tilt_rotate(imu[fx], imu[fy], imu[fz], p['roll'],
                                                p['pitch'])
    elif effect == 'wheel_radius_scale':
        odom[ODOM_FIELDS[0]] *= 1 + p['scale']
    elif effect == 'track_width_scale':
        odom[ODOM_FIELDS[1]] /= 1 + p['scale']
    elif effect == 'wheel_slip':
        c = sim['/cmd_vel']
        a = np.interp(real['/odom'].t, c.t, np.gradient(c.fields['linear.x'], c.t))
        odom[ODOM_FIELDS[0]] *= 1 + p['coefficient'] * a
    return real


CASES = [('gyro_bias', {'bias': 0.01}), ('gyro_scale', {'scale': 0.03}),
         ('gyro_bias_drift', {'bias': 0.002, 'drift': 1e-4}), ('time_offset', {'tau': 0.03}),
         ('time_offset', {'tau': -0.004}), ('accel_bias', {'bias': 0.1}),
         ('centripetal_acceleration', {'gain': 0.8}),
         ('imu_mounting_tilt', {'roll': 0.03, 'pitch': -0.02}),
         ('wheel_radius_scale', {'scale': 0.02}), ('track_width_scale', {'scale': 0.05}),
         ('wheel_slip', {'coefficient': 0.3})]


@pytest.mark.parametrize('effect,params', CASES)
def test_effect_recovered_exactly_on_noiseless_data(effect, params):
    sim = _smooth_run()
    real = _apply(sim, effect, params)
    out, _ = analyse_recordings(sim, real)
    assert out['verdict'] == 'mismatch'
    top = out['findings'][0]
    assert top['effect'] == effect
    for k, v in params.items():
        assert top['parameters'][k] == pytest.approx(v, rel=1e-4, abs=1e-9)
    assert top['window'] is None
    assert len(out['findings']) == 1


def test_identical_recordings_are_consistent():
    sim = _smooth_run(60.0)
    out, _ = analyse_recordings(sim, _copy(sim))
    assert out['verdict'] == 'consistent' and out['findings'] == []


def test_noise_level_white_and_coloured():
    rng = np.random.default_rng(1)
    x = 0.3 * rng.standard_normal(20000)
    s, phi = noise_level(x, np.ones(x.size, bool), 0.01)
    assert s == pytest.approx(0.3, rel=0.05)
    assert phi < 1.3
    y = np.convolve(x, np.ones(10) / np.sqrt(10), mode='same')  # correlated over 10 samples
    s2, phi2 = noise_level(y, np.ones(y.size, bool), 0.01)
    assert s2 == pytest.approx(0.3, rel=0.1)
    assert 5.0 < phi2 < 15.0


def test_scan_window_finds_a_step_in_the_residual():
    rng = np.random.default_rng(2)
    n = 6000
    r = 0.01 * rng.standard_normal(n)
    r[1500:4200] += 0.004
    X = np.ones((n, 1))
    i0, i1, d = scan_window([X], [r], [1.0 / 0.01 ** 2], 60)
    assert abs(i0 - 1500) < 60 and abs(i1 - 4200) < 60
    assert d > 100


def test_active_windows_on_crafted_residual():
    rng = np.random.default_rng(3)
    t = np.arange(0, 200, 0.01)
    r = 0.02 * rng.standard_normal(t.size)
    r[(t > 80) & (t < 120)] += 0.05 * np.sin(t[(t > 80) & (t < 120)])
    w = active_windows(t, r, np.ones(t.size, bool), 0.02, 1.0)
    assert len(w) == 1
    assert abs(w[0][0] - 80) < 6 and abs(w[0][1] - 120) < 6
    assert active_windows(t, 0.02 * rng.standard_normal(t.size), np.ones(t.size, bool),
                          0.02, 1.0) == []


def test_xcorr_lag_recovers_a_shift():
    t = np.arange(0, 60, 0.005)
    x = np.sin(0.9 * t) + 0.5 * np.sin(2.3 * t + 0.4) + 0.3 * np.sin(11.0 * t)
    y = np.interp(t - 0.0375, t, x)
    tau, gain = xcorr_lag({'a': x}, {'a': y}, 0.005, 0.5)
    assert tau == pytest.approx(0.0375, abs=0.005)
    assert gain > 0


def test_regressor_signal_leaves_smooth_signals_and_removes_own_noise():
    t = np.arange(0, 50, 0.01)
    x = np.sin(t)
    assert regressor_signal(x) is x
    rng = np.random.default_rng(4)
    n = rng.standard_normal(t.size) * 0.05
    xr = regressor_signal(x + n)
    assert xr is not x + n
    # the sample's own noise is not in its regressor value
    assert abs(np.corrcoef(xr - x, n)[0, 1]) < 0.03
    d = loo_derivative(2.0 * t, 0.01)
    assert np.allclose(d[3:-3], 2.0)


@pytest.mark.parametrize('seed', range(10))
def test_abstains_on_pure_noise(seed):
    sim, real, truth = M.make_pair(500 + seed, n_effects=0, duration=40.0)
    assert truth['effects'] == []
    out, _ = analyse_recordings(sim, real)
    assert out['verdict'] == 'consistent', out['findings']
    assert out['findings'] == []


def test_windowed_bias_found_with_window():
    eff = [{'effect': 'gyro_bias', 'channel': '/imu.angular_velocity.z',
            'parameters': {'bias': 0.01}, 'window': [20.0, 45.0]}]
    sim, real, truth = M.make_pair(11, duration=80.0, kind='mixed', effects=eff)
    out, _ = analyse_recordings(sim, real)
    f = [x for x in out['findings'] if x['effect'] == 'gyro_bias']
    assert f, out['findings']
    w = f[0]['window']
    assert w is not None and abs(w[0] - 20.0) < 2.0 and abs(w[1] - 45.0) < 2.0
    assert f[0]['parameters']['bias'] == pytest.approx(0.01, rel=0.1)
    lo, hi = f[0]['ci95']['bias']
    assert lo < 0.01 < hi or abs(f[0]['parameters']['bias'] - 0.01) < 0.001
    assert f[0]['fit']['heldout_rmse_after'] < f[0]['fit']['heldout_rmse_before']


def test_indistinguishable_effects_are_reported_as_alternatives():
    # nearly constant turn rate: an offset and a scale error look alike
    t = np.arange(0, 60, 0.01)
    w = 0.5 + 0.05 * np.sin(0.2 * t)
    rng = np.random.default_rng(5)
    fields = {f: np.zeros_like(t) for f in IMU_FIELDS}
    fields['angular_velocity.z'] = w
    fields['linear_acceleration.z'] = np.full_like(t, GRAVITY)
    sim = {'/imu': Topic('/imu', IMU_TYPE, t, fields)}
    real = _copy(sim)
    for f in IMU_FIELDS:
        real['/imu'].fields[f] = real['/imu'].fields[f] + 0.02 * rng.standard_normal(t.size)
    real['/imu'].fields['angular_velocity.z'] += 0.01
    out, _ = analyse_recordings(sim, real)
    f = [x for x in out['findings'] if x['channel'] == '/imu.angular_velocity.z']
    assert len(f) == 1
    names = {f[0]['effect']} | {a['effect'] for a in f[0].get('alternatives', [])}
    assert {'gyro_bias', 'gyro_scale'} <= names
    assert all(a['separating_motion'] for a in f[0]['alternatives'])
