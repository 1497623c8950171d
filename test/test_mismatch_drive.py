# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The drive chain of the mismatch analyser: known drive effects found, none on a null pair."""

from dataclasses import dataclass
from pathlib import Path
import sys

import numpy as np
import pytest

from robot_calib.mismatch import analyse_recordings
from robot_calib.mismatch import drive as D
from robot_calib.mismatch import drive_interval as DI
from robot_calib.mismatch.channels import JOINT_STATE_TYPE, ODOM_TYPE, Topic

DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data' / 'mrclam'


def _commands(seed: int, duration: float = 240.0, rate: float = 50.0):
    """Return t, v, omega: held commands (1-4 s), stops, straight runs and turns both ways."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate)
    edges = np.cumsum(rng.uniform(1.0, 4.0, int(duration)))
    k = np.searchsorted(edges, t)
    vs = np.where(rng.random(k.max() + 1) < 0.15, 0.0, rng.uniform(0.05, 0.35, k.max() + 1))
    ws = np.where(rng.random(k.max() + 1) < 0.3, 0.0, rng.uniform(-0.7, 0.7, k.max() + 1))
    return t, vs[k], ws[k]


def _pair(seed: int, fwd: D.AxisModel, turn: D.AxisModel, noise=(0.004, 0.01)):
    t, v, w = _commands(seed)
    dt = t[1] - t[0]
    rng = np.random.default_rng(seed + 100)
    rv = D.predict(v, np.abs(w), dt, fwd) + noise[0] * rng.standard_normal(t.size)
    rw = D.predict(w, None, dt, turn) + noise[1] * rng.standard_normal(t.size)

    def rec(a, b):
        return {'/odom': Topic('/odom', ODOM_TYPE, t, {D.V: a, D.W: b})}
    return rec(v, w), rec(rv, rw)


def _found(res: dict, effect: str, field: str) -> float:
    for f in res['findings']:
        if f['effect'] == effect and f['channel'].endswith(field):
            return float(next(iter(f['parameters'].values())))
    return float('nan')


CASES = [
    ('drive_lag', D.V, D.AxisModel(tau=0.35), D.AxisModel(tau=0.25), 0.35),
    ('drive_lag', D.W, D.AxisModel(tau=0.35), D.AxisModel(tau=0.25), 0.25),
    ('turn_speed_loss', D.V, D.AxisModel(tau=0.3, k=1.1), D.AxisModel(tau=0.25), 1.1),
    ('drive_dead_time', D.W, D.AxisModel(tau=0.3), D.AxisModel(d=0.15, tau=0.2), 0.15),
    ('drive_deadband', D.W, D.AxisModel(tau=0.3), D.AxisModel(tau=0.2, band=0.15), 0.15),
    ('drive_rate_limit', D.V, D.AxisModel(tau=0.1, limit=0.25), D.AxisModel(tau=0.2), 0.25),
    # one delay on both axes of a lagging drive: its dead time, not a clock offset
    ('drive_dead_time', D.V, D.AxisModel(d=0.1, tau=0.3), D.AxisModel(d=0.1, tau=0.2), 0.1),
    # a drive that settles short of (or past) its command: the chain's gain, judged with it
    ('drive_gain', D.W, D.AxisModel(tau=0.3), D.AxisModel(tau=0.2, gain=-0.08), -0.08),
    ('drive_gain', D.V, D.AxisModel(tau=0.3, k=1.0, gain=0.07), D.AxisModel(tau=0.2), 0.07),
]


@pytest.mark.parametrize('effect,field,fwd,turn,want', CASES)
def test_drive_effect_found(effect, field, fwd, turn, want):
    sim, real = _pair(3, fwd, turn)
    res, _ = analyse_recordings(sim, real)
    got = _found(res, effect, field)
    assert abs(got - want) <= 0.25 * abs(want), (effect, got, res['drive'])
    assert 'Drive model' in res['drive']['/odom']
    # one owner for a scale of the drive's output: no second one named beside the chain's gain
    scales = [f['effect'] for f in res['findings'] if f['channel'].endswith(field) and
              f['effect'] in ('drive_gain', 'wheel_radius_scale', 'track_width_scale')]
    assert len(scales) <= 1, scales


def test_rate_limit_over_smooth_commands_found():
    """A limit that binds only on a few large steps among many small changes is found."""
    t = np.arange(0.0, 240.0, 0.02)
    steps = np.where((t // 8.0) % 2 == 0, 0.0, 0.6) * np.sign(np.sin(0.37 * (t // 8.0) + 0.5))
    w = 0.3 * np.sin(2 * np.pi * t / 20.0) + steps  # smooth turns (0.1 rad/s^2) and steps
    v = 0.2 + 0.1 * np.sin(2 * np.pi * t / 30.0)
    rng = np.random.default_rng(11)
    turn = D.AxisModel(tau=0.15, limit=1.0)
    rw = D.predict(w, None, 0.02, turn) + 0.01 * rng.standard_normal(t.size)
    rv = D.predict(v, np.abs(w), 0.02, D.AxisModel(tau=0.2)) + 0.004 * rng.standard_normal(t.size)

    def rec(a, b):
        return {'/odom': Topic('/odom', ODOM_TYPE, t, {D.V: a, D.W: b})}
    res, _ = analyse_recordings(rec(v, w), rec(rv, rw))
    got = _found(res, 'drive_rate_limit', D.W)
    assert abs(got - 1.0) <= 0.25, (got, res['drive'])


def _lag_finding(res: dict, field: str) -> dict:
    return next(f for f in res['findings'] if f['effect'] == 'drive_lag' and
                f['channel'].endswith(field))


@pytest.mark.parametrize('zeta', [0.4, 0.7])
def test_second_order_drive_named_with_its_damping(zeta):
    """An underdamped turn response is named second order, its damping within 25 %."""
    sim, real = _pair(4, D.AxisModel(tau=0.3), D.AxisModel(tau=0.3, zeta=zeta))
    res, _ = analyse_recordings(sim, real)
    lag = _lag_finding(res, D.W)
    assert abs(lag['parameters']['damping'] - zeta) <= 0.25 * zeta, lag
    assert abs(lag['parameters']['tau'] - 0.3) <= 0.25 * 0.3, lag
    assert 'second order' in lag['explanation']
    # the first-order forward axis stays first order
    assert 'damping' not in _lag_finding(res, D.V)['parameters']


def test_second_order_step_overshoots_and_chain_matches_the_simulator():
    """The simulator's second order overshoots as zeta says; the chain's response is the same."""
    from robot_calib.sim.drive import DriveDynamics
    from robot_calib.sim.params import DriveParams

    zeta, tau, dt = 0.4, 0.3, 0.01
    u = np.zeros((600, 2))
    u[50:, 1] = 0.5
    sim = DriveDynamics(DriveParams(angular_time_constant=tau, angular_damping=zeta), dt,
                        0.3, 0.05)(u)[:, 1]
    want = np.exp(-np.pi * zeta / np.sqrt(1 - zeta * zeta))
    assert sim.max() / 0.5 - 1.0 == pytest.approx(want, rel=0.02)
    # the mean delay of the step response is tau, as a first-order lag's
    assert np.sum(1.0 - sim[50:] / 0.5) * dt == pytest.approx(tau, rel=0.02)
    chain = D.predict(u[:, 1], None, dt, D.AxisModel(tau=tau, zeta=zeta))
    assert np.max(np.abs(chain - sim)) < 1e-9


def test_a_lagging_drive_names_its_lags_and_nothing_else():
    """Two first-order lags: no deadband, limit, loss or gain of size zero beside them."""
    sim, real = _pair(9, D.AxisModel(tau=0.3), D.AxisModel(tau=0.2))
    res, _ = analyse_recordings(sim, real)
    named = {f['effect'] for f in res['findings'] + res['minor_findings']}
    assert named == {'drive_lag'}, res['drive']


def _capped(seed: int, limit: float, straight: bool = False) -> dict:
    """Return the analysis of a lagging drive whose faster wheel is capped (half track 0.15 m)."""
    from robot_calib.mismatch import drive_cap as DC

    t, v, w = _commands(seed)
    if straight:  # hardly turning
        w = 0.01 * np.sin(t / 7.0)
    dt = t[1] - t[0]
    lv = D.predict(v, None, dt, D.AxisModel(tau=0.3))
    lw = D.predict(w, None, dt, D.AxisModel(tau=0.2))
    s = DC.factor((lv, lw), DC.WheelCap(limit, 0.15))
    rng = np.random.default_rng(seed + 100)

    def rec(a, b):
        return {'/odom': Topic('/odom', ODOM_TYPE, t, {D.V: a, D.W: b})}
    res, _ = analyse_recordings(rec(v, w), rec(s * lv + 0.004 * rng.standard_normal(t.size),
                                               s * lw + 0.01 * rng.standard_normal(t.size)))
    return res


@pytest.mark.parametrize('seed,limit', [(9, 0.3), (7, 0.18)])
def test_wheel_speed_cap_found_with_the_lags_under_it(seed, limit):
    """A differential drive whose faster wheel is capped (18 % or 57 % of the time)."""
    res = _capped(seed, limit)
    cap = next(f for f in res['findings'] if f['effect'] == 'wheel_speed_limit')
    assert cap['parameters']['limit'] == pytest.approx(limit, rel=0.05), cap
    assert cap['parameters']['half_track'] == pytest.approx(0.15, rel=0.15), cap
    for field, tau in ((D.V, 0.3), (D.W, 0.2)):
        assert _found(res, 'drive_lag', field) == pytest.approx(tau, rel=0.25), res['drive']
    # nothing else of the drive is named beside the cap and the lags, no scale over 2 %
    drive = {f['effect'] for f in res['findings'] if f['effect'].startswith('drive_') or
             f['effect'] == 'turn_speed_loss'}
    assert drive == {'drive_lag'}, res['drive']
    scales = [f['parameters']['scale'] for f in res['findings']
              if f['effect'] in ('track_width_scale', 'wheel_radius_scale')]
    assert all(abs(k) < 0.02 for k in scales), scales


def test_a_cap_met_driving_straight_has_no_half_track():
    """Capped only while hardly turning: the top speed named, its half track unknown (None)."""
    res = _capped(9, 0.25, straight=True)
    cap = next(f for f in res['findings'] if f['effect'] == 'wheel_speed_limit')
    assert cap['parameters']['limit'] == pytest.approx(0.25, rel=0.05), cap
    assert cap['parameters']['half_track'] is None, cap
    assert 'cannot be told' in cap['explanation']


def test_cap_fit_keeps_a_half_track_a_robot_can_have():
    """
    A turn-rate ceiling and little forward motion: the half track stays in the searched range.

    Unbounded, the limit and the half track grow together without end (1e12 m
    on a real pair): a turn-rate cap dressed as the wheel of no robot.
    """
    from robot_calib.mismatch import drive_cap as DC
    rng = np.random.default_rng(7)
    t, v, w = _commands(5)
    vh, wh = 0.1 * v, 1.5 * w
    yv = vh + 0.002 * rng.standard_normal(t.size)
    yw = np.clip(wh, -0.5, 0.5) + 0.01 * rng.standard_normal(t.size)
    cap, with_cap, without = DC.fit((vh, wh), (yv, yw), np.ones(t.size, bool))
    assert cap is not None and with_cap < without
    assert DC.HALVES[0] <= cap.half <= DC.HALVES[-1] * (1 + 1e-9), cap


def test_drive_null_pair_has_no_finding():
    sim, real = _pair(5, D.AxisModel(), D.AxisModel())
    res, _ = analyse_recordings(sim, real)
    assert res['findings'] == [], [(f['effect'], f['parameters']) for f in res['findings']]


def test_drive_even_odd_split_has_no_finding():
    """One lagging drive's odometry, its even samples against its odd ones: nothing to name."""
    _, real = _pair(6, D.AxisModel(tau=0.3), D.AxisModel(tau=0.2))
    tp = real['/odom']

    def half(k):
        return {'/odom': Topic('/odom', ODOM_TYPE, tp.t[k::2],
                               {f: x[k::2] for f, x in tp.fields.items()})}
    res, _ = analyse_recordings(half(0), half(1))
    assert res['findings'] == [], [(f['effect'], f['parameters']) for f in res['findings']]


