# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Tests of the tilt estimator: seed filter steps, attitude estimator, fall detector."""

import math

import numpy as np
import pytest

from robot_calib.core.estimator import run_batch
from robot_calib.core.geometry import quat_multiply, quat_to_matrix
from robot_calib.core.types import ImuSample
from robot_calib.methods.tilt_detection import params as TL
from robot_calib.methods.tilt_detection.common import FallDetector
from robot_calib.methods.tilt_detection.seed import SeedKalmanAxis
from robot_calib.methods.tilt_detection.variants import make_estimator, track

G = 9.80665


# -- synthetic IMU from a known attitude trajectory -------------------------------------------
def _expq(v):
    """Return the quaternion of rotation vector v (rad)."""
    a = float(np.linalg.norm(v))
    if a < 1e-15:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate(([math.cos(a / 2)], math.sin(a / 2) * v / a))


def synth(rate_fn, t_end, fs=200.0, q0=(1.0, 0.0, 0.0, 0.0), lin_acc_fn=None,
          gyro_bias=(0.0, 0.0, 0.0)):
    """
    Integrate body rates exactly (constant per sample); return t, gyro, accel, q_true.

    The gyro reading of sample k is the rate over (t_{k-1}, t_k], as the estimator assumes;
    the specific force is R(q_k)' (a_lin + g up).
    """
    n = int(round(t_end * fs)) + 1
    dt = 1.0 / fs
    t = np.arange(n) * dt
    q = np.array(q0, dtype=float)
    gyro = np.zeros((n, 3))
    acc = np.zeros((n, 3))
    qs = np.zeros((n, 4))
    for k in range(n):
        w = np.asarray(rate_fn(t[k]), dtype=float) if k > 0 else np.zeros(3)
        if k > 0:
            q = quat_multiply(q, _expq(w * dt))
            q /= np.linalg.norm(q)
        gyro[k] = w + np.asarray(gyro_bias)
        a_world = np.array([0.0, 0.0, G])
        if lin_acc_fn is not None:
            a_world = a_world + np.asarray(lin_acc_fn(t[k]))
        acc[k] = quat_to_matrix(q).T @ a_world
        qs[k] = q
    return t, gyro, acc, qs


def imu(t, gyro, accel):
    """Return one IMU sample (s, rad/s, m/s^2)."""
    return ImuSample(t, np.array(gyro, dtype=float), np.array(accel, dtype=float))


def incl_err_deg(q_est, q_true):
    """Return the inclination error (deg) per sample (BROAD metric)."""
    from robot_calib.io.datasets.broad import inclination_error
    return np.degrees(inclination_error(q_est, q_true))


# -- seed filter --------------------------------------------------------------------------------
def test_seed_axis_first_step_by_hand():
    f = SeedKalmanAxis(0.001, 0.0005, 0.03, angle0=0.0)
    angle = f.step(rate=1.0, z_angle=0.05, dt=0.01)
    # predict: angle 0.01, P = Q; K0 = 0.001 / 0.031; update with innovation 0.04
    assert angle == pytest.approx(0.01 + 0.001 / 0.031 * 0.04, abs=1e-12)
    assert f.x[1] == pytest.approx(0.0, abs=1e-15)
    assert f.P[0, 0] == pytest.approx(0.001 * (1 - 0.001 / 0.031), abs=1e-12)
    assert f.P[1, 1] == pytest.approx(0.0005, abs=1e-12)


def test_seed_axis_matches_matrix_equations():
    rng = np.random.default_rng(3)
    qa, qg, r = 0.001, 0.0005, 0.03
    f = SeedKalmanAxis(qa, qg, r, angle0=0.2)
    x = np.array([0.2, 0.0])
    P = np.zeros((2, 2))
    H = np.array([[1.0, 0.0]])
    for _ in range(50):
        dt = rng.uniform(0.002, 0.02)
        u = rng.normal(0.0, 0.5)
        z = rng.normal(0.1, 0.2)
        A = np.array([[1.0, -dt], [0.0, 1.0]])
        B = np.array([dt, 0.0])
        x = A @ x + B * u
        P = A @ P @ A.T + np.diag([qa, qg])
        K = P @ H.T / (H @ P @ H.T + r)
        x = x + (K * (z - H @ x)).ravel()
        P = (np.eye(2) - K @ H) @ P
        got = f.step(u, z, dt)
        assert got == pytest.approx(x[0], abs=1e-12)
        np.testing.assert_allclose(f.P, P, atol=1e-14)
    # the seed's bias state learns a constant gyro offset
    assert np.isfinite(f.x[1])


def test_seed_bias_state_converges():
    f = SeedKalmanAxis(0.001, 0.0005, 0.03, angle0=0.0)
    for _ in range(5000):
        f.step(rate=0.05, z_angle=0.0, dt=0.01)   # level, gyro reads a 0.05 rad/s bias
    assert f.x[1] == pytest.approx(0.05, abs=0.005)
    assert abs(f.x[0]) < 0.01


