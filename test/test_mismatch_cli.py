# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The mismatch tools end to end: ``robot-calib ideal`` and ``robot-calib mismatch`` on bags.

Pairing by ``--remap`` and across message types, clocks aligned from the motion,
a pair that cannot be aligned, the kernels travelling in a bag's metadata, and the
ideal sensors of known trajectories.
"""

import json

import numpy as np
import pytest

from robot_calib import cli
from robot_calib.core import types as T
from robot_calib.io.bags import BagWriter
from robot_calib.mismatch import analyse, MismatchError, read_bag
from robot_calib.mismatch.channels import KERNELS_KEY
from robot_calib.mismatch.derive import derive_recording, IdealParams, write_recording
from robot_calib.mismatch.ideal import ideal_imu


def _odom_items(topic, t, v, w, shift=0.0):
    return [(topic, T.OdomSample(float(x + shift), 0.0, 0.0, 0.0, vx=float(a), wz=float(b)))
            for x, a, b in zip(t, v, w)]


def _write(path, items):
    with BagWriter(path) as bag:
        for topic, s in sorted(items, key=lambda z: z[1].t):
            bag.write(topic, s)


def _drive(duration=90.0, rate=50.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate)
    steps = np.repeat(rng.uniform(-1.0, 1.0, t.size // 100 + 1), 100)[:t.size]
    v = 0.5 + 0.3 * np.convolve(steps, np.ones(25) / 25, 'same')
    w = 0.8 * np.convolve(np.roll(steps, 37), np.ones(25) / 25, 'same')
    return t, v, w


def test_ideal_then_mismatch_recovers_the_simulators_truth(tmp_path):
    sim_drive = pytest.importorskip('robot_calib.sim')
    bag = tmp_path / 'drive'
    sim_drive.simulate('drive', bag, seed=4, duration=80.0,
                       overrides={'imu.gyro_bias': '[0, 0, 0.01]',
                                  'wheels.track_width_error': '0.03'})
    truth = json.loads((tmp_path / 'drive.truth.json').read_text())
    assert cli.main(['ideal', str(bag), '--out', str(tmp_path / 'ideal')]) == 0
    assert cli.main(['mismatch', '--sim', str(tmp_path / 'ideal'), '--real', str(bag),
                     '--out', str(tmp_path / 'mm')]) == 0
    res = json.loads((tmp_path / 'mm' / 'findings.json').read_text())
    named = {(f['effect'], f['channel']): f['parameters'] for f in res['findings']}
    bias = named[('gyro_bias', '/imu.angular_velocity.z')]['bias']
    assert bias == pytest.approx(truth['gyro_bias_z'], rel=0.1)
    # odometry with the nominal track turns faster than the real, wider robot
    k = named[('track_width_scale', '/odom.twist.twist.angular.z')]['scale']
    expected = truth['nominal']['track_width'] / truth['track_width'] - 1.0
    assert k == pytest.approx(expected, abs=0.005)
    assert (tmp_path / 'mm' / 'report.md').read_text().count('The simulation left out') == 1


def test_remap_pairs_topics_the_names_do_not(tmp_path, capsys):
    t, v, w = _drive()
    _write(tmp_path / 'sim', _odom_items('/odom', t, v, w))
    _write(tmp_path / 'real', _odom_items('/wheel/odom', t, 1.03 * v, w) +
           _odom_items('/odometry/filtered', t, v, w))
    with pytest.raises(MismatchError, match='--remap /odom:=/wheel/odom'):
        analyse(tmp_path / 'sim', tmp_path / 'real', tmp_path / 'a', plots=False)
    assert cli.main(['mismatch', '--sim', str(tmp_path / 'sim'), '--real', str(tmp_path / 'real'),
                     '--out', str(tmp_path / 'b'), '--remap', '/odom:=/wheel/odom']) == 0
    res = json.loads((tmp_path / 'b' / 'findings.json').read_text())
    scale = [f for f in res['findings'] if f['effect'] == 'wheel_radius_scale']
    assert scale and scale[0]['parameters']['scale'] == pytest.approx(0.03, rel=0.05)
    code = cli.main(['mismatch', '--sim', str(tmp_path / 'sim'), '--real', str(tmp_path / 'real'),
                     '--out', str(tmp_path / 'c'), '--remap', '/odom:=/nope'])
    assert code == 2 and 'not in the real recording' in capsys.readouterr().err
    assert not (tmp_path / 'c').exists()


def test_imu_yaw_rate_compared_with_odometry_yaw_rate(tmp_path):
    t, v, w = _drive(rate=100.0)
    imu = [('/imu/data', T.ImuSample(float(x), np.array([0.0, 0.0, b]), np.array([0, 0, 9.8])))
           for x, b in zip(t, w)]
    _write(tmp_path / 'sim', imu)
    _write(tmp_path / 'real', _odom_items('/odom', t, v, w / 1.2))
    res = analyse(tmp_path / 'sim', tmp_path / 'real', tmp_path / 'o', plots=False,
                  remaps=[('/imu/data', '/odom')])
    tw = [f for f in res['findings'] if f['effect'] == 'track_width_scale']
    assert tw and tw[0]['parameters']['scale'] == pytest.approx(0.2, rel=0.03)
    assert tw[0]['channel'] == '/odom.twist.twist.angular.z'


def test_clocks_aligned_from_the_motion(tmp_path):
    t, v, w = _drive(duration=120.0)
    _write(tmp_path / 'sim', _odom_items('/odom', t, v, w))
    # the real run in epoch time, with 7.3 s more at rest before it starts
    rest = np.arange(-7.3, 0.0, 0.02)
    epoch = 1.7e9
    real = _odom_items('/odom', rest, np.zeros_like(rest), np.zeros_like(rest), epoch + 7.3) + \
        _odom_items('/odom', t, v, w, epoch + 7.3)
    _write(tmp_path / 'real', real)
    res = analyse(tmp_path / 'sim', tmp_path / 'real', tmp_path / 'o', plots=False)
    clock = res['time_alignment']['clock']
    assert clock['method'] == 'motion'
    assert clock['offset'] == pytest.approx(-(epoch + 7.3), abs=0.02)
    assert res['verdict'] == 'consistent'


def test_a_pair_that_cannot_be_aligned_is_a_one_line_error(tmp_path, capsys):
    t, v, w = _drive(seed=1)
    _write(tmp_path / 'sim', _odom_items('/odom', t, v, w))
    t2, v2, w2 = _drive(seed=2)
    _write(tmp_path / 'real', _odom_items('/odom', t2, v2, w2, 1.7e9))
    code = cli.main(['mismatch', '--sim', str(tmp_path / 'sim'), '--real', str(tmp_path / 'real'),
                     '--out', str(tmp_path / 'o')])
    err = capsys.readouterr().err
    assert code == 2 and 'cannot align' in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / 'o').exists()
    assert not list(tmp_path.glob('.o.partial*'))


def _helix(rate=200.0, duration=30.0):
    """Return (t, p, q, rate (3,) rad/s, specific force) of a body on a tilted helix."""
    t = np.arange(0.0, duration, 1.0 / rate)
    om = 0.7
    p = np.column_stack((2.0 * np.cos(om * t), 2.0 * np.sin(om * t), 0.1 * t))
    yaw = om * t + np.pi / 2
    q = np.column_stack((np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)))
    # in the body frame (x along the velocity, z up): centripetal towards -y... plus gravity
    a_world = np.column_stack((-2.0 * om ** 2 * np.cos(om * t), -2.0 * om ** 2 * np.sin(om * t),
                               0 * t + 9.80665))
    c, s = np.cos(yaw), np.sin(yaw)
    f_body = np.column_stack((c * a_world[:, 0] + s * a_world[:, 1],
                              -s * a_world[:, 0] + c * a_world[:, 1], a_world[:, 2]))
    return t, p, q, np.array([0.0, 0.0, om]), f_body


def test_ideal_imu_of_a_known_trajectory():
    t, p, q, rate, force = _helix()
    rng = np.random.default_rng(3)
    out = ideal_imu(t, q, p + 1e-5 * rng.standard_normal(p.shape))
    ok = np.all(np.isfinite(out['gyro']), axis=1) & np.all(np.isfinite(out['accel']), axis=1)
    assert ok.mean() > 0.9
    assert np.allclose(out['gyro'][ok], rate, atol=1e-6)
    assert np.allclose(out['accel'][ok], force[ok], atol=0.05)
    assert out['kernels']['gyro'][0] == 'box' and out['kernels']['accel'][0] == 'tri'
    assert out['half']['accel'] > 1  # position noise differentiated twice: a wider window


def test_ideal_joint_states_of_a_planar_truth_and_kernels_in_the_bag(tmp_path):
    t, p, q, _, _ = _helix(rate=50.0)
    p[:, 2] = 0.0
    prm = IdealParams(drive_type='differential', wheel_radius=0.1, track_width=0.4)
    rec = derive_recording(t, p, q, prm)
    js = rec['/joint_states']
    ok = np.isfinite(js.fields['velocity.left_wheel_joint'])
    v, om = 2.0 * 0.7, 0.7
    assert np.allclose(js.fields['velocity.left_wheel_joint'][ok], (v - om * 0.2) / 0.1,
                       rtol=1e-3)
    assert np.allclose(js.fields['velocity.right_wheel_joint'][ok], (v + om * 0.2) / 0.1,
                       rtol=1e-3)
    write_recording(rec, tmp_path / 'ideal')
    back = read_bag(tmp_path / 'ideal')
    assert back['/imu'].kernels == rec['/imu'].kernels
    assert back['/joint_states'].kernels['velocity.left_wheel_joint'][0] == 'box'
    meta = (tmp_path / 'ideal' / 'metadata.yaml').read_text()
    assert KERNELS_KEY in meta


def test_ideal_without_a_truth_topic_is_a_clear_error(tmp_path, capsys):
    t, v, w = _drive(duration=5.0)
    imu = [('/imu', T.ImuSample(float(x), np.zeros(3), np.array([0, 0, 9.8]))) for x in t]
    _write(tmp_path / 'b', imu)
    assert cli.main(['ideal', str(tmp_path / 'b'), '--out', str(tmp_path / 'o')]) == 2
    assert 'no ground-truth pose topic' in capsys.readouterr().err
    assert not (tmp_path / 'o').exists()
    with pytest.raises(MismatchError):
        analyse(tmp_path / 'b', tmp_path / 'missing', tmp_path / 'x')
