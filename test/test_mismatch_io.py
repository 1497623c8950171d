# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Mismatch analyser end to end: bags, the CLI verb, bad input and real-data slices."""

import json
from pathlib import Path
import sys

import numpy as np
import pytest

from robot_calib.core import types as T
from robot_calib.io.bags import BagWriter
from robot_calib.mismatch import analyse, analyse_recordings, MismatchError
from robot_calib.mismatch.channels import ChannelError, IMU_TYPE, ODOM_TYPE, Topic

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'benchmarks'))
import mismatch_suite as M  # noqa: E402,I100

FINDING_KEYS = {'channel', 'effect', 'parameters', 'window', 'fit', 'explanation'}
FIT_KEYS = {'rmse_before', 'rmse_after', 'heldout_rmse_before', 'heldout_rmse_after'}


@pytest.fixture(scope='module')
def pair_bags(tmp_path_factory):
    """Write a short generated pair with a concealed wheel-radius error as bags."""
    d = tmp_path_factory.mktemp('mm')
    eff = [{'effect': 'wheel_radius_scale', 'channel': '/odom.twist.twist.linear.x',
            'parameters': {'scale': 0.03}, 'window': None}]
    sim, real, truth = M.make_pair(21, duration=40.0, imu_rate=100.0, odom_rate=20.0,
                                   kind='mixed', effects=eff)
    M.write_bag(sim, d / 'sim')
    M.write_bag(real, d / 'real')
    return d, truth


def test_cli_end_to_end(pair_bags, capsys):
    from robot_calib import cli
    d, truth = pair_bags
    out = d / 'out_cli'
    rc = cli.main(['mismatch', '--sim', str(d / 'sim'), '--real', str(d / 'real'),
                   '--out', str(out)])
    assert rc == 0
    res = json.loads((out / 'findings.json').read_text())
    assert res['verdict'] == 'mismatch'
    for f in res['findings']:
        assert FINDING_KEYS <= set(f)
        assert FIT_KEYS <= set(f['fit'])
    top = res['findings'][0]
    assert top['effect'] == 'wheel_radius_scale'
    assert top['channel'] == '/odom.twist.twist.linear.x'
    assert top['parameters']['scale'] == pytest.approx(0.03, rel=0.1)
    assert top['fit']['heldout_rmse_after'] < 0.7 * top['fit']['heldout_rmse_before']
    report = (out / 'report.md').read_text()
    assert 'wheel_radius_scale' in report
    assert list(out.glob('*.png'))
    assert 'mismatch' in capsys.readouterr().out


def test_analyse_same_bag_is_consistent(pair_bags):
    d, _ = pair_bags
    res = analyse(d / 'sim', d / 'sim', d / 'out_same', plots=False)
    assert res['verdict'] == 'consistent' and res['findings'] == []


def test_missing_bag_is_a_clear_error(tmp_path):
    with pytest.raises(MismatchError, match='not found'):
        analyse(tmp_path / 'nope', tmp_path / 'nope2', tmp_path / 'out')
    from robot_calib import cli
    assert cli.main(['mismatch', '--sim', str(tmp_path / 'a'), '--real', str(tmp_path / 'b'),
                     '--out', str(tmp_path / 'o')]) == 2


def _write(path, items):
    with BagWriter(path) as w:
        for topic, s in items:
            w.write(topic, s)


def test_different_message_types_and_missing_topics(tmp_path):
    t = np.arange(0, 20, 0.02)
    imu = [('/imu', T.ImuSample(float(x), np.array([0, 0, np.sin(x)]), np.array([0, 0, 9.8])))
           for x in t]
    odom_on_imu = [('/imu', T.OdomSample(float(x), 0, 0, 0, vx=1.0, wz=np.sin(x))) for x in t]
    odom = [('/odom', T.OdomSample(float(x), 0, 0, 0, vx=1.0 + 0.1 * np.sin(x), wz=0.1))
            for x in t]
    _write(tmp_path / 'sim', imu + odom)
    _write(tmp_path / 'real', odom_on_imu + odom)
    res = analyse(tmp_path / 'sim', tmp_path / 'real', tmp_path / 'out', plots=False)
    reasons = {d['channel']: d['reason'] for d in res['not_judged']}
    assert 'different message types' in reasons['/imu']
    assert res['verdict'] == 'consistent'
    assert '/odom.twist.twist.linear.x' in res['channels']
    _write(tmp_path / 'real2', odom_on_imu[:10])
    with pytest.raises(MismatchError):
        analyse(tmp_path / 'sim', tmp_path / 'real2', tmp_path / 'out2', plots=False)


