# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Tilt detection on inputs read through: units out, repeated mountings, rejections in every path.

Before: ``tilt/imu`` carried an IMU's acceleration in g (labelled base_link when
mounted) right after saying it multiplies by 9.81; a mounting from /tf_static
that was not exactly unit length was applied and logged again on every
/tf_static message; an all-zero accelerometer as the first sample crashed a
batch run (only the live pipeline rejected it).
"""

import dataclasses
import math

import numpy as np
import pytest

from robot_calib.core import types as T
from robot_calib.core.constants import GRAVITY
from robot_calib.core.estimator import run_batch
from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix, rotation_angle, \
    same_rotation
from robot_calib.methods.tilt_detection.params import ImprovedFilterParams, TiltParams
from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
from robot_calib.methods.tilt_detection.quaternion import qnorm
from robot_calib.methods.tilt_detection.variants import make_estimator, track

MODES = ['improved', 'seed']


def _level(n=300, accel=(0.0, 0.0, GRAVITY), frame='imu_link', rate=200.0):
    """Return ``n`` samples of a still IMU reading ``accel`` (any unit), with a little noise."""
    rng = np.random.default_rng(0)
    return [T.ImuSample(i / rate, rng.normal(0.0, 1e-3, 3),
                        np.asarray(accel, dtype=float) * (1.0 + rng.normal(0.0, 1e-3)), frame,
                        accel_cov=np.eye(3) * 1e-4, stamp_ns=int(round(i / rate * 1e9)))
            for i in range(n)]


def _tilt_imu(outs):
    return [o for k, o in outs if k == 'imu']


# -- 1. tilt/imu in m/s^2, also from an IMU in g -------------------------------------------------
@pytest.mark.parametrize('mode', MODES)
@pytest.mark.parametrize('mounting', [(0.0, 0.0, 0.0), (0.0, 0.0, math.pi / 2)])
def test_tilt_imu_carries_mps2_from_an_imu_in_g(mode, mounting):
    """The same IMU read in g and in m/s^2 publishes the same specific force (m/s^2)."""
    out = {}
    for units, k in (('mps2', 1.0), ('g', 1.0 / GRAVITY)):
        samples = [dataclasses.replace(s, accel=s.accel * k, accel_cov=s.accel_cov * k * k)
                   for s in _level()]
        pipe = TiltPipeline(TiltParams(mode=mode, mounting_rpy=list(mounting)))
        out[units] = _tilt_imu([o for s in samples for o in pipe.process('imu', s)])
        assert pipe.summary()['accel_units'] == 'detected_' + units
    assert len(out['g']) == len(out['mps2']) == 300
    for a, b in zip(out['g'], out['mps2']):
        assert a.frame_id == b.frame_id
        np.testing.assert_allclose(a.accel, b.accel, rtol=1e-12, atol=1e-12)
        if b.accel_cov is not None:
            np.testing.assert_allclose(a.accel_cov, b.accel_cov, rtol=1e-12)
    assert abs(out['g'][-1].accel[2] - GRAVITY) < 0.1


@pytest.mark.parametrize('mode', MODES)
def test_replay_of_an_imu_in_g_mounted_by_tf_static_publishes_mps2_in_base_link(tmp_path, mode):
    """An IMU rolled 90 deg, reading g: tilt/imu says 9.81 m/s^2 up in base_link."""
    from robot_calib.io.bags import BagWriter, read_messages
    from robot_calib.replay import replay
    q = quat_from_rpy(math.pi / 2, 0.0, 0.0)
    to_imu = quat_to_matrix(q).T                        # base_link -> IMU frame
    bag = tmp_path / 'in_g'
    with BagWriter(bag) as w:
        w.write('/tf_static', [T.StaticTransform('base_link', 'imu_link', np.zeros(3), q)],
                10 ** 9)
        for s in _level(accel=to_imu @ [0.0, 0.0, 1.0]):
            ns = 10 ** 9 + s.stamp_ns
            w.write('/imu', dataclasses.replace(s, t=ns * 1e-9, stamp_ns=ns), ns)
    summary = replay(bag, tmp_path / 'out', nodes='tilt_detection', progress=False,
                     plots=False, overrides=[f'tilt_detection.mode={mode}'])
    node = summary['nodes']['tilt_detection']
    assert node['accel_units'] == 'detected_g' and node['mounting'] == '/tf_static'
    imu = [s for m in read_messages([tmp_path / 'out' / 'output.mcap'], ['/tilt/imu'])
           for s in m.samples]
    assert len(imu) == 300 and {s.frame_id for s in imu} == {'base_link'}
    a = np.array([s.accel for s in imu])
    np.testing.assert_allclose(np.median(a, axis=0), [0.0, 0.0, GRAVITY], atol=0.05)


# -- 2. a mounting is a rotation: the same one is not applied again ------------------------------
def test_same_rotation_compares_rotations():
    q = quat_from_rpy(0.3, -0.2, 1.1)
    assert same_rotation(q, -q) and same_rotation(q, 2.5 * q)
    assert same_rotation((0.7071, 0.0, 0.0, 0.7071), quat_from_rpy(0.0, 0.0, math.pi / 2))
    assert not same_rotation(q, quat_from_rpy(0.3, -0.2, 1.1 + 1e-5))
    assert rotation_angle(q, quat_from_rpy(0.3, -0.2, 1.1 + 1e-8)) == pytest.approx(1e-8, 1e-6)
    assert rotation_angle((1.0, 0, 0, 0), (0.0, 1.0, 0, 0)) == pytest.approx(math.pi)
    assert rotation_angle(quat_from_rpy(0.0, 0.0, 0.5), -quat_from_rpy(0.0, 0.7, 0.5)) == \
        pytest.approx(0.7)
    for bad in ((0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0), (math.inf, 0.0, 0.0, 0.0)):
        assert not same_rotation(bad, bad) and not same_rotation(q, bad)


ROLL_125 = tuple(float(v) for v in quat_from_rpy(math.radians(125.0), 0.0, 0.0))


@pytest.mark.parametrize('mode', MODES)
@pytest.mark.parametrize('rotation', [(0.7071, 0.0, 0.0, 0.7071), ROLL_125],
                         ids=['hand_typed', 'roll_125'])
def test_a_mounting_sent_again_is_applied_and_logged_once(mode, rotation):
    """/tf_static five times with a rotation whose normalised form differs in the last bits."""
    assert qnorm(rotation) != rotation  # what made it look new every time
    logs = []
    pipe = TiltPipeline(TiltParams(mode=mode), log=lambda level, msg: logs.append(msg))
    samples = _level(500)
    tf = T.StaticTransform('base_link', 'imu_link', np.zeros(3), np.array(rotation))
    for i, s in enumerate(samples):
        if i % 100 == 0:
            again = tf if i % 200 == 0 else dataclasses.replace(tf, rotation=-tf.rotation)
            pipe.process('tf_static', again)
        pipe.process('imu', s)
    assert pipe.est.result().mounting_updates == 1
    assert len([m for m in logs if m.startswith('IMU mounting from /tf_static')]) == 1
    # a mounting that does change is still taken
    pipe.process('tf_static', dataclasses.replace(tf, rotation=quat_from_rpy(0.0, 0.0, 0.1)))
    assert pipe.est.result().mounting_updates == 2


@pytest.mark.parametrize('rotation', [(0.7071, 0.0, 0.0, 0.7071), ROLL_125],
                         ids=['hand_typed', 'roll_125'])
def test_fusion_takes_a_mounting_sent_again_once(rotation):
    """Fusion set and announced its IMU extrinsic again for every /tf_static transform."""
    from robot_calib.methods.odometry_fusion.params import FusionParams
    from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
    logs = []
    pipe = FusionPipeline(FusionParams(), log=lambda level, msg: logs.append(msg))
    tf = T.StaticTransform('base_link', 'imu_link', np.zeros(3), np.array(rotation))
    laser = T.StaticTransform('base_link', 'laser', np.zeros(3), np.array([1.0, 0, 0, 0]))
    for i, s in enumerate(_level(500)):
        if i % 100 == 0:
            pipe.process('tf_static', tf if i % 200 == 0 else
                         dataclasses.replace(tf, rotation=-tf.rotation))
            pipe.process('tf_static', laser)
        pipe.process('imu', s)
    said = [m for m in logs if m.startswith('IMU extrinsic from /tf_static')]
    assert len(said) == 1
    pipe.process('tf_static', dataclasses.replace(tf, rotation=quat_from_rpy(0.0, 0.0, 0.1)))
    assert len([m for m in logs if m.startswith('IMU extrinsic from /tf_static')]) == 2


# -- 3. every path rejects what the live one rejects ---------------------------------------------
@pytest.mark.parametrize('mode', MODES)
def test_an_all_zero_first_sample_is_rejected_in_a_batch_run(mode):
    """Before: ZeroDivisionError in the improved filter's start-up."""
    samples = _level(200)
    t = np.array([s.t for s in samples])
    gyro = np.array([s.gyro for s in samples])
    accel = np.array([s.accel for s in samples])
    accel[0] = 0.0
    params = TiltParams(mode=mode)
    out = track(t, gyro, accel, params)
    rest = track(t[1:], gyro[1:], accel[1:], params)
    assert np.isnan(out['quat'][0]).all() and np.isnan(out['tilt'][0])
    for key in ('quat', 'tilt', 'alert', 'rest', 'bias'):
        assert np.array_equal(out[key][1:], rest[key]), key
    batch = run_batch(make_estimator(params), [dataclasses.replace(samples[0], accel=accel[0])]
                      + samples[1:])
    assert batch.result.rejected == {'accel_zero': 1} and len(batch.outputs) == 199