def _wheel_pair(seed: int, wheel: D.AxisModel, noise: float = 0.05):
    """Return sim, real joint states of two wheels (r 0.05 m, track 0.3 m); real via ``wheel``."""
    t, v, w = _commands(seed)
    dt = t[1] - t[0]
    rng = np.random.default_rng(seed + 200)
    rates = {'left_wheel_joint': (v - 0.15 * w) / 0.05, 'right_wheel_joint': (v + 0.15 * w) / 0.05}

    def rec(fn):
        return {'/joint_states': Topic('/joint_states', JOINT_STATE_TYPE, t, {
            f'velocity.{j}': fn(x) for j, x in rates.items()})}
    return rec(lambda x: x), rec(lambda x: D.predict(x, None, dt, wheel) +
                                 noise * rng.standard_normal(t.size))


def test_wheel_joints_get_the_drive_chain():
    """Each wheel of a joint-state topic is a motor of its own: its dead time and lag named."""
    sim, real = _wheel_pair(7, D.AxisModel(d=0.1, tau=0.25))
    res, _ = analyse_recordings(sim, real)
    for j in ('left_wheel_joint', 'right_wheel_joint'):
        d, tau = (_found(res, e, f'velocity.{j}') for e in ('drive_dead_time', 'drive_lag'))
        assert abs(np.nan_to_num(d) + tau - 0.35) <= 0.25 * 0.35, (j, d, tau, res['drive'])
    assert 'wheel rate' in res['drive']['/joint_states']
    clean, _ = analyse_recordings(*_wheel_pair(8, D.AxisModel()))  # the same wheels, noise
    assert clean['findings'] == [], [(f['effect'], f['parameters']) for f in clean['findings']]


