# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The mismatch analyser on real-data problems: whole-sensor effects, robust evidence, honesty.

Each test builds a simulated recording with known physics, makes a "real"
one that differs by a known effect (or by something outside the library, or
by nothing), and checks what the analyser names, how precisely, and what it
refuses to name.
"""

import numpy as np
import pytest

from robot_calib.core.constants import GRAVITY
from robot_calib.mismatch import analyse_recordings
from robot_calib.mismatch import latency as L
from robot_calib.mismatch import robust as R
from robot_calib.mismatch.channels import IMU_FIELDS, IMU_TYPE, ODOM_FIELDS, ODOM_TYPE, Topic
from robot_calib.mismatch.effects import rotate
from robot_calib.mismatch.findings import evidence, heldout_support, motion_ratio
from robot_calib.mismatch.regressors import command_slope
from robot_calib.mismatch.timing import field_taus

GYRO, ACC = IMU_FIELDS[:3], IMU_FIELDS[3:]


def _smooth_noise(rng, n, width):
    """Return unit-variance noise smoothed by three passes of a ``width``-sample box."""
    x = rng.standard_normal(n + 3 * width)
    for _ in range(3):
        x = np.convolve(x, np.ones(width) / width, 'valid')
    return x[:n] / np.std(x[:n])


def _tumbling_imu(seed=0, duration=120.0, rate=200.0):
    """Return (t, gyro (n, 3), specific force (n, 3)) of a hand-held IMU turned every way."""
    rng = np.random.default_rng(seed)
    n = int(duration * rate)
    t = np.arange(n) / rate
    w = np.column_stack([1.2 * _smooth_noise(rng, n, int(0.3 * rate)) for _ in range(3)])
    # gravity direction in the sensor frame, integrated from the rates (dR/dt = -w x R)
    g = np.zeros((n, 3))
    g[0] = (0.0, 0.0, GRAVITY)
    dt = 1.0 / rate
    for i in range(1, n):
        v = g[i - 1] - np.cross(w[i - 1], g[i - 1]) * dt
        g[i] = v * (GRAVITY / np.linalg.norm(v))
    lin = np.column_stack([1.0 * _smooth_noise(rng, n, int(0.4 * rate)) for _ in range(3)])
    return t, w, g + lin


def _imu_rec(t, gyro, acc):
    fields = {f: (gyro if i < 3 else acc)[:, i % 3].copy() for i, f in enumerate(IMU_FIELDS)}
    return {'/imu': Topic('/imu', IMU_TYPE, t.copy(), fields)}


def _noisy(rec, seed, sg=0.003, sa=0.03):
    rng = np.random.default_rng(seed)
    tp = rec['/imu']
    f = {k: v + rng.standard_normal(v.size) * (sg if k in GYRO else sa)
         for k, v in tp.fields.items()}
    return {'/imu': Topic('/imu', IMU_TYPE, tp.t.copy(), f)}


def _named(out, effect):
    return [f for f in out['findings'] + out['minor_findings'] if f['effect'] == effect]


def test_mounting_rotation_of_the_whole_imu_is_one_finding():
    t, w, a = _tumbling_imu(1)
    roll, pitch, yaw = np.radians([1.5, -2.0, 2.5])
    rg = np.column_stack(rotate(tuple(w.T), roll, pitch, yaw))
    ra = np.column_stack(rotate(tuple(a.T), roll, pitch, yaw))
    out, _ = analyse_recordings(_imu_rec(t, w, a), _noisy(_imu_rec(t, rg, ra), 2))
    rot = _named(out, 'imu_mounting_rotation')
    assert rot, out['findings']
    p = rot[0]['parameters']
    assert np.degrees([p['roll'], p['pitch'], p['yaw']]) == pytest.approx([1.5, -2.0, 2.5],
                                                                          abs=0.1)
    # one whole-sensor effect, not a cross-axis term per channel
    assert not _named(out, 'gyro_cross_axis')


def test_lever_arm_recovered():
    t, w, a = _tumbling_imu(3)
    dt = t[1] - t[0]
    wd = np.gradient(w, dt, axis=0)
    r = np.array([0.05, -0.08, 0.03])
    ra = a + np.cross(wd, r) + np.cross(w, np.cross(w, r))
    out, _ = analyse_recordings(_imu_rec(t, w, a), _noisy(_imu_rec(t, w, ra), 4))
    lev = _named(out, 'lever_arm')
    assert lev, out['findings']
    got = np.array([lev[0]['parameters'][k] for k in 'xyz'])
    assert np.linalg.norm(got - r) < 0.1 * np.linalg.norm(r)


def _loud_while_moving(seed):
    """Return (t, sim, real): a tumbling IMU, its real gyro ten times noisier half the time."""
    t, w, a = _tumbling_imu(seed)
    rng = np.random.default_rng(seed + 1)
    moving = (np.sin(2 * np.pi * t / 30.0) > 0).astype(float)
    real = _imu_rec(t, w, a)
    for k in GYRO:
        # white noise, and a slow wander, both only while moving (a reference's own errors)
        loud = moving * (0.03 * rng.standard_normal(t.size) +
                         0.02 * _smooth_noise(rng, t.size, 400))
        real['/imu'].fields[k] = real['/imu'].fields[k] + 0.002 * rng.standard_normal(t.size) \
            + loud
    return t, _imu_rec(t, w, a), real


def test_heteroscedastic_noise_does_not_hide_a_small_bias():
    """Noise ten times louder while moving: the quiet stretches pin the bias."""
    _, sim, real = _loud_while_moving(5)
    real['/imu'].fields['angular_velocity.y'] += 0.003
    out, _ = analyse_recordings(sim, real)
    b = [f for f in _named(out, 'gyro_bias') if f['channel'].endswith('.y')]
    assert b and b[0]['parameters']['bias'] == pytest.approx(0.003, abs=0.0004)


@pytest.mark.parametrize('seed', [5, 7, 9])
def test_loud_stretches_do_not_outvote_a_drift_the_quiet_ones_show(seed):
    """
    A drifting gyro bias, under noise ten times louder while moving, is a finding.

    Held-out time must judge it as the fit weighs each sample: by plain RMSE
    the loud stretches decide, and the drift was left a weak finding.
    """
    t, sim, real = _loud_while_moving(seed)
    real['/imu'].fields['angular_velocity.z'] += 1.2e-4 * t
    out, _ = analyse_recordings(sim, real)
    d = [f for f in out['findings'] if f['effect'] == 'gyro_bias_drift']
    assert d and d[0]['channel'].endswith('.z'), out['findings']
    assert d[0]['parameters']['drift'] == pytest.approx(1.2e-4, rel=0.05)


def test_a_delay_on_small_fast_motion_is_not_taken_for_noise():
    """
    A gyro axis turning little but quickly still joins the delay, and its scale is found.

    Left in the residual, a 30 ms delay of that axis measures as noise seventy
    times the sensor's; the axis then seemed too still to show a delay at all.
    """
    t, w, a = _tumbling_imu(1)
    w[:, 0] = 0.3 * _smooth_noise(np.random.default_rng(11), t.size, 10)   # 0.05 s wiggles
    real = _noisy(_imu_rec(t, w, a), 2)['/imu']
    real.fields['angular_velocity.x'] *= 1.04
    real = {'/imu': Topic('/imu', IMU_TYPE, real.t + 0.03, real.fields)}
    out, _ = analyse_recordings(_imu_rec(t, w, a), real)
    delays = out['time_alignment']['/imu']['delays']
    assert len(delays) == 1 and 'angular_velocity.x' in delays[0]['fields']
    assert delays[0]['tau'] == pytest.approx(0.03, abs=1e-4)
    s = [f for f in out['findings'] if f['effect'] == 'gyro_scale']
    assert s and s[0]['channel'].endswith('.x'), out['findings']
    assert s[0]['parameters']['scale'] == pytest.approx(0.04, abs=0.004)


@pytest.mark.parametrize('seed', [3, 4, 5])
def test_a_delay_of_gentle_motion_over_a_long_recording_is_found(seed):
    """
    A cart yawing gently (about twice the noise) for 200 s shows its 60 ms lead.

    Per sample the motion hardly stands above the noise, but the delay estimate
    integrates it over the whole recording; the channels of noise alone stay out.
    """
    rate = 100.0
    n = int(200 * rate)
    t = np.arange(n) / rate
    rng = np.random.default_rng(seed)
    w = np.zeros((n, 3))
    w[:, 2] = 0.03 * _smooth_noise(rng, n, 100)
    a = np.zeros((n, 3))
    a[:, 2] = GRAVITY
    a[:, 0] = 0.09 * _smooth_noise(rng, n, 150)
    sim = _noisy(_imu_rec(t, w, a), seed + 1, sg=0.01, sa=0.05)
    real = _noisy(_imu_rec(t, w, a), seed + 2, sg=0.01, sa=0.05)['/imu']
    real = {'/imu': Topic('/imu', IMU_TYPE, real.t - 0.06, real.fields)}
    out, _ = analyse_recordings(sim, real)
    delays = out['time_alignment']['/imu']['delays']
    assert len(delays) == 1 and 'angular_velocity.z' in delays[0]['fields'], delays
    assert not {'angular_velocity.x', 'angular_velocity.y'} & set(delays[0]['fields'])
    assert delays[0]['tau'] == pytest.approx(-0.06, abs=0.006)


def test_a_physical_name_replaces_an_implausible_one_that_fits_the_same():
    """
    Driving circles, the real IMU feels 60 % more centripetal acceleration than simulated.

    The simulated lateral acceleration is v omega itself, so a 60 % accelerometer
    scale (no working sensor has one) fits exactly as well as the missing
    centripetal term; the physical name is reported, not an unexplained residual.
    """
    rate = 100.0
    n = int(120 * rate)
    t = np.arange(n) / rate
    rng = np.random.default_rng(4)
    v = 1.0 + 0.2 * _smooth_noise(rng, n, 800)
    wz = 0.5 + 0.1 * _smooth_noise(rng, n, 800)
    w = np.zeros((n, 3))
    w[:, 2] = wz
    a = np.zeros((n, 3))
    a[:, 0], a[:, 1], a[:, 2] = np.gradient(v, 1 / rate), v * wz, GRAVITY
    real_a = a.copy()
    real_a[:, 1] += 0.6 * v * wz

    def odom(noise):
        fields = (v[::5] + noise * rng.standard_normal(n // 5),
                  wz[::5] + noise * rng.standard_normal(n // 5))
        return {'/odom': Topic('/odom', ODOM_TYPE, t[::5].copy(), dict(zip(ODOM_FIELDS, fields)))}
    out, _ = analyse_recordings({**_imu_rec(t, w, a), **odom(0.0)},
                                {**_noisy(_imu_rec(t, w, real_a), 5), **odom(0.004)})
    named = [f for f in out['findings'] if f['channel'].endswith('linear_acceleration.y')]
    assert [f['effect'] for f in named] == ['centripetal_acceleration'], out['findings']
    assert named[0]['parameters']['gain'] == pytest.approx(0.6, abs=0.01)
    assert not any(f['effect'] == 'unexplained' for f in out['findings'])
    assert any('far beyond a physical value' in n for n in out['notes'])


def test_a_scale_on_a_steady_turn_is_named_beside_the_offset_it_looks_like():
    """
    A 4 % gyro scale acting only during a 40 s turn at a constant rate reads as an offset.

    The recording cannot tell the two apart there; the finding must say so (the
    scale as its alternative, the confidence halved), even though the simulated
    rate's own noise makes the scale fit a little worse than the offset.
    """
    t, w, a = _tumbling_imu(2)
    steady = (t >= 40.0) & (t < 80.0)
    w[steady, 2] = 0.5
    real = _imu_rec(t, w, a)
    real['/imu'].fields['angular_velocity.z'] = np.where(steady, 1.04, 1.0) * w[:, 2]
    out, _ = analyse_recordings(_noisy(_imu_rec(t, w, a), 4), _noisy(real, 3))
    named = [f for f in out['findings'] + out['weak_findings']
             if f['channel'].endswith('angular_velocity.z')]
    assert len(named) == 1 and named[0]['effect'] in ('gyro_bias', 'gyro_scale'), named
    f = named[0]
    assert f['window'] == pytest.approx([40.0, 80.0], abs=0.1)
    alts = {x['effect']: x['parameters'] for x in f.get('alternatives', [])}
    twin = 'gyro_scale' if f['effect'] == 'gyro_bias' else 'gyro_bias'
    assert twin in alts, f
    values = {f['effect']: f['parameters'], twin: alts[twin]}
    assert values['gyro_bias']['bias'] == pytest.approx(0.02, abs=0.002)
    assert values['gyro_scale']['scale'] == pytest.approx(0.04, abs=0.004)
    assert f['confidence'] <= 0.55


def test_a_delay_is_shown_on_the_channel_it_explains_best_against_its_noise():
    """
    A 20 ms delay shows on the gyros far above their noise and on a noisy accelerometer barely.

    The accelerometer's RMSE falls more in m/s^2 than a gyro's in rad/s; units
    must not pick the channel the finding shows.
    """
    t, w, a = _tumbling_imu(6)
    w *= 0.1
    a[:, 0] += 3.0 * np.sin(2 * np.pi * t / 2.0)
    real = _noisy(_imu_rec(t, w, a), 7, sg=0.002, sa=0.4)['/imu']
    real = {'/imu': Topic('/imu', IMU_TYPE, real.t + 0.02, real.fields)}
    out, _ = analyse_recordings(_imu_rec(t, w, a), real)
    f = [x for x in out['findings'] if x['effect'] == 'time_offset']
    assert f and f[0]['parameters']['tau'] == pytest.approx(0.02, abs=1e-3)
    assert '.angular_velocity.' in f[0]['channel']
    assert f[0]['fit']['heldout_rmse_after'] < 0.5 * f[0]['fit']['heldout_rmse_before']


def test_held_out_time_that_moves_less_is_not_held_against_an_effect():
    """
    An effect removes from each part of the recording what its motion puts there.

    Held-out time moving three times less (in mean square) confirms a third of
    the fitted gain: full credit once the motion is counted, partial without.
    """
    fitted = np.arange(3000) < 2000
    change = np.sin(0.1 * np.arange(3000)) * np.where(fitted, 1.0, np.sqrt(1 / 3))
    motion = motion_ratio(change, fitted, ~fitted)
    assert motion == pytest.approx(3.0, rel=0.01)
    fitd = {'rmse_before': np.sqrt(2.0), 'rmse_after': 1.0,          # gain 1.0 in mean square
            'heldout_rmse_before': np.sqrt(1.3), 'heldout_rmse_after': 1.0}   # gain 0.3
    assert evidence(1.0, fitd) == pytest.approx(0.6)
    assert evidence(1.0, fitd, motion) == pytest.approx(1.0)
    # a spurious effect makes held-out time worse: no credit, however the motion lies
    worse = dict(fitd, heldout_rmse_before=1.0, heldout_rmse_after=np.sqrt(1.3))
    assert evidence(1.0, worse, motion) == 0.0
    assert motion_ratio(np.zeros(10), np.arange(10) < 5, np.arange(10) >= 5) == 1.0


def test_held_out_time_too_still_to_tell_is_no_evidence_either_way():
    """
    Held-out time that hardly moves gives its gain a large error (fresh seed 5017).

    A slip confirmed there to within its error was weak (0.27) because that
    time moved 29 times less than the fitted time; the credit is now at least
    the odds that the held-out gain comes from the effect rather than none.
    """
    fitd = {'rmse_before': np.sqrt(2.0), 'rmse_after': 1.0,
            'heldout_rmse_before': np.sqrt(1.0105), 'heldout_rmse_after': 1.0}
    assert evidence(1.0, fitd, 4.0) < 0.1
    assert evidence(1.0, fitd, 4.0, (0.01, 0.005)) > 0.85
    # no gain where 0.01 was predicted within 0.005: mostly against it
    none = dict(fitd, heldout_rmse_before=1.0)
    assert evidence(1.0, none, 4.0, (0.01, 0.005)) < 0.15
    # too still to tell: one half, so an effect resting on held-out time alone stays weak
    assert evidence(1.0, none, 4.0, (0.001, 0.01)) == pytest.approx(0.5, abs=0.01)
    # an effect that leaves held-out time untouched (a windowed slip whose held-out chunks do
    # not accelerate, fresh seed 7111: coefficient within 1 %, evidence 0.0) cannot be told
    assert evidence(0.6, none, 1.0, heldout_support(np.zeros(10), np.ones(10, bool),
                                                    np.ones(10))) == pytest.approx(0.3)
    # a precise held-out part that gets worse gives no credit
    worse = dict(fitd, heldout_rmse_before=1.0, heldout_rmse_after=np.sqrt(1.3))
    assert evidence(1.0, worse, 4.0, (0.3, 0.01)) == 0.0


def test_held_out_support_error_matches_the_spread_of_the_gain():
    rng = np.random.default_rng(29)
    n = 400
    held = np.ones(n, bool)
    change = 0.02 * np.sin(np.arange(n) / 9.0)
    gains, ses = [], []
    for _ in range(400):
        e = 0.05 * rng.standard_normal(n)
        r = change + e
        gains.append(np.mean(r ** 2) - np.mean(e ** 2))
        expected, se = heldout_support(change, held, e)
        ses.append(se)
    assert expected == pytest.approx(np.mean(change ** 2))
    assert np.mean(gains) == pytest.approx(expected, abs=3 * np.std(gains) / 20)
    assert np.median(ses) == pytest.approx(np.std(gains), rel=0.15)


def _commanded_ramps(rng, t, accel):
    """Return a commanded speed (m/s) ramping at ``accel`` (m/s^2) to a new target every 3 s."""
    dt = t[1] - t[0]
    targets = rng.uniform(0.0, 1.0, t.size // 150 + 1)[np.arange(t.size) // 150]
    v = np.zeros(t.size)
    for i in range(1, t.size):
        v[i] = v[i - 1] + np.clip(targets[i] - v[i - 1], -accel * dt, accel * dt)
    return v


def test_commanded_acceleration_is_the_slope_of_each_command_interval():
    """
    The slip regressor on a ramped command sampled at 10 Hz (fresh seeds 2018, 3111, 5082).

    Central differences of the command, interpolated again, spread each
    acceleration over two command periods; a slip fitted to that smoothed
    regressor came out 12-16 % too large (errors in the regressor). The slope
    of each command interval, the derivative of the speed as it is
    interpolated, carries the acceleration at its full size.
    """
    dt = 0.02
    t = np.arange(0.0, 240.0, dt)
    v = _commanded_ramps(np.random.default_rng(31), t, 1.0)
    a = np.diff(v, append=v[-1]) / dt
    tc = np.arange(0.0, 240.0, 0.1)
    vc = np.interp(tc, t, v)

    def gain(x):   # the slip fitted on regressor v x, relative to the true one (on v a)
        return float(np.sum(v * a * v * x) / np.sum((v * x) ** 2))

    assert gain(command_slope(tc, vc, t)) == pytest.approx(1.0, abs=0.02)
    assert gain(np.interp(t, tc, np.gradient(vc, tc))) > 1.05
    far = command_slope(tc, vc, np.array([-1.0, 250.0]))
    assert np.isnan(far).all()


def _ramped_drive(rng, slip=0.0, tau=0.0, lag=0.0):
    """Return (sim, real): odometry of commanded ramps, real with slip, a lag and/or a delay."""
    dt = 0.02
    t = np.arange(0.0, 240.0, dt)
    v = _commanded_ramps(rng, t, 0.6)
    w = 0.4 * np.sin(2 * np.pi * t / 17.0)
    tc = np.arange(0.0, 240.0, 0.1)
    cmd = Topic('/cmd_vel', 'geometry_msgs/msg/Twist', tc,
                {'linear.x': np.interp(tc, t, v), 'angular.z': np.zeros(tc.size)})
    sim = {'/odom': Topic('/odom', ODOM_TYPE, t, dict(zip(ODOM_FIELDS, (v, w)))),
           '/cmd_vel': cmd}
    # slip as the analyser models it: with the commanded acceleration
    rv, rw = v * (1.0 + slip * command_slope(tc, cmd.fields['linear.x'], t)), w
    if lag:  # the drive's own filter, on the slipping speed
        rv, rw = L.lag_response(rv, dt, lag), L.lag_response(rw, dt, lag)
    rv, rw = np.interp(t - tau, t, rv), np.interp(t - tau, t, rw)
    real = {'/odom': Topic('/odom', ODOM_TYPE, t, dict(zip(ODOM_FIELDS, (
        rv + 0.004 * rng.standard_normal(t.size), rw + 0.004 * rng.standard_normal(t.size))))),
        '/cmd_vel': cmd}
    return sim, real


def test_an_odometry_delay_that_slip_explains_as_well_is_not_named_alone():
    """
    Slip under acceleration looks like a delay of the odometry speed (``c v a`` against ``tau a``).

    The delay stage runs first; a slip it took for a 30 ms delay was named with
    full confidence (fresh seed 4063). Now a delay is estimated on the speed
    less a slip fitted jointly with it, and one that the slip explains as well
    has the slip as its alternative; a delay of both channels keeps its
    confidence.
    """
    out, _ = analyse_recordings(*_ramped_drive(np.random.default_rng(31), slip=0.1))
    for f in _named(out, 'time_offset'):
        assert 'wheel_slip' in [a['effect'] for a in f.get('alternatives', [])]
        assert f['confidence'] <= 0.5
    out, _ = analyse_recordings(*_ramped_drive(np.random.default_rng(31), tau=0.03))
    delay = _named(out, 'time_offset')
    assert delay and delay[0]['parameters']['tau'] == pytest.approx(0.03, abs=2e-3)
    assert delay[0]['confidence'] > 0.9 and 'alternatives' not in delay[0]


@pytest.mark.parametrize('tau', [-0.02, 0.02, 0.2])
def test_a_slip_and_an_odometry_delay_together_are_both_found(tau):
    """
    The slip and the delay are fitted jointly on the speed, not each alone (fresh seed 4087).

    Fitted alone, each takes the other's share (both grow with the
    acceleration): the delay stage estimated a -20 ms delay beside a slip as
    -6 +- 3 ms and dropped it, and the slip came out 23 % small. The slip
    fitted jointly with the delay's linearisation is removed before the delay
    is estimated (and again, delayed by the delay found, until the two settle),
    a delay beside a slip is weighed by what it adds, and a delay against a lag
    of the drive is judged on the speed without its slip. The slip's regressor
    (the commanded acceleration, another topic) is read as late as the
    odometry once aligned: read on time beside a 0.2 s delay the slip came out
    a third small.
    """
    out, _ = analyse_recordings(*_ramped_drive(np.random.default_rng(32), slip=0.1, tau=tau))
    delay, slip = _named(out, 'time_offset'), _named(out, 'wheel_slip')
    assert delay and delay[0]['parameters']['tau'] == pytest.approx(tau, abs=2e-3)
    assert 'alternatives' not in delay[0]
    assert slip and slip[0]['parameters']['coefficient'] == pytest.approx(0.1, rel=0.08)


def test_a_slip_behind_a_drive_lag_is_measured_through_the_lag():
    """The commanded acceleration (another topic) passes the drive's lag like the speed does."""
    out, _ = analyse_recordings(*_ramped_drive(np.random.default_rng(7), slip=0.1, lag=0.15))
    lag, slip = _named(out, 'drive_lag'), _named(out, 'wheel_slip')
    # the speed's lag, which the slip is measured behind (on ramps the turn rate's lag and
    # dead time are hard to tell apart)
    lag = [f for f in lag if f['channel'].endswith('linear.x')]
    # the drive chain fits the lag beside dead time and rate limit on 10 Hz block means; the
    # slip beside it comes out 17 % large here (8 % with the lag alone): docs/bench/14
    assert lag and lag[0]['parameters']['tau'] == pytest.approx(0.15, rel=0.1)
    assert slip and slip[0]['parameters']['coefficient'] == pytest.approx(0.1, rel=0.2)