def test_seed_mode_fall_is_angle_outside_range():
    p = TL.TiltParams(mode='seed')
    est = make_estimator(p, 0.01)
    roll = math.radians(50.0)
    acc = (0.0, G * math.sin(roll), G * math.cos(roll))
    states = [est.update(imu(k * 0.01, (0.0, 0.0, 0.0), acc)) for k in range(10)]
    assert states[-1].alert
    assert states[-1].roll == pytest.approx(roll, abs=1e-6)


# -- improved estimator ---------------------------------------------------------------------
def test_improved_tracks_whole_sphere_rotation():
    # roll through 90, 180 and 270 deg and a pitch over the top, with a gyro bias
    def rate(t):
        if t < 2.0:
            return (0.0, 0.0, 0.0)
        if t < 10.0:
            return (0.8, 0.0, 0.3)
        if t < 14.0:
            return (0.0, 1.2, -0.2)
        return (0.0, 0.0, 0.0)
    t, gyro, acc, q = synth(rate, 20.0, gyro_bias=(0.002, -0.003, 0.001))
    out = track(t, gyro, acc)
    err = incl_err_deg(out['quat'], q)
    true_tilt = np.degrees(np.arccos(np.clip(1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2), -1, 1)))
    assert true_tilt.max() > 165.0          # really went (nearly) upside down
    assert np.max(err) < 1.5
    assert np.sqrt(np.mean(err ** 2)) < 0.5
    # the alert follows the truth (it is raised while tilted beyond 45 deg)
    assert out['alert'][(true_tilt > 60.0)].mean() > 0.95


def test_improved_at_rest_estimates_gyro_bias():
    bias = np.array([0.01, -0.02, 0.015])   # rad/s (0.6-1.1 deg/s)
    t, gyro, acc, q = synth(lambda t: (0.0, 0.0, 0.0), 30.0, gyro_bias=bias)
    rng = np.random.default_rng(0)
    gyro = gyro + rng.normal(0, 0.002, gyro.shape)
    acc = acc + rng.normal(0, 0.02, acc.shape)
    out = track(t, gyro, acc)
    np.testing.assert_allclose(out['bias'][-1], bias, atol=math.radians(0.05))


@pytest.mark.parametrize('spin', [0.3, 1.0])
def test_a_steady_spin_is_not_rest_and_its_rate_is_not_bias(spin):
    """
    Turning in place at a steady rate is steady, but not still (an audit's spin at 1 rad/s).

    Rest was rates near their own mean: a steady spin passed, and the rest
    update learned the turn rate as gyro bias (held at its 2 deg/s clip).
    """
    bias = np.array([0.002, -0.001, 0.002])
    t, gyro, acc, q = synth(lambda t: (0.0, 0.0, spin if t < 40.0 else 0.0), 50.0,
                            gyro_bias=bias)
    rng = np.random.default_rng(1)
    gyro = gyro + rng.normal(0, 0.002, gyro.shape)
    acc = acc + rng.normal(0, 0.02, acc.shape)
    out = track(t, gyro, acc)
    spinning = (t > 2.0) & (t < 40.0)
    assert not np.any(np.asarray(out['rest'])[spinning])
    assert np.max(np.abs(np.asarray(out['bias'])[spinning, 2] - bias[2])) < math.radians(0.2)
    assert np.any(np.asarray(out['rest'])[t > 45.0])   # still again: rest found


def test_improved_rejects_linear_acceleration():
    # level robot braking/accelerating at 3 m/s^2 back and forth, with turns
    def lin(t):
        return (3.0 * math.sin(2 * math.pi * 0.5 * t), 2.0 * math.sin(2 * math.pi * 0.3 * t), 0.0)
    t, gyro, acc, q = synth(lambda t: (0.0, 0.0, 0.5 * math.sin(t)), 60.0, lin_acc_fn=lin)
    out = track(t, gyro, acc)
    err = incl_err_deg(out['quat'], q)
    assert np.max(err[t > 10.0]) < 2.0
    assert np.sqrt(np.mean(err[t > 10.0] ** 2)) < 1.0
    assert not out['alert'].any()
    # the accelerometer alone would have seen up to 20 deg of tilt
    acc_tilt = np.degrees(np.arccos(acc[:, 2] / np.linalg.norm(acc, axis=1)))
    assert acc_tilt.max() > 15.0


def test_improved_starts_upside_down_and_on_the_side():
    for acc0, expect in (((0.0, 0.0, -G), 180.0), ((G, 0.0, 0.0), 90.0)):
        est = make_estimator(TL.TiltParams(), 0.005)
        s = [est.update(imu(k * 0.005, (0.0, 0.0, 0.0), acc0)) for k in range(10)]
        assert math.degrees(s[0].tilt) == pytest.approx(expect, abs=1e-6)
        assert s[-1].alert
        assert s[-1].t <= 0.05


def test_gap_restarts_filter_and_keeps_alert():
    est = make_estimator(TL.TiltParams(), 0.005)
    for k in range(100):
        est.update(imu(k * 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, -G)))
    assert est.result().alert
    s = est.update(imu(5.0, (0.0, 0.0, 0.0), (0.0, 0.0, -G)))   # a 4.5 s gap
    assert est.result().restarts == 1
    assert s.alert


