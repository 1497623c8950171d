# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The mismatch analyser's findings checked along the run and across topics.

A delay is one number for a whole run, so time lines that drift apart are
named as such, not as a latency; one change of how the robot moved shows on
every sensor that saw it and is one finding, not one per sensor; a delay that
sampling rates alone make is said to be so; a fit that does not lower the
held-out residual does not claim to.
"""

import numpy as np
import pytest

from robot_calib.core.constants import GRAVITY
from robot_calib.mismatch import analyse_recordings
from robot_calib.mismatch.channels import IMU_FIELDS, IMU_TYPE, ODOM_FIELDS, ODOM_TYPE, Topic
from robot_calib.mismatch.explain import explain
from robot_calib.mismatch.reconcile import reconcile


def _smooth(rng, n, width):
    x = rng.standard_normal(n + 3 * width)
    for _ in range(3):
        x = np.convolve(x, np.ones(width) / width, 'valid')
    return x[:n] / np.std(x[:n])


def _motion(seed, duration=150.0, rate=100.0):
    """Return (t, v m/s, w rad/s) of a robot driving and turning both ways."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration * rate)) / rate
    v = 0.5 + 0.3 * _smooth(rng, t.size, int(1.5 * rate))
    w = 0.6 * _smooth(rng, t.size, int(0.8 * rate))
    return t, v, w


def _imu(t, w, v, rng, scale=1.0):
    acc = np.gradient(v, t)
    f = dict(zip(IMU_FIELDS, (np.zeros(t.size), np.zeros(t.size), scale * w,
                              acc, v * w, np.full(t.size, GRAVITY))))
    f = {k: x + rng.standard_normal(t.size) * (0.003 if k.startswith('angular') else 0.03)
         for k, x in f.items()}
    return Topic('/imu', IMU_TYPE, t, f)


def _odom(name, t, v, w, rng, noise=0.002):
    return Topic(name, ODOM_TYPE, t, {ODOM_FIELDS[0]: v + noise * rng.standard_normal(t.size),
                                      ODOM_FIELDS[1]: w + noise * rng.standard_normal(t.size)})


def _all(out):
    return out['findings'] + out['minor_findings']


def test_time_lines_drifting_apart_are_not_named_a_constant_latency():
    """
    A real run drifting to 0.3 s behind the simulation is a timing drift, not a latency.

    A closed-loop run that reaches its goals later than simulated (or a clock of
    another rate) shifts the time lines by an amount that grows along the run:
    the delay of a whole run came out as a latency of the run-wide mean at
    confidence 1.0. The delays of the run's parts now have to agree first.
    """
    t, v, w = _motion(1)
    rng = np.random.default_rng(2)
    sim = {'/imu': _imu(t, w, v, rng)}
    late = t - 0.3 * t / t[-1]       # the real run shows at t what the simulation did at late
    real_imu = _imu(t, np.interp(late, t, w), np.interp(late, t, v), rng)
    out, _ = analyse_recordings(sim, {'/imu': real_imu})
    assert not [f for f in _all(out) if f['effect'] == 'time_offset'], out['findings']
    drift = [f for f in out['findings'] if f['effect'] == 'timing_drift']
    assert drift and drift[0]['confidence'] > 0.5
    p = drift[0]['parameters']
    assert p['tau_start'] == pytest.approx(0.05, abs=0.03)
    assert p['tau_end'] == pytest.approx(0.25, abs=0.03)
    assert 'not one constant' in drift[0]['explanation']


def test_a_constant_latency_stays_a_latency():
    """The control: the same motion 80 ms late throughout is one delay, not a drift."""
    t, v, w = _motion(1)
    rng = np.random.default_rng(2)
    late = t - 0.08
    out, _ = analyse_recordings({'/imu': _imu(t, w, v, rng)},
                                {'/imu': _imu(t, np.interp(late, t, w),
                                              np.interp(late, t, v), rng)})
    delay = [f for f in out['findings'] if f['effect'] == 'time_offset']
    assert delay and delay[0]['parameters']['tau'] == pytest.approx(0.08, abs=0.002)
    assert not [f for f in _all(out) if f['effect'] == 'timing_drift']