def test_physics_outside_the_library_is_unexplained_not_misnamed():
    """A drag term (speed squared) on the odometry is not a radius error or slip."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 180.0, 0.02)
    v = 1.0 + 0.8 * np.sin(2 * np.pi * t / 23.0) + 0.3 * np.sin(2 * np.pi * t / 7.0)
    w = 0.5 * np.sin(2 * np.pi * t / 17.0)
    sim = {'/odom': Topic('/odom', ODOM_TYPE, t, dict(zip(ODOM_FIELDS, (v, w))))}
    real_v = v - 0.06 * (v - 1.0) ** 3 + 0.003 * rng.standard_normal(t.size)
    real = {'/odom': Topic('/odom', ODOM_TYPE, t, dict(zip(ODOM_FIELDS, (
        real_v, w + 0.003 * rng.standard_normal(t.size)))))}
    out, _ = analyse_recordings(sim, real)
    left = [f for f in out['findings'] if f['effect'] == 'unexplained']
    assert left, out['findings']
    assert left[0]['parameters']['rms'] > 0
    assert isinstance(left[0]['parameters']['correlates_with'], str)


def test_implausible_fit_is_not_reported_as_physics():
    """A real channel that does not follow the simulation gets no 40 % 'scale'."""
    t, w, a = _tumbling_imu(9, duration=90.0)
    rg = w.copy()
    rg[:, 2] = 0.6 * w[:, 2]
    out, _ = analyse_recordings(_imu_rec(t, w, a), _noisy(_imu_rec(t, rg, a), 10))
    assert not [f for f in out['findings'] if f['effect'] == 'gyro_scale']
    assert any(d['channel'].endswith('angular_velocity.z') for d in out['not_judged'])


def test_small_significant_effect_is_listed_as_minor():
    t, w, a = _tumbling_imu(11, duration=90.0)
    rg = w.copy()
    rg[:, 0] = 1.004 * w[:, 0]
    out, _ = analyse_recordings(_imu_rec(t, w, a), _noisy(_imu_rec(t, rg, a), 12, sg=0.0005))
    assert not [f for f in out['findings'] if f['effect'] == 'gyro_scale']
    minor = [f for f in out['minor_findings'] if f['effect'] == 'gyro_scale']
    assert minor and minor[0]['parameters']['scale'] == pytest.approx(0.004, rel=0.1)


def test_a_bandwidth_difference_is_not_named_a_scale():
    """A reference carrying less fast motion than the sensor is not a gyro scale or cross-axis."""
    t, w, a = _tumbling_imu(13, duration=90.0)
    width = int(0.15 / (t[1] - t[0]))
    slow = w.copy()
    slow[:, 0] = np.convolve(w[:, 0], np.ones(width) / width, 'same')  # the reference's x
    out, _ = analyse_recordings(_imu_rec(t, slow, a), _noisy(_imu_rec(t, w, a), 14))
    gains = [f for f in _named(out, 'gyro_scale') + _named(out, 'gyro_cross_axis')
             if f['channel'].endswith('angular_velocity.x')]
    assert not gains, gains
    assert any('angular_velocity.x' in n and 'not as one gain' in n for n in out['notes'])


def test_a_gain_acts_alike_on_slow_and_fast_motion():
    """The same gain on both halves of the spectrum passes the band test."""
    t, w, a = _tumbling_imu(15, duration=90.0)
    rg = w.copy()
    rg[:, 1] = 1.03 * w[:, 1]
    out, _ = analyse_recordings(_imu_rec(t, w, a), _noisy(_imu_rec(t, rg, a), 16))
    scale = [f for f in _named(out, 'gyro_scale') if f['channel'].endswith('angular_velocity.y')]
    assert scale and scale[0]['parameters']['scale'] == pytest.approx(0.03, rel=0.1)
    assert not any('not as one gain' in n for n in out['notes'])


def test_drive_lag_told_from_a_delay():
    rng = np.random.default_rng(13)
    dt = 0.02
    t = np.arange(0.0, 200.0, dt)
    cmd = np.repeat(rng.uniform(-1.0, 1.0, t.size // 150 + 1), 150)[:t.size]
    sim = {'/odom': Topic('/odom', ODOM_TYPE, t, dict(zip(ODOM_FIELDS, (cmd, 0.5 * cmd))))}
    lagged = [L.lag_response(x, dt, 0.15) + 0.002 * rng.standard_normal(t.size)
              for x in (cmd, 0.5 * cmd)]
    real = {'/odom': Topic('/odom', ODOM_TYPE, t, dict(zip(ODOM_FIELDS, lagged)))}
    out, _ = analyse_recordings(sim, real)
    lag = _named(out, 'drive_lag')
    assert lag, out['findings']
    assert lag[0]['parameters']['tau'] == pytest.approx(0.15, rel=0.1)
    assert not _named(out, 'time_offset')


@pytest.mark.parametrize('noisy_sim', [False, True])
def test_delay_estimate_unbiased_and_its_error_honest(noisy_sim):
    rng = np.random.default_rng(17)
    dt = 0.005
    n = 24000
    x = _smooth_noise(rng, n, 20) * 2.0
    t = np.arange(n) * dt
    f = np.fft.rfftfreq(n, dt)
    errs = []
    for tau in (0.0, 0.0137):
        y = np.fft.irfft(np.fft.rfft(x) * np.exp(-2j * np.pi * f * tau), n)
        s = x + (0.05 * rng.standard_normal(n) if noisy_sim else 0.0)
        r = y + 0.05 * rng.standard_normal(n)
        d = L.estimate_delay([s], [r], [np.ones(n, bool)], dt, R.block_edges(n, dt))
        errs.append((d.tau - tau) / d.std)
        assert abs(d.tau - tau) < 3e-4
    assert np.all(np.abs(errs) < 5.0)  # the jackknife error covers the actual error
    assert t.size == n


def test_delay_of_a_drive_ending_in_a_fast_turn():
    """
    A sub-sample delay when the recording ends mid-turn (seed 6038 of the suite).

    Shifting such a channel moves a large value across the end of the compared
    samples, so their correlation alone grows towards one edge of the trial
    delays and hid a 9 ms odometry delay; least squares does not.
    """
    rng = np.random.default_rng(23)
    dt = 0.02
    n = 8000
    turn = 3.0 / (1.0 + np.exp(-(np.arange(n) - 0.93 * n) / 20.0))
    x = 0.1 * _smooth_noise(rng, n, 15) + turn
    f = np.fft.rfftfreq(2 * n, dt)
    mirrored = np.concatenate((x, x[::-1]))
    tau = 0.0092
    y = np.fft.irfft(np.fft.rfft(mirrored) * np.exp(-2j * np.pi * f * tau), 2 * n)[:n]
    r = y + 0.005 * rng.standard_normal(n)
    d = L.estimate_delay([x], [r], [np.ones(n, bool)], dt, R.block_edges(n, dt))
    assert d.tau == pytest.approx(tau, abs=1e-3)
    assert abs(d.tau - tau) < 4.0 * d.std


def test_a_delay_shifts_every_channel_of_its_clock():
    """
    A delay estimated on the channels that move applies to all channels of that clock.

    A still gyro axis left unaligned showed the delay as a gain on its fast
    motion and hid a gyro bias there (fresh seed 2091).
    """
    gyro = L.Delay(0.03, 0.001, 10, (0.0, 50.0))
    accel = L.Delay(0.01, 0.001, 10, (0.0, 50.0))
    both = L.TimeEffect(['angular_velocity.z', 'linear_acceleration.x'], L.pool([gyro, accel]),
                        {('angular_velocity.z',): gyro, ('linear_acceleration.x',): accel},
                        consistent=False)
    taus = field_taus(both, IMU_FIELDS)
    assert taus['angular_velocity.x'] == taus['angular_velocity.z'] == 0.03
    assert taus['linear_acceleration.y'] == taus['linear_acceleration.z'] == 0.01
    one = L.TimeEffect(['angular_velocity.z'], gyro, {('angular_velocity.z',): gyro})
    assert set(field_taus(one, IMU_FIELDS).values()) == {0.03}
    assert set(field_taus(one, IMU_FIELDS)) == set(IMU_FIELDS)
    odom = L.TimeEffect([ODOM_FIELDS[0]], accel, {(ODOM_FIELDS[0],): accel})
    assert field_taus(odom, ODOM_FIELDS) == {f: 0.01 for f in ODOM_FIELDS}
    assert field_taus(odom) == {ODOM_FIELDS[0]: 0.01}


def test_delay_of_a_single_manoeuvre_is_not_claimed():
    """One turn in a long recording: a delay there is one observation, not forty."""
    rate = 100.0
    t = np.arange(0.0, 120.0, 1.0 / rate)
    w = np.where((t > 50.0) & (t < 53.0), np.sin(np.pi * (t - 50.0) / 3.0), 0.0)
    rng = np.random.default_rng(19)
    zero = np.zeros_like(t)
    sim = _imu_rec(t, np.column_stack((zero, zero, w)),
                   np.column_stack((zero, zero, zero + GRAVITY)))
    shifted = np.interp(t - 0.02, t, w)
    real = _imu_rec(t, np.column_stack((zero, zero, shifted)),
                    np.column_stack((zero, zero, zero + GRAVITY)))
    real = _noisy(real, 20, sg=0.01)
    out, _ = analyse_recordings(sim, real)
    claimed = [f for f in out['findings'] if f['effect'] == 'time_offset']
    assert not claimed or claimed[0]['evidence']['blocks'] >= L.MIN_BLOCKS
    assert rng is not None


def test_confidence_and_alternatives_on_every_finding():
    t, w, a = _tumbling_imu(21, duration=90.0)
    rg = w.copy()
    rg[:, 1] += 0.01
    out, _ = analyse_recordings(_imu_rec(t, w, a), _noisy(_imu_rec(t, rg, a), 22))
    assert out['findings']
    for f in out['findings']:
        assert 0.0 <= f['confidence'] <= 1.0
        assert 'fit' in f and 'explanation' in f
        for alt in f.get('alternatives', []):
            assert alt['separating_motion']