def _wheels_capped(seed: int, cap: float, one: bool = False, one_way: bool = False) -> dict:
    """
    Return the analysis of two wheels (lags 0.25 / 0.3 s) whose faster one is capped (rad/s).

    ``one``: the left wheel alone clipped at ``cap``, the right one free (no coupling);
    ``one_way``: always turning left (the right wheel the faster one).
    """
    t, v, w = _commands(seed)
    if one_way:
        w = np.abs(w) + 0.2
    dt = t[1] - t[0]
    left, right = (D.predict((v + sign * 0.15 * w) / 0.05, None, dt, D.AxisModel(tau=tau))
                   for sign, tau in ((-1.0, 0.25), (1.0, 0.3)))
    if one:
        real = (np.clip(left, -cap, cap), right)
    else:  # the simulator's cap (robot_calib/sim/drive.py), written out here
        s = np.minimum(1.0, cap / np.maximum(np.maximum(np.abs(left), np.abs(right)), 1e-12))
        real = (s * left, s * right)
    rng = np.random.default_rng(seed + 200)
    names = ('velocity.left_wheel_joint', 'velocity.right_wheel_joint')

    def rec(a, b):
        return {'/joint_states': Topic('/joint_states', JOINT_STATE_TYPE, t, dict(zip(names, (
            a, b))))}
    res, _ = analyse_recordings(rec((v - 0.15 * w) / 0.05, (v + 0.15 * w) / 0.05),
                                rec(*(x + 0.05 * rng.standard_normal(t.size) for x in real)))
    return res