def _imu_rec(t, gz, az=None):
    f = {k: np.zeros_like(t) for k in ('angular_velocity.x', 'angular_velocity.y',
                                       'linear_acceleration.x', 'linear_acceleration.y')}
    f['angular_velocity.z'] = gz
    f['linear_acceleration.z'] = np.full_like(t, 9.81) if az is None else az
    return {'/imu': Topic('/imu', IMU_TYPE, t, f)}


def test_topic_missing_on_one_side_is_reported():
    t = np.arange(0, 30, 0.01)
    rng = np.random.default_rng(0)
    sim = _imu_rec(t, np.sin(t))
    sim['/odom'] = Topic('/odom', ODOM_TYPE, t[::4], {'twist.twist.linear.x': np.ones(750),
                                                      'twist.twist.angular.z': np.sin(t[::4])})
    real = _imu_rec(t, np.sin(t) + 0.01 * rng.standard_normal(t.size))
    res, _ = analyse_recordings(sim, real)
    assert {'channel': '/odom', 'reason': 'topic missing in the real recording'} in \
        res['not_judged']


def test_constant_and_empty_channels_cannot_be_judged():
    t = np.arange(0, 30, 0.01)
    rng = np.random.default_rng(1)
    sim = _imu_rec(t, np.sin(t))
    real = _imu_rec(t, np.zeros_like(t))  # stuck gyro
    real['/imu'].fields['linear_acceleration.z'] = 9.81 + 0.02 * rng.standard_normal(t.size)
    res, _ = analyse_recordings(sim, real)
    reasons = {d['channel']: d['reason'] for d in res['not_judged']}
    assert 'constant' in reasons['/imu.angular_velocity.z']
    assert not any(f['channel'] == '/imu.angular_velocity.z' for f in res['findings'])
    empty = {'/imu': Topic('/imu', IMU_TYPE, np.zeros(0), {})}
    with pytest.raises(ChannelError):
        analyse_recordings(sim, empty)


def test_no_motion_is_consistent_and_says_what_cannot_be_judged():
    t = np.arange(0, 60, 0.01)
    rng = np.random.default_rng(2)
    sim = _imu_rec(t, np.zeros_like(t))
    real = _imu_rec(t, 0.003 * rng.standard_normal(t.size),
                    9.81 + 0.02 * rng.standard_normal(t.size))
    res, _ = analyse_recordings(sim, real)
    assert res['verdict'] == 'consistent'
    assert any('does not rotate' in n for n in res['notes'])
    # a bias is still visible at rest
    real['/imu'].fields['angular_velocity.z'] += 0.01
    res, _ = analyse_recordings(sim, real)
    assert [f['effect'] for f in res['findings']] == ['gyro_bias']


def test_different_rates_and_lengths():
    eff = [{'effect': 'gyro_scale', 'channel': '/imu.angular_velocity.z',
            'parameters': {'scale': 0.04}, 'window': None}]
    sim, real, _ = M.make_pair(31, duration=60.0, imu_rate=100.0, kind='mixed', effects=eff)
    # the real IMU at 250 Hz and 10 s shorter
    sim2, real2, _ = M.make_pair(31, duration=60.0, imu_rate=250.0, kind='mixed', effects=eff)
    keep = real2['/imu'].t < 50.0
    real['/imu'] = Topic('/imu', IMU_TYPE, real2['/imu'].t[keep],
                         {k: v[keep] for k, v in real2['/imu'].fields.items()})
    res, _ = analyse_recordings(sim, real)
    assert any('different rates' in n for n in res['notes'])
    assert any('different lengths' in n for n in res['notes'])
    top = [f for f in res['findings'] if f['effect'] == 'gyro_scale']
    assert top and top[0]['parameters']['scale'] == pytest.approx(0.04, rel=0.1)