def _bad_inputs():
    """Return samples with every kind of value and stamp the live pipeline turns down."""
    samples = _level(120)
    bad = {5: {'accel': np.zeros(3)}, 9: {'gyro': np.array([math.nan, 0.0, 0.0])},
           13: {'accel': np.array([0.0, math.inf, 9.8])}, 17: {'accel': np.array([0, 0, 200.0])},
           21: {'gyro': np.array([0.0, 40.0, 0.0])}, 40: {'accel': np.full(3, 1e-7)}}
    out = []
    for i, s in enumerate(samples):
        out.append(dataclasses.replace(s, **bad.get(i, {})))
        if i == 30:
            out.append(s)                                            # the same stamp again
        if i == 50:
            out.append(dataclasses.replace(samples[45], accel=s.accel))  # 25 ms back
    return out


@pytest.mark.parametrize('mode', MODES)
def test_batch_and_live_reject_the_same_samples(mode):
    samples = _bad_inputs()
    params = TiltParams(mode=mode)
    pipe = TiltPipeline(params)
    live = _tilt_imu([o for s in samples for o in pipe.process('imu', s)])
    counts = pipe.summary()['inputs']['imu']
    rejected = {k[len('rejected_'):]: v for k, v in counts.items() if k.startswith('rejected_')}
    batch = run_batch(make_estimator(params), samples)
    assert rejected == batch.result.rejected == {
        'accel_zero': 2, 'non_finite': 2, 'accel_out_of_range': 1, 'gyro_out_of_range': 1,
        'duplicate_stamp': 1, 'out_of_order': 1}
    assert [o.t for o in live] == [s.t for s in batch.outputs]
    assert np.array_equal([o.orientation for o in live], [s.quat for s in batch.outputs])


