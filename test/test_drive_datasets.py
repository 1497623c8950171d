# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The MR.CLAM and Lost in the Woods loaders and the drive pairs built from them."""

from pathlib import Path
import sys

import numpy as np
import pytest

from robot_calib.io.datasets import lost_in_woods, mrclam

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'benchmarks'))

import drive_pairs as D  # noqa: E402,I100

HEAD = '# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n# format\n'


def _write_run(folder: Path, robot: int = 1, gap: bool = True) -> None:
    """Write a tiny MR.CLAM run: 0.2 m/s then a 0.3 rad/s turn, Vicon with a 1 s gap."""
    tc = np.arange(0.0, 20.0, 0.014) + 1000.0
    v = np.where(tc < 1010.0, 0.2, 0.1)
    w = np.where(tc < 1010.0, 0.0, 0.3)
    rows = [f'{a:.3f} \t {b:.3f} \t {c:.3f}' for a, b, c in zip(tc, v, w)]
    rows.insert(5, rows[5])  # a repeated stamp is dropped
    (folder / f'Robot{robot}_Odometry.dat').write_text(HEAD + '\n'.join(rows) + '\n')
    tg = np.arange(0.0, 20.0, 1 / 60) + 1000.0
    x, y, yaw = D.integrate(tg, np.interp(tg, tc, v), np.interp(tg, tc, w), (1.0, 2.0, 0.5))
    keep = ~((tg > 1005.0) & (tg < 1006.0)) if gap else np.ones(tg.size, bool)
    rows = [f'{a:.3f} \t {b:.6f} \t {c:.6f} \t {d:.6f}'
            for a, b, c, d in zip(tg[keep], x[keep], y[keep], yaw[keep])]
    (folder / f'Robot{robot}_Groundtruth.dat').write_text(HEAD + '\n'.join(rows) + '\n')


def test_mrclam_parses_and_cuts_gaps(tmp_path):
    _write_run(tmp_path)
    run = mrclam.load(tmp_path, 1)
    assert mrclam.list_robots(tmp_path) == [1]
    assert np.all(np.diff(run.t_cmd) > 0) and np.all(np.diff(run.t_gt) > 0)
    assert run.v_cmd[0] == pytest.approx(0.2) and run.w_cmd[-1] == pytest.approx(0.3)
    gaps = run.gaps()
    assert gaps.shape == (1, 2) and gaps[0, 1] - gaps[0, 0] == pytest.approx(1.0, abs=0.03)
    pairs = D.mrclam_pairs(tmp_path, robots=(1,), window=15.0)
    assert len(pairs) == 1
    p = pairs[0]
    # no real sample inside the gap: the hole is cut, not bridged
    assert not np.any((p.real['t'] > 1005.0) & (p.real['t'] < 1006.0))
    assert p.real['t'].size < p.sim['t'].size
    # the derivative recovers the body-frame twist the poses were made from
    straight = (p.real['t'] > 1001.0) & (p.real['t'] < 1004.5)
    assert np.allclose(p.real['v'][straight], 0.2, atol=2e-3)
    assert np.allclose(p.real['w'][straight], 0.0, atol=2e-3)
    turn = (p.real['t'] > 1011.0) & (p.real['t'] < 1014.0)
    assert np.allclose(p.real['w'][turn], 0.3, atol=5e-3)
    assert np.allclose(p.real['v'][turn], 0.1, atol=2e-3)
    # the ideal robot executing the commands starts on the real pose and follows it
    assert np.hypot(p.sim['x'][-1] - p.real['x'][-1], p.sim['y'][-1] - p.real['y'][-1]) < 0.02
    sim, real = D.recordings(p)
    assert set(sim) == {'/odom'} and set(real) == {'/odom', '/cmd_vel'}


def test_mrclam_pair_bags_round_trip(tmp_path):
    _write_run(tmp_path, gap=False)
    p = D.mrclam_pairs(tmp_path, robots=(1,), window=10.0)[0]
    s, r = D.write_pair(p, tmp_path / 'pair')
    from robot_calib.mismatch.channels import read_bag
    rs, rr = read_bag(s), read_bag(r)
    assert len(rs['/odom']) == p.sim['t'].size and len(rr['/cmd_vel']) == p.cmd['t'].size
    assert np.allclose(rr['/odom'].fields['twist.twist.linear.x'], p.real['v'])


def test_lost_in_woods_parses(tmp_path):
    from scipy.io import savemat
    n = 50
    t = np.arange(n) * 0.1
    valid = np.ones(n, np.uint8)
    valid[20] = 0
    savemat(tmp_path / 'd.mat', {'t': t[:, None], 'v': np.full((n, 1), 0.3),
                                 'om': np.full((n, 1), 0.1), 'x_true': (0.3 * t)[:, None],
                                 'y_true': np.zeros((n, 1)), 'th_true': (0.1 * t)[:, None],
                                 'true_valid': valid[:, None], 'v_var': np.array([[0.01]])})
    run = lost_in_woods.load(tmp_path / 'd.mat')
    assert run.t.size == n and not run.valid[20] and np.isnan(run.x[20])
    assert run.v_var == pytest.approx(0.01) and np.isnan(run.om_var)
    p = D.woods_pair(tmp_path / 'd.mat')
    # samples next to the invalid one are cut from the ideal odometry
    assert not np.any(np.isin(np.round(p.sim['t'], 3), [1.9, 2.0, 2.1]))
    assert p.real['t'].size == n
    with pytest.raises(ValueError):
        savemat(tmp_path / 'bad.mat', {'t': t[:, None]})
        lost_in_woods.load(tmp_path / 'bad.mat')