def test_mounting_rotation_is_applied():
    # IMU mounted upside down (roll pi) on an upright robot: no alert
    p = TL.TiltParams(mounting_rpy=[math.pi, 0.0, 0.0])
    est = make_estimator(p, 0.005)
    s = [est.update(imu(k * 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, -G))) for k in range(50)]
    assert math.degrees(s[-1].tilt) < 1e-6
    assert not s[-1].alert


# -- fall detector --------------------------------------------------------------------------
def test_fall_detector_duration_hysteresis_and_clear():
    d = FallDetector(fall_angle=0.8, min_duration=0.02, clear_angle=0.7, clear_duration=1.0)
    assert d.update(0.000, 0.9) is None          # above, but not yet for 20 ms
    assert d.update(0.010, 0.9) is None
    assert d.update(0.015, 0.5) is None          # dips below: timer restarts
    assert d.update(0.020, 0.9) is None
    assert d.update(0.040, 0.9) is True          # 20 ms above
    assert d.update(0.500, 0.75) is None         # inside the hysteresis band: stays
    assert d.update(0.600, 0.6) is None          # below clear_angle: clear timer starts
    assert d.update(1.000, 0.75) is None         # back in the band: timer reset
    assert d.update(1.100, 0.6) is None
    assert d.update(2.050, 0.6) is None
    assert d.update(2.100, 0.6) is False         # 1.0 s below clear_angle
    assert d.episodes == 1 and not d.alert


def test_params_clear_angle_default_and_validation():
    p = TL.TiltParams()
    assert p.effective_clear_angle() == pytest.approx(math.pi / 4 - 0.0873)
    assert TL.TiltParams(fall_angle=1.0).effective_clear_angle() == pytest.approx(1.0 - 0.0873)
    with pytest.raises(ValueError):
        TL.TiltParams(fall_angle=0.5, clear_angle=0.6)
    with pytest.raises(ValueError):
        TL.TiltParams(mounting_rpy=[0.0, 0.0])


def test_rest_snap_recovers_after_missed_rotation():
    # the gyro missed a 90 deg roll (e.g. saturated): the accelerometer alone must fix it
    def tilt_after(snap_deg):
        p = TL.TiltParams(improved=TL.ImprovedFilterParams(rest_snap_angle=snap_deg))
        est = make_estimator(p, 0.005)
        for k in range(1000):                                    # 5 s upright at rest
            est.update(imu(k * 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, G)))
        s = None
        for k in range(800):                                     # 4 s on its side
            s = est.update(imu(5.0 + k * 0.005, (0.0, 0.0, 0.0), (0.0, G, 0.0)))
        return math.degrees(s.tilt), est.result().rest_snaps
    tilt, snaps = tilt_after(5.0)
    assert snaps >= 1 and tilt == pytest.approx(90.0, abs=1.0)
    tilt_off, snaps_off = tilt_after(0.0)
    assert snaps_off == 0 and tilt_off < 85.0


# -- the Estimator protocol ------------------------------------------------------------------
@pytest.mark.parametrize('mode', ['seed', 'improved'])
def test_variants_implement_the_estimator_protocol(mode):
    from dataclasses import FrozenInstanceError

    from robot_calib.core.estimator import Estimator
    from robot_calib.core.types import StaticTransform
    est = make_estimator(TL.TiltParams(mode=mode), 0.005)
    assert isinstance(est, Estimator)
    # an IMU mounted upside down, given by a static transform: upright, no alert
    est.set_mounting(StaticTransform('base_link', 'imu_link', np.zeros(3),
                                     np.array([0.0, 1.0, 0.0, 0.0])))
    run = run_batch(est, [imu(k * 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, -G)) for k in range(50)])
    r = run.result
    assert len(run.outputs) == 50 and r.samples == 50 and r.mode == mode
    assert r.mounting_source == '/tf_static' and r.imu_frame == 'imu_link'
    assert r.tilt < 1e-6 and not r.alert and r.alert_episodes == ()
    np.testing.assert_allclose(run.outputs[-1].accel, [0.0, 0.0, G], atol=1e-9)
    with pytest.raises(FrozenInstanceError):
        r.restarts = 3
    # reset forgets the state and keeps the mounting
    est.reset()
    assert est.result().samples == 0 and est.result().t is None
    s = est.update(imu(1.0, (0.0, 0.0, 0.0), (0.0, 0.0, -G)))
    assert s.tilt < 1e-6 and est.result().mounting_source == '/tf_static'


def test_alert_episodes_in_result():
    p = TL.TiltParams(clear_duration=0.1)
    est = make_estimator(p, 0.005)
    for k in range(40):
        est.update(imu(k * 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, -G)))
    r = est.result()
    assert r.alert and len(r.alert_episodes) == 1 and r.alert_episodes[0][1] is None
    assert r.max_tilt == pytest.approx(math.pi)
    for k in range(2000):
        est.update(imu(0.2 + k * 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, G)))
    r = est.result()
    assert not r.alert and r.alert_episodes[0][1] is not None