# -- item 6: the bias-only Kalman filter (scale_estimation: false) --------------------------------
def test_bias_only_filter_learns_the_gyro_bias_of_a_drive():
    """
    ``scale_estimation: false`` is the VQF-structure filter: gyro bias only, no scale factors.

    On a simulated drive with a gyro bias it learns the bias as the default
    filter does (at rest and, about x and y, in motion) and leaves the scale at 0.
    """
    from robot_calib.sim import run_scenario
    bias = np.array([0.01, -0.02, 0.015])
    res = run_scenario('bumpy_drive', seed=2, duration=90.0,
                       overrides=['imu.gyro_bias=' + ','.join(map(str, bias)), 'lidar.rate=0.2'])
    inputs = [m for topic, m in res.messages if topic == '/imu'] + \
        [tf for topic, m in res.messages if topic == '/tf_static' for tf in m]
    inputs.sort(key=lambda s: (not isinstance(s, T.StaticTransform), s.t))

    def run(**kw):
        params = TiltParams(improved=ImprovedFilterParams(scale_estimation=False, **kw))
        return run_batch(make_estimator(params), inputs)

    only = run()
    assert only.result.scale == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(only.result.bias, bias, atol=1e-3)
    both = run_batch(make_estimator(TiltParams()), inputs)
    assert both.result.scale != (0.0, 0.0, 0.0)
    tilt_only = np.array([s.tilt for s in only.outputs])
    tilt_both = np.array([s.tilt for s in both.outputs])
    assert 0.0 < np.max(np.abs(tilt_only - tilt_both)) < math.radians(0.5)
    motion = run(rest_bias=False)                       # in motion: x and y, not z (level)
    np.testing.assert_allclose(motion.result.bias[:2], bias[:2], atol=3e-3)
    assert abs(motion.result.bias[2]) < 0.2 * abs(bias[2])