def test_real_mrclam_and_woods(shared_data):
    pairs = D.mrclam_pairs(shared_data / 'mrclam')
    assert len(pairs) >= 4
    for p in pairs:
        assert p.real['t'].size > 0.95 * p.sim['t'].size
        assert 0.8 < np.median(np.diff(p.real['t'])) * D.RATE < 1.2
    w = D.woods_pair(shared_data / 'utias_lost_in_woods' / 'dataset2.mat', window=300.0)
    assert w.real['t'].size == 3000 and w.sim['t'].size > 2800


def test_independent_fit_recovers_known_drive():
    import drive_fit as F
    rng = np.random.default_rng(3)
    tc = np.cumsum(rng.uniform(0.5, 2.0, 60))
    vc = rng.choice([0.0, 0.1, 0.2, 0.3], tc.size)
    wc = rng.choice([-0.4, 0.0, 0.0, 0.2, 0.4], tc.size)
    dt = 0.02
    grid = np.arange(0.0, tc[-1], dt)
    d, tau, g, k = 0.12, 0.2, 0.97, 1.1
    u = F.held(tc, vc, grid - d) * (1 - k * np.abs(F.held(tc, wc, grid - d)))
    v = g * F.lag(u, dt, tau) + 0.003 * rng.standard_normal(grid.size)
    w = 1.02 * F.lag(F.held(tc, wc, grid - 0.06), dt, 0.15)
    prm = F.FitParams(dead_max=0.3, tau_points=20)
    fw = F.fit_axis('forward', tc, vc, wc, grid, v, prm)
    assert fw['dead_time'] == pytest.approx(d, abs=0.02)
    assert fw['tau'] == pytest.approx(tau, abs=0.02)
    assert fw['gain'] == pytest.approx(g, abs=0.01) and fw['k'] == pytest.approx(k, abs=0.05)
    tn = F.fit_axis('turn', tc, vc, wc, grid, w, prm)
    assert tn['gain'] == pytest.approx(1.02, abs=0.01)
    assert tn['dead_time'] + tn['tau'] == pytest.approx(0.21, abs=0.02)


def test_added_drive_effects_act_as_described():
    import drive_added as DA
    t = np.concatenate((np.arange(0.0, 10.0, 0.02), np.arange(11.0, 20.0, 0.02)))
    step = (t > 2.0).astype(float)
    f = {DA.FWD: 0.2 * step, DA.TURN: 0.4 * step}
    cmd = {'t': np.array([0.0, 2.0, 15.0]), 'v': np.array([0.0, 0.2, 0.2]),
           'w': np.array([0.0, 0.4, 0.01])}
    e = {'effect': 'speed_scale', 'field': DA.FWD, 'parameters': {'scale': 0.08}}
    assert np.allclose(DA.apply(t, f, e, cmd)[1][DA.FWD], 1.08 * f[DA.FWD])
    e = {'effect': 'transport_delay', 'field': None, 'parameters': {'tau': 0.1}}
    assert np.allclose(DA.apply(t, f, e, cmd)[0], t + 0.1)
    e = {'effect': 'time_constant', 'field': DA.TURN, 'parameters': {'tau': 0.3}}
    y = DA.apply(t, f, e, cmd)[1][DA.TURN]
    i = np.searchsorted(t, 2.0 + 0.3)
    assert y[i] == pytest.approx(0.4 * (1 - np.exp(-1)), abs=0.02)  # one time constant
    assert y[np.searchsorted(t, 11.0)] == pytest.approx(0.4, abs=1e-3)  # restarts per stretch
    e = {'effect': 'accel_limit', 'field': DA.FWD, 'parameters': {'limit': 0.1}}
    y = DA.apply(t, f, e, cmd)[1][DA.FWD]
    # the motion changes no faster than the limit (its 0.2 s mean starts 0.1 s early)
    ramp = (t > 2.2) & (t < 9.9)
    assert np.max(np.diff(y[ramp])) <= 0.1 * 0.02 + 1e-12
    assert y[np.searchsorted(t, 3.0)] == pytest.approx(0.1 * 1.1, abs=0.005)
    # the measurement's noise on a steady speed is left as it was (not slewed)
    noise = 0.01 * np.random.default_rng(1).standard_normal(t.size)
    y = DA.apply(t, {DA.FWD: 0.2 + noise, DA.TURN: f[DA.TURN]}, e, cmd)[1][DA.FWD]
    assert np.std(y[100:400]) == pytest.approx(np.std(noise[100:400]), rel=0.05)
    e = {'effect': 'deadband', 'field': DA.TURN, 'parameters': {'band': 0.03}}
    y = DA.apply(t, f, e, cmd, response=0.2)[1][DA.TURN]
    assert np.all(y[(t > 15.25)] == 0.0) and np.all(y[(t > 12.0) & (t < 15.0)] == 0.4)