def _wheels_pair(seed, motion_scale, gyro_scale):
    """Return (sim, real) with a ground truth and an IMU; the real robot moves scaled."""
    t, v, w = _motion(seed)
    rng = np.random.default_rng(seed + 10)
    sim = {'/ground_truth/odom': _odom('/ground_truth/odom', t, v, w, rng),
           '/imu': _imu(t, w, v, rng)}
    k = motion_scale
    real = {'/ground_truth/odom': _odom('/ground_truth/odom', t, k * v, k * w, rng),
            '/imu': _imu(t, k * w, v, rng, scale=gyro_scale)}
    return sim, real


def test_one_change_of_the_motion_is_one_finding_not_one_per_sensor():
    """
    Wheels 3 % larger: the robot drives and turns 3 % faster, and every sensor sees it.

    Each topic explained alone named a wheel radius scale (speed), a track
    width scale (the same factor on the yaw rate) and a gyro scale (the
    perfect gyro seeing the faster turns), all at full confidence; a user
    correcting all three would count one error three times.
    """
    out, _ = analyse_recordings(*_wheels_pair(3, 1.03, 1.0))
    names = [f['effect'] for f in _all(out)]
    assert 'track_width_scale' not in names and 'gyro_scale' not in names, out['findings']
    wheel = [f for f in out['findings'] if f['effect'] == 'wheel_radius_scale']
    assert wheel and wheel[0]['parameters']['scale'] == pytest.approx(0.03, abs=0.002)
    assert 'scales alike' in wheel[0]['explanation']
    assert any('not a gyro scale error' in n for n in out['notes'])


def test_a_gyro_that_disagrees_with_the_ground_truth_keeps_its_scale():
    """The control: the robot moves as simulated but the gyro reads 3 % high."""
    out, _ = analyse_recordings(*_wheels_pair(3, 1.0, 1.03))
    gyro = [f for f in out['findings'] if f['effect'] == 'gyro_scale']
    assert gyro and gyro[0]['parameters']['scale'] == pytest.approx(0.03, abs=0.002)


def test_a_gyro_fault_beside_a_motion_change_is_kept_with_its_own_part():
    """
    The robot turns 5 % faster and the gyro also reads 2 % high: the gyro shows +7.1 %.

    Scales within 10 % of each other were merged, so a gyro fault up to a tenth
    of the motion change vanished (an audit: +0.8 % beside -9.6 %). Now only
    scales within their errors or 0.2 % are one, and a gyro kept beside a
    motion change says what its own part is if the other topic is the truth.
    """
    out, _ = analyse_recordings(*_wheels_pair(3, 1.05, 1.02))
    gyro = [f for f in out['findings'] if f['effect'] == 'gyro_scale']
    assert gyro and gyro[0]['parameters']['scale'] == pytest.approx(1.05 * 1.02 - 1, abs=0.003)
    assert "the gyro's own scale error is +2.0" in gyro[0]['explanation']


def test_reconcile_keeps_scales_that_differ():
    """A track width and a wheel radius of different sizes are two effects, both kept."""
    def finding(effect, channel, scale):
        return {'effect': effect, 'channel': channel, 'window': None, 'explanation': '',
                'parameters': {'scale': scale}, 'std': {'scale': 1e-4}}
    found = [finding('wheel_radius_scale', '/odom.twist.twist.linear.x', 0.02),
             finding('track_width_scale', '/odom.twist.twist.angular.z', 0.05),
             finding('gyro_scale', '/imu.angular_velocity.z', 0.02)]
    notes = []
    assert reconcile(found, notes) == found and not notes
    # a speed change of -10 % and a yaw-rate change of -10.9 % (a wider track besides): two
    # effects, though within 10 % of each other
    found = [finding('wheel_radius_scale', '/gt.twist.twist.linear.x', -0.1),
             finding('track_width_scale', '/gt.twist.twist.angular.z', 0.1222)]
    assert reconcile(found, notes) == found and not notes
    assert "the track width's own part is -0.99%" in found[1]['explanation']   # 1/1.1222/0.9