@pytest.mark.parametrize('seed,cap', [(9, 6.0), (7, 4.0)])
def test_wheel_rate_cap_on_joint_states_found_with_the_lags_under_it(seed, cap):
    """Two wheels whose faster one is capped (19 % or 51 % of the time): W in rad/s, the lags."""
    res = _wheels_capped(seed, cap)
    found = [f for f in res['findings'] if f['effect'] == 'wheel_speed_limit']
    assert len(found) == 1, res['drive']
    assert found[0]['parameters']['limit'] == pytest.approx(cap, rel=0.02), found
    assert found[0]['parameters']['half_track'] is None, found
    assert found[0]['units']['limit'] == 'rad/s'
    assert 'wheel rate' in found[0]['explanation']
    assert len(found[0]['channels']) == 2
    for joint, tau in (('left_wheel_joint', 0.25), ('right_wheel_joint', 0.3)):
        got = _found(res, 'drive_lag', f'velocity.{joint}')
        assert got == pytest.approx(tau, rel=0.1), (joint, got, res['drive'])
    # the cap is not taken for a gain, a rate limit or a deadband of the wheels
    drive = {f['effect'] for f in res['findings'] if f['effect'].startswith('drive_')}
    assert drive == {'drive_lag'}, res['drive']


def test_uncapped_or_one_wheel_clipped_joint_states_name_no_wheel_cap():
    """
    No cap: none named. The left wheel alone clipped (no coupling): no common cap named.

    A common cap met on the right wheel only (always turning left): the left's own limit is
    not seen, so it is not named either.
    """
    for res in (_wheels_capped(9, 1e3), _wheels_capped(9, 5.0, one=True),
                _wheels_capped(9, 6.0, one_way=True)):
        caps = [f['parameters'] for f in res['findings'] + res['minor_findings']
                if f['effect'] == 'wheel_speed_limit']
        assert caps == [], (caps, res['drive'])