def test_broad_slice_finds_the_gyro_bias(shared_data):
    from robot_calib.io.datasets import broad
    import mismatch_protocols as P
    tr = broad.load_trial(shared_data / 'broad' / '10_undisturbed_slow_translation_A.npz')
    n = min(len(tr.t), int(60 * tr.fs))
    for k in ('t', 'gyr', 'acc', 'gt_quat', 'movement', 'pos'):
        setattr(tr, k, getattr(tr, k)[:n])
    sim, real = P.broad_pair(tr)
    res, _ = analyse_recordings(sim, real)
    g = np.column_stack([sim['/imu'].fields[f'angular_velocity.{a}'] for a in 'xyz'])
    rest = (np.linalg.norm(np.nan_to_num(g, nan=9.0), axis=1) < 0.05) & ~tr.movement
    ref = tr.gyr[rest].mean(axis=0)
    ax = int(np.argmax(np.abs(ref)))
    found = [f for f in res['findings'] if f['effect'] in ('gyro_bias', 'gyro_bias_drift')
             and f['channel'] == f'/imu.angular_velocity.{"xyz"[ax]}']
    assert found, res['findings']
    assert found[0]['parameters']['bias'] == pytest.approx(ref[ax], abs=0.0004)


def test_broad_translation_bandwidth_is_not_a_gyro_gain(shared_data):
    """Trial 10's x gyro follows the optical rates with a gain on fast motion only: not named."""
    from robot_calib.io.datasets import broad
    import mismatch_protocols as P
    tr = broad.load_trial(shared_data / 'broad' / '10_undisturbed_slow_translation_A.npz')
    res, _ = analyse_recordings(*P.broad_pair(tr))
    x = '/imu.angular_velocity.x'
    assert not [f for f in res['findings'] if f['channel'] == x and
                f['effect'] in ('gyro_scale', 'gyro_cross_axis')], res['findings']
    assert any(n.startswith(f'{x}: a candidate gyro_scale fits, but not as one gain')
               for n in res['notes'])


def test_ferraris_protocol_scale_and_bias(shared_data):
    from robot_calib.io.datasets import ferraris
    import mismatch_protocols as P
    rec = ferraris.load(shared_data / 'imucal')
    sim, real = P.ferraris_pair(rec)
    res, _ = analyse_recordings(sim, real)
    eff = {(f['effect'], f['channel']): f['parameters'] for f in res['findings']}
    sx = eff.get(('gyro_scale', '/imu.angular_velocity.x'))
    assert sx is not None and 0.02 < sx['scale'] < 0.04
    assert any(e in ('accel_bias', 'imu_mounting_tilt') for e, _ in eff)


def test_project_simulator_pair_gyro_bias():
    sim_mod = pytest.importorskip('robot_calib.sim')
    from robot_calib.mismatch.channels import recording_from_samples
    base = {'imu.gyro_noise': '0.002', 'imu.accel_noise': '0.02'}
    plain = sim_mod.run_scenario('drive', seed=3, duration=60.0, overrides=dict(base))
    over = dict(base)
    over['imu.gyro_bias'] = '[0.004, -0.003, 0.0]'
    real = sim_mod.run_scenario('drive', seed=3, duration=60.0, overrides=over)
    diff = np.array(real.truth['gyro_bias']) - np.array(plain.truth['gyro_bias'])
    drop = ('/ground_truth/odom',)
    res, _ = analyse_recordings(
        recording_from_samples([m for m in plain.messages if m[0] not in drop]),
        recording_from_samples([m for m in real.messages if m[0] not in drop]))
    found = {f['channel']: f['parameters']['bias'] for f in res['findings']
             if f['effect'] == 'gyro_bias'}
    for ax, d in zip('xyz', diff):
        ch = f'/imu.angular_velocity.{ax}'
        if abs(d) > 1e-3:
            assert found.get(ch) == pytest.approx(d, rel=0.1), res['findings']
        else:
            assert ch not in found


def test_renamed_topic_is_paired_by_type():
    t = np.arange(0, 30, 0.01)
    rng = np.random.default_rng(3)
    sim = _imu_rec(t, np.sin(t))
    real = _imu_rec(t, np.sin(t) + 0.01 + 0.005 * rng.standard_normal(t.size))
    real = {'/imu/data': Topic('/imu/data', IMU_TYPE, t, real['/imu'].fields)}
    res, _ = analyse_recordings(sim, real)
    assert any('/imu/data' in n for n in res['notes'])
    assert [f['effect'] for f in res['findings']] == ['gyro_bias']