def test_a_slower_robot_is_not_a_missing_centripetal_term():
    """A 10 % slip slows speed and turn rate alike: v * omega is 19 % smaller, nothing missing."""
    def finding(effect, channel, key, value):
        return {'effect': effect, 'channel': channel, 'window': None, 'explanation': '',
                'parameters': {key: value}, 'std': {key: 1e-4}}
    found = [finding('wheel_radius_scale', '/gt.twist.twist.linear.x', 'scale', -0.1),
             finding('track_width_scale', '/gt.twist.twist.angular.z', 'scale', 1 / 0.9 - 1),
             finding('centripetal_acceleration', '/imu.linear_acceleration.y', 'gain', -0.191)]
    notes = []
    left = reconcile(found, notes)
    assert [f['effect'] for f in left] == ['wheel_radius_scale']
    assert any('centripetal gain' in n for n in notes)


def test_a_delay_that_the_sampling_rates_make_says_so():
    """
    Odometry at 20 Hz against a simulation at 50 Hz: the speeds differ by 15 ms.

    A speed differenced over one period stands for the middle of it, so it
    trails its stamp by half a period; the delay is real in the data, but the
    rate alone may make it, and the finding says how to tell.
    """
    rng = np.random.default_rng(5)
    t, v, w = _motion(5, rate=50.0)
    tr = np.arange(0.0, t[-1], 0.05)
    sim = {'/odom': _odom('/odom', t, v, w, rng)}
    late = tr - 0.5 * (0.05 - 0.02)
    real = {'/odom': _odom('/odom', tr, np.interp(late, t, v), np.interp(late, t, w), rng)}
    out, _ = analyse_recordings(sim, real)
    delay = [f for f in out['findings'] if f['effect'] == 'time_offset']
    assert delay and delay[0]['parameters']['tau'] == pytest.approx(0.015, abs=0.002)
    assert 'half the difference of the two sample periods' in delay[0]['explanation']


def test_a_fit_that_does_not_lower_the_held_out_residual_does_not_claim_to():
    """The sentence follows the numbers it quotes."""
    worse = explain('wheel_radius_scale', {'scale': 0.02}, None,
                    {'heldout_rmse_before': 0.119, 'heldout_rmse_after': 0.121})
    assert 'cuts' not in worse and 'does not lower' in worse
    better = explain('wheel_radius_scale', {'scale': 0.02}, None,
                     {'heldout_rmse_before': 0.119, 'heldout_rmse_after': 0.02})
    assert 'cuts the held-out residual from 0.119 to 0.02' in better


def test_a_consistent_verdict_with_minor_effects_does_not_claim_noise_only():
    """Below the naming floor is not within the noise: the paragraph lists what is smaller."""
    from robot_calib.mismatch.report import summary_paragraph
    minor = {'effect': 'gyro_scale', 'channel': '/imu.angular_velocity.z', 'window': None,
             'parameters': {'scale': 0.00998}}
    text = summary_paragraph({'findings': [], 'minor_findings': [minor]})
    assert 'within its noise' not in text and 'gyro scale on `/imu.angular_velocity.z`' in text
    assert 'within its noise' in summary_paragraph({'findings': [], 'minor_findings': []})


def test_a_channel_that_does_not_follow_the_simulation_carries_no_finding():
    """
    The real gyro z reads 0.3 times the simulated rate (and 0.01 rad/s more).

    Its gyro scale fit (-0.7) is far beyond a working sensor, so the channel is
    listed as not following the simulation; an offset fitted beside it (0.037,
    not the 0.01 added) was still listed as a gyro bias (an audit, on another
    trajectory: 0.04 rad/s at confidence 0.82 against a true 0.003).
    """
    t, v, w = _motion(1)
    rng = np.random.default_rng(2)
    real = _imu(t, w, v, rng, scale=0.3)
    real.fields['angular_velocity.z'] += 0.01
    out, _ = analyse_recordings({'/imu': _imu(t, w, v, rng)}, {'/imu': real})
    z = [f for f in _all(out) + out['weak_findings'] if f['channel'] == '/imu.angular_velocity.z']
    assert not [f for f in z if f['effect'] != 'unexplained'], z
    assert any(d['channel'] == '/imu.angular_velocity.z' for d in out['not_judged'])