def test_simulator_wheel_cap_round_trip_on_joint_states(tmp_path):
    """``simulate drive`` with drive.max_wheel_speed 6 rad/s, followed ideally: W and the lags."""
    from robot_calib import cli
    from robot_calib.mismatch.channels import read_bag

    sets = [a for kv in ('drive.linear_time_constant=0.25', 'drive.angular_time_constant=0.25',
                         'drive.max_wheel_speed=6', 'wheels.left_radius_error=0',
                         'wheels.right_radius_error=0', 'wheels.track_width_error=0')
            for a in ('--set', kv)]
    assert cli.main(['simulate', 'drive', '--out', str(tmp_path / 'real'), '--duration', '120',
                     '--seed', '3', *sets]) == 0
    assert cli.main(['simulate', 'follow', str(tmp_path / 'real'), '--out',
                     str(tmp_path / 'ideal'), *sets[6:]]) == 0  # the same wheels, no drive
    sim, real = ({'/joint_states': read_bag(tmp_path / n)['/joint_states']}
                 for n in ('ideal', 'real'))
    res, _ = analyse_recordings(sim, real)
    cap = [f['parameters']['limit'] for f in res['findings']
           if f['effect'] == 'wheel_speed_limit']
    assert cap == [pytest.approx(6.0, rel=0.02)], res['drive']
    for joint in ('left_wheel_joint', 'right_wheel_joint'):  # both axes lag 0.25 s: each wheel
        got = _found(res, 'drive_lag', f'velocity.{joint}')
        assert got == pytest.approx(0.25, rel=0.1), (joint, got, res['drive'])


def test_chain_pieces():
    u = np.r_[np.zeros(10), np.ones(100)]
    assert np.allclose(D.deadband(np.array([0.05, -0.2]), 0.1), [0.0, -0.2])
    assert np.max(np.diff(D.rate_limit(u, 0.02, 1.0))) <= 0.02 + 1e-12
    y = D.lag(u, 0.02, 0.2)
    assert abs(y[10 + 10] - (1 - np.exp(-11 * 0.02 / 0.2))) < 1e-9
    assert np.allclose(D.shift(u, 0.1, 0.02)[:15], 0.0)


def _with_std(res: dict, effect: str, field: str) -> tuple:
    """Return (value, std, explanation) of the finding ``effect`` on ``field``."""
    for f in res['findings']:
        if f['effect'] == effect and f['channel'].endswith(field):
            k = next(iter(f['parameters']))
            assert set(f['std']) == set(f['parameters'])
            return float(f['parameters'][k]), float(f['std'][k]), f['explanation']
    return float('nan'), float('nan'), ''


def test_drive_std_covers_the_truth():
    """A known dead time and lag: each std finite, positive, the truth within 4 std."""
    sim, real = _pair(3, D.AxisModel(tau=0.35), D.AxisModel(d=0.15, tau=0.2))
    res, _ = analyse_recordings(sim, real)
    for effect, field, want in (('drive_dead_time', D.W, 0.15), ('drive_lag', D.W, 0.2),
                                ('drive_lag', D.V, 0.35)):
        val, sd, text = _with_std(res, effect, field)
        assert np.isfinite(sd) and sd > 0, (effect, field, val, sd)
        assert abs(val - want) <= 4.0 * sd, (effect, field, val, sd)
        assert ' +- ' in text, text
        # an interval, not a statement of ignorance: well under the value itself
        assert sd < 0.5 * want, (effect, field, val, sd)


