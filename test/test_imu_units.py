# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
IMU units and axes the drivers get wrong, told from the data.

Tilt: before, an IMU in g tilted the same but judged rest against m/s^2
thresholds; an IMU whose driver took gravity out raised a fall alert 0.02 s into
a level drive and held it (tilt 90 deg), at full confidence. Fusion: a gyro in
deg/s re-initialised the filter 4852 times in 120 s and said only that.
"""

import dataclasses
import json
import math

import numpy as np
import pytest
from robot_calib.core.constants import GRAVITY
from robot_calib.methods.tilt_detection.params import TiltParams
from robot_calib.methods.tilt_detection.pipeline import TiltPipeline


@pytest.fixture(scope='module')
def drive():
    from robot_calib.sim import run_scenario
    return run_scenario('fusion_drive', seed=1, duration=120.0)


def _imu(drive, change=lambda a: a):
    return [dataclasses.replace(m, accel=change(np.asarray(m.accel, dtype=float)))
            for topic, m in drive.messages if topic == '/imu']


def _run(samples, **params):
    logs = []
    pipe = TiltPipeline(TiltParams(**params), log=lambda level, msg: logs.append((level, msg)))
    outs = [out for s in samples for out in pipe.process('imu', s)]
    return pipe, outs, logs


@pytest.mark.parametrize('mode', ['improved', 'seed'])
def test_gravity_removed_raises_no_alert_and_says_so(drive, mode):
    samples = _imu(drive, lambda a: a - np.array([0.0, 0.0, GRAVITY]))
    pipe, outs, logs = _run(samples, mode=mode)
    s = pipe.summary()
    assert s['accel_units'] == 'no_gravity' and s['alerts'] == 0
    assert s['max_tilt_deg'] is None and s['final_tilt_deg'] is None
    assert not any(o.value for k, o in outs if k == 'fall_alert')
    imu = [o for k, o in outs if k == 'imu']
    assert all(o.orientation_cov[0][0] == -1.0 for o in imu[10:])
    last = [o for k, o in outs if k == 'diagnostics'][-1].statuses[0]
    assert last.level == 2 and 'no gravity' in last.message
    assert [m for level, m in logs if level == 'error' and 'no gravity' in m]


@pytest.mark.slow
def test_an_imu_in_g_is_told_and_scaled(drive):
    ref, ref_outs, _ = _run(_imu(drive))
    pipe, outs, logs = _run(_imu(drive, lambda a: a / GRAVITY))
    assert ref.summary()['accel_units'] == 'detected_mps2'
    assert pipe.summary()['accel_units'] == 'detected_g'
    assert [m for level, m in logs if 'in g' in m]
    q_ref = np.array([o.orientation for k, o in ref_outs if k == 'imu'])
    q = np.array([o.orientation for k, o in outs if k == 'imu'])
    assert np.allclose(q, q_ref, atol=1e-9)
    # units given: no detection, the scale applied from the first sample
    given, given_outs, _ = _run(_imu(drive, lambda a: a / GRAVITY), accel_units='g')
    assert given.summary()['accel_units'] == 'g'
    assert np.allclose([o.orientation for k, o in given_outs if k == 'imu'], q_ref, atol=1e-9)


def test_undecided_units_hold_the_alert_until_the_median_says(drive):
    """A first reading far from gravity (a knock) waits for 10 samples, then decides."""
    samples = _imu(drive)
    samples[0] = dataclasses.replace(samples[0], accel=np.array([0.0, 0.0, 30.0]))
    pipe, outs, _ = _run(samples)
    assert pipe.summary()['accel_units'] == 'detected_mps2'
    assert pipe.summary()['alerts'] == 0


def test_replay_of_a_gravity_free_imu(tmp_path, drive):
    """End to end: summary, report and plots written; the warning in summary.json."""
    from robot_calib.io.bags import BagWriter
    from robot_calib.replay import replay
    bag = tmp_path / 'free'
    with BagWriter(bag) as w:
        for s in _imu(drive, lambda a: a - np.array([0.0, 0.0, GRAVITY])):
            ns = 10 ** 9 + int(round(s.t * 1e9))
            w.write('/imu', dataclasses.replace(s, stamp_ns=ns), ns)
    summary = replay(bag, tmp_path / 'out', nodes='tilt_detection', progress=False)
    node = summary['nodes']['tilt_detection']
    assert node['accel_units'] == 'no_gravity' and node['alerts'] == 0
    assert (tmp_path / 'out' / 'report.md').exists()
    assert json.loads((tmp_path / 'out' / 'summary.json').read_text())['nodes'][
        'tilt_detection']['max_tilt_deg'] is None


@pytest.mark.slow
def test_fusion_names_a_gyro_in_degrees(drive):
    from robot_calib.methods.odometry_fusion.params import FusionParams
    from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
    pipe = FusionPipeline(FusionParams())
    outs = []
    for topic, m in drive.messages:
        if topic == '/tf_static':
            for tf in m:
                pipe.on_static_transform(tf)
        elif topic == '/imu':
            outs += pipe.process('imu', dataclasses.replace(m, gyro=np.degrees(m.gyro)))
        elif topic == '/odom':
            outs += pipe.process('odom', m)
    said = [w for w in pipe.summary()['warnings'] if 'the gyro reads deg/s' in w]
    assert said and said[0].startswith('end: ')
    status = [o for k, o in outs if k == 'diagnostics'][-1].statuses[0]
    assert status.level == 2 and 'deg/s' in status.message


@pytest.mark.parametrize('scale, says', [
    (math.pi / 180 * 1.04, 'the gyro reads deg/s'), (180 / math.pi * 0.9, 'odometry yaw rate'),
    (-1.0, 'points down'), (0.82, ''), (1.04, ''), (0.1, '')])
def test_units_advice_from_the_yaw_rate_scale(scale, says):
    from robot_calib.methods.odometry_fusion.report import units_advice
    advice = units_advice({'status': 'ok', 'yaw_rate_scale': scale})
    assert (says in advice) if says else advice == ''
    assert units_advice({'status': 'too_little_motion', 'yaw_rate_scale': scale}) == ''


def _fuse(drive, gyro=None, imu=True):
    from robot_calib.methods.odometry_fusion.params import FusionParams
    from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
    pipe = FusionPipeline(FusionParams())
    last = None
    for topic, m in drive.messages:
        if topic == '/imu' and imu:
            pipe.process('imu', m if gyro is None else dataclasses.replace(m, gyro=gyro(m)))
        elif topic == '/odom':
            for key, out in pipe.process('odom', m):
                if key == 'odom':
                    last = out
    return pipe, last


@pytest.mark.slow
def test_fusion_does_not_take_an_all_zero_gyro_for_a_gyro(drive):
    """An IMU that fills no angular velocity: before, 'ok' with the pose driven straight."""
    pipe, last = _fuse(drive, gyro=lambda m: np.zeros(3))
    _, no_imu = _fuse(drive, imu=False)
    est = pipe.estimator
    assert est.zero_gyro.missing and est.counts['gyro_missing_periods'] == 1
    assert pipe.summary()['inputs']['imu']['rejected_no_angular_velocity'] > 10000
    assert any('angular velocity exactly 0' in w for w in pipe.summary()['warnings'])
    assert math.hypot(last.x - no_imu.x, last.y - no_imu.y) < 1.0   # the wheels alone
    # a driver's deadband (exact zeros below 0.01 rad/s) is a gyro all the same
    dead, _ = _fuse(drive, gyro=lambda m: np.where(np.abs(m.gyro) < 0.01, 0.0, m.gyro))
    assert not dead.estimator.counts.get('gyro_missing_periods')


@pytest.mark.slow
def test_loop_closure_does_not_take_an_all_zero_gyro_for_a_gyro():
    from robot_calib.methods.loop_closure_correction.params import LoopClosureParams
    from robot_calib.methods.loop_closure_correction.pipeline import LoopClosurePipeline
    from robot_calib.sim import run_scenario
    res = run_scenario('revisit', seed=1, duration=60.0)
    heading = {}
    for zero in (False, True):
        pipe = LoopClosurePipeline(LoopClosureParams())
        for topic, s in res.messages:
            key = topic.lstrip('/')
            if key == 'imu' and zero:
                s = dataclasses.replace(s, gyro=np.zeros(3))
            for one in (s if isinstance(s, list) else [s]):
                pipe.process(key, one)
        result = pipe.estimator.result()
        heading[zero] = (result.heading_source, result.counts.get('gyro_missing_periods'))
    assert heading == {False: ('imu', None), True: ('odom', 1)}


@pytest.mark.slow
def test_gyro_line_does_not_take_an_all_zero_gyro_for_a_gyro():
    """Before: 178 deg off after 150 s of a vacuum run (the zeros integrated as the heading)."""
    from robot_calib.methods.gyro_line_calibration.params import GyroLineParams
    from robot_calib.methods.gyro_line_calibration.variants import make_estimator
    from robot_calib.sim import run_scenario
    res = run_scenario('vacuum', seed=0, duration=150.0)
    core = make_estimator(GyroLineParams())
    t, heading = [], []
    for topic, s in res.messages:
        if topic == '/tf_static':
            for tf in s:
                core.set_mounting(tf)
        elif topic in ('/imu', '/odom', '/scan'):
            core.update(dataclasses.replace(s, gyro=np.zeros(3)) if topic == '/imu' else s)
            if topic == '/odom':
                t.append(s.t)
                heading.append(core.heading)
    gt = [s for topic, s in res.messages if topic == '/ground_truth/odom']
    true = np.interp(t, [s.t for s in gt], np.unwrap([s.yaw for s in gt]))
    err = np.degrees(np.abs(np.angle(np.exp(1j * (np.array(heading) - true)))))
    assert core.counts['gyro_missing_periods'] == 1
    assert err[-1] < 1.0 and np.median(err) < 1.0


def test_tilt_says_an_alert_from_the_first_samples_may_be_the_mounting():
    """
    An IMU on its side, no mounting given: the alert stands but says what else reads the same.

    (A robot on its back must raise it at once.) A later fall does not say it.
    """
    from robot_calib.core.types import ImuSample
    from robot_calib.sim import run_scenario
    pipe, outs, _ = _run([ImuSample(i * 0.005, np.zeros(3), np.array([0.0, 9.81, 0.0]))
                          for i in range(200)])
    s = pipe.summary()
    assert s['alerts'] == 1 and 'mounting' in s['mounting_caveat']
    assert 'mounting' in [o for k, o in outs if k == 'diagnostics'][-1].statuses[0].message
    tip = run_scenario('tip_over', seed=1, duration=30.0)
    later, _, _ = _run([m for topic, m in tip.messages if topic == '/imu'])
    assert later.summary()['alerts'] >= 1 and 'mounting_caveat' not in later.summary()


@pytest.mark.parametrize('norm, units', [
    (GRAVITY, 'mps2'), (1.0, 'g'), (6.0, ''), (14.0, ''), (1.4, ''), (0.6, ''), (0.05, '')])
def test_tilt_and_fusion_tell_the_units_by_one_rule(norm, units):
    """
    A level IMU reading |a| = ``norm``: both nodes say the same (core.imu_units).

    Before, fusion took 5-15 for m/s^2 and 0.5-1.5 for g, tilt 30 % around either:
    at 6 m/s^2 tilt said no gravity and fusion used the accelerometer.
    """
    from robot_calib.core.imu_units import accel_units_of
    from robot_calib.core.types import ImuSample
    from robot_calib.methods.odometry_fusion.params import FusionParams
    from robot_calib.methods.odometry_fusion.variants import make_estimator
    samples = [ImuSample(i * 0.01, np.zeros(3), np.array([0.0, 0.0, norm])) for i in range(30)]
    pipe, _, _ = _run(samples)
    fusion = make_estimator(FusionParams(imu_rpy=[0.0, 0.0, 0.1]))
    for s in samples:
        fusion.update(s)
    assert accel_units_of(norm) == units
    assert pipe.summary()['accel_units'] == ('detected_' + units if units else 'no_gravity')
    assert fusion.result().accel_units == ('detected_' + units if units else 'unknown')