def _turn_std(noise: float, groups: int = 8) -> dict:
    """Return the jackknife std of a turn axis with a dead time and a lag, at ``noise`` rad/s."""
    t, _, w = _commands(7, duration=150.0, rate=20.0)
    dt = t[1] - t[0]
    rng = np.random.default_rng(8)
    y = D.predict(w, None, dt, D.AxisModel(d=0.12, tau=0.25)) + \
        noise * rng.standard_normal(t.size)
    ok = np.ones(t.size, bool)
    parts = {'drive_dead_time', 'drive_lag'}
    return DI.block_jackknife(lambda m: D.fit_axis(w, None, y, m, dt, 0.5, parts, refine=True),
                              ok, groups)


def test_drive_jackknife_shrinks_with_the_noise():
    """Four times less noise: the jackknife's std of the dead time and lag at least halves."""
    loud, quiet = _turn_std(0.04), _turn_std(0.01)
    for k in ('d', 'tau'):
        assert np.isfinite(quiet[k]) and quiet[k] > 0, (k, loud, quiet)
        assert quiet[k] < 0.5 * loud[k], (k, loud[k], quiet[k])
    assert np.isnan(loud['band']) and np.isnan(loud['limit'])  # not fitted: no interval


def test_block_jackknife_of_a_mean():
    """The jackknife of a mean over contiguous groups is the standard error of the group means."""
    @dataclass
    class Mean:
        mu: float

    y = np.random.default_rng(1).standard_normal(800) + np.repeat([0.0, 1.0], 400)
    ok = np.ones(y.size, bool)
    ok[::10] = False  # 720 samples: groups of equal count
    sd = DI.block_jackknife(lambda w: Mean(float(y[w].mean())), ok, 8)
    means = [y[g].mean() for g in DI.groups(ok, 8)]
    assert abs(sd['mu'] - np.std(means, ddof=1) / np.sqrt(8)) < 1e-12
    assert DI.block_jackknife(lambda w: Mean(1.0), ok, 8) == {'mu': pytest.approx(np.nan,
                                                                                  nan_ok=True)}
    assert DI.block_jackknife(lambda w: Mean(1.0), ok, 2) is None


@pytest.mark.skipif(not DATA.is_dir(), reason='MR.CLAM data not available')
def test_mrclam_names_lag_and_turn_speed_loss():
    """Each 300 s window: the turn speed loss of the independent fit (0.99-1.12 s/rad)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'benchmarks'))
    import drive_pairs as DP
    lags = 0
    for p in DP.mrclam_pairs(DATA):
        sim, real = DP.recordings(p)
        res, _ = analyse_recordings(sim, real)
        k = _found(res, 'turn_speed_loss', D.V)
        assert 0.8 <= k <= 1.5, res['drive']
        _, sd, _ = _with_std(res, 'turn_speed_loss', D.V)
        assert 0.0 < sd < 0.2, (p.name, k, sd)
        lags += 'time constant' in res['drive']['/odom']
    # the forward lag is missed where the time stage took the turn rate's delay as a drift
    assert lags >= 3


@pytest.mark.skipif(not DATA.is_dir(), reason='MR.CLAM data not available')
def test_mrclam_turn_deficit_is_no_top_speed():
    """
    Robot 2's first window with its turn rate 8.9 % short: no wheel-speed cap named.

    Its straight commands sit at one speed; a cap just over it (0.0695 m/s,
    half track unknown) fitted the turn deficit of the turns it met, and the
    forward speed alone does not call for it: a top speed is judged on the
    forward speed.
    """
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'benchmarks'))
    import drive_pairs as DP
    pair = next(p for p in DP.mrclam_pairs(DATA) if p.name == 'Robot2_w0')
    sim, real = DP.recordings(pair)
    odom = real['/odom']
    fields = dict(odom.fields, **{D.W: odom.fields[D.W] * (1.0 - 0.089)})
    res, _ = analyse_recordings(sim, dict(real, **{'/odom': Topic('/odom', odom.msgtype,
                                                                  odom.t, fields)}))
    named = [f['effect'] for f in res['findings'] + res.get('minor_findings', [])]
    assert 'wheel_speed_limit' not in named, res['drive']
    assert 'track_width_scale' in named or 'drive_gain' in named, named


def test_value_with_std_text():
    """The std to two digits, the value to its decimal place; nothing said without a std."""
    assert DI.with_std(0.25312, 0.031) == '0.253 +- 0.031'
    assert DI.with_std(0.17501, 0.04546, 1000.0) == '175 +- 45'
    assert DI.with_std(0.25, float('nan')) == '0.25'
