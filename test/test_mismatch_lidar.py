# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The lidar in the mismatch analyser: coverage of every topic, motion and beam effects.

Simulated pairs in a room (:func:`lidar_inject.simulated_run`): the real side is
the simulated scans with fresh noise and one known effect; each effect must be
found within 25 %, a null pair must give nothing, and a drive without turning
must refuse the mounting offset. A real-data check on the MIT CSAIL log skips
without the shared data.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from robot_calib.core import types as T
from robot_calib.io.bags import BagWriter
from robot_calib.mismatch import analyse
from robot_calib.mismatch import lidar as L
from robot_calib.mismatch import lidar_inject as inj

DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data' / 'carmen'


@pytest.fixture(scope='module')
def run():
    return inj.simulated_run(60.0, seed=1)


def _analyse(run, effect=None, value=None, odom=None, seed=3):
    real = inj.inject(run['scans'], 'noise', 0.005, seed=seed)
    if effect is not None:
        real = inj.inject(real, effect, value, seed=seed + 1)
    od = odom or run['odom']
    return L.analyse_lidar({'/scan': run['scans']}, {'/scan': real}, od, od)


CASES = [('lidar_mounting_yaw', math.radians(1.0), 'yaw'),
         ('lidar_mounting_offset', (0.06, -0.04), ('x', 'y')),
         ('lidar_time_offset', 0.05, 'tau'),
         ('range_bias', 0.03, 'bias'),
         ('range_scale', 0.01, 'scale'),
         ('range_noise_growth', 0.004, 's1'),
         ('dropout_rate', (0.1, 4.0), ('rate', 'beyond'))]


@pytest.mark.parametrize('effect,value,keys', CASES, ids=[c[0] for c in CASES])
def test_each_injected_effect_is_found_within_25_percent(run, effect, value, keys):
    out = _analyse(run, effect, value)
    found = [f for f in out['findings'] if f['effect'] == effect]
    assert found, out
    keys = keys if isinstance(keys, tuple) else (keys,)
    values = value if isinstance(value, tuple) else (value,)
    for k, v in zip(keys, values):
        assert abs(found[0]['parameters'][k] - v) <= 0.25 * abs(v), (k, found[0])
    f = found[0]
    assert 0.0 < f['confidence'] <= 1.0 and f['window'] is None
    assert f['fit']['heldout_rmse_after'] < f['fit']['heldout_rmse_before']
    # nothing else is named alongside
    others = {g['effect'] for g in out['findings']} - {effect}
    assert not others, out['findings']


def test_null_pair_has_no_finding(run):
    for seed in (5, 9):
        assert _analyse(run, seed=seed)['findings'] == []


def test_offset_refused_without_turning():
    run = inj.simulated_run(60.0, seed=2, turn=False)
    out = _analyse(run, 'lidar_time_offset', 0.0)
    real = inj.inject(inj.inject(run['scans'], 'noise', 0.005, seed=3),
                      'lidar_mounting_offset', (0.06, 0.0))
    # stamps shifted with the odometry: the beams are not compared, the motion is
    res = L.analyse_lidar({'/scan': run['scans']}, {'/scan': [T.ScanSample(
        t=s.t + 0.5, angle_min=s.angle_min, angle_increment=s.angle_increment,
        ranges=s.ranges) for s in real]}, run['odom'],
        (run['odom'][0] + 0.5, run['odom'][1], run['odom'][2]))
    assert not [f for f in res['findings'] if f['effect'] == 'lidar_mounting_offset']
    reasons = ' '.join(d['reason'] for d in res['not_judged'])
    assert 'turn' in reasons, res['not_judged']
    assert out['findings'] == []


def _bag(path, run, scans, with_scan=True, extra=False):
    t, v, w = run['odom']
    items = [('/odom', T.OdomSample(float(a), 0.0, 0.0, 0.0, vx=float(b), wz=float(c)))
             for a, b, c in zip(t, v, w)]
    items += [('/cmd_vel', T.TwistSample(float(a), vx=float(b), wz=float(c)))
              for a, b, c in zip(t[::5], v[::5], w[::5])] if extra else []
    if with_scan:
        items += [('/scan', s) for s in scans]
    with BagWriter(path) as bag:
        for topic, s in sorted(items, key=lambda z: z[1].t):
            bag.write(topic, s)


def test_scan_topic_compared_or_listed_in_not_judged(tmp_path, run):
    short = inj.simulated_run(40.0, seed=4)
    sim, real = tmp_path / 'sim', tmp_path / 'real'
    _bag(sim, short, short['scans'])
    noisy = inj.inject(short['scans'], 'noise', 0.005, seed=1)
    _bag(real, short, inj.inject(noisy, 'range_scale', 0.015), extra=True)
    out = analyse(sim, real, tmp_path / 'out', plots=False)
    assert '/scan' in out['lidar']['judged']
    assert any(f['effect'] == 'range_scale' for f in out['findings'])
    assert out['verdict'] == 'mismatch'
    # a scan in one bag only, and a topic nobody compares, are listed with a reason
    real2 = tmp_path / 'real2'
    _bag(real2, short, short['scans'], with_scan=False, extra=True)
    out = analyse(sim, real2, tmp_path / 'out2', plots=False)
    nj = {d['channel']: d['reason'] for d in out['not_judged']}
    assert '/scan' in nj and 'missing' in nj['/scan']
    listed = {d['channel'] for d in out['not_judged']} | set(out['channels']) | \
        set(out['time_alignment'])
    for topic in ('/odom', '/cmd_vel', '/scan'):
        assert any(x == topic or x.startswith(topic + '.') for x in listed), (topic, listed)


@pytest.mark.skipif(not (DATA / 'mit-csail.clf').exists(), reason='shared data absent')
def test_mit_csail_injected_yaw_and_null():
    from robot_calib.io.datasets import carmen
    log = carmen.read_log(DATA / 'mit-csail.clf')
    scans = log.scans[:700]
    od = log.odometry()[:700]
    odom = (np.array([o.t for o in od]), np.array([o.vx for o in od]),
            np.array([o.wz for o in od]))
    prm = L.LidarMismatchParams(max_pairs=400)
    base = inj.inject(scans, 'noise', 0.01, seed=1)
    null = L.analyse_lidar({'/scan': scans}, {'/scan': base}, odom, odom, prm)
    assert null['findings'] == []
    real = inj.inject(base, 'lidar_time_offset', 0.06)
    out = L.analyse_lidar({'/scan': scans}, {'/scan': real}, odom, odom, prm)
    tau = [f['parameters']['tau'] for f in out['findings']
           if f['effect'] == 'lidar_time_offset']
    assert tau and abs(tau[0] - 0.06) < 0.015


def test_lidar_findings_reach_the_simulator_parameters():
    from robot_calib.core.params import to_flat
    from robot_calib.mismatch import export
    from robot_calib.sim.params import SimParams
    fs = {'verdict': 'mismatch', 'findings': [
        {'channel': '/scan.ranges', 'effect': 'range_scale', 'parameters': {'scale': 0.012},
         'window': None, 'confidence': 0.9},
        {'channel': '/scan.stamp', 'effect': 'lidar_time_offset', 'parameters': {'tau': 0.04},
         'window': None, 'confidence': 0.9}]}
    text = export.sim_params_text(fs)
    flat = to_flat(SimParams())
    if 'lidar.range_scale' in flat:
        import yaml
        written = yaml.safe_load(text)
        assert written['sim']['lidar']['range_scale'] == pytest.approx(0.012)
        # the scan delay reaches the simulator as its lidar time offset
        if 'lidar.time_offset' in flat:
            assert written['sim']['lidar']['time_offset'] == pytest.approx(0.04)
        else:
            assert written['sim']['latency']['scan'] == pytest.approx(0.04)
    else:
        assert 'range_scale on /scan.ranges' in text


def test_recast_keeps_isolated_returns_and_edges():
    # every other beam returns (as far, sparse surfaces do): a turned or moved scanner
    # must not lose them at the gaps of the polyline (it would read as a dropout)
    ang = -math.pi / 2 + np.arange(181) * math.radians(1.0)
    r = np.where(np.arange(181) % 2 == 0, 6.0, np.inf)
    r[60:90] = 2.0 + 0.01 * np.arange(30)  # a near surface with depth edges
    s = T.ScanSample(t=0.0, angle_min=float(ang[0]), angle_increment=math.radians(1.0),
                     ranges=r, range_min=0.05, range_max=30.0)
    for effect, value in (('lidar_mounting_yaw', math.radians(1.0)),
                          ('lidar_mounting_yaw', math.radians(0.5)),
                          ('lidar_mounting_offset', (0.03, 0.0))):
        out = inj.inject([s], effect, value)[0].ranges
        assert np.isfinite(out).sum() >= np.isfinite(r).sum() - 2, (effect, value)


def _sim_pair(real_sets, sim_sets=(), duration=60.0, scenario='drive'):
    from robot_calib.sim import engine
    from robot_calib.sim.scenario import BuildContext

    def one(sensor_seed, sets):
        sc = engine.get_scenario(scenario)
        p = engine.make_params(sc, list(sets))
        setup = sc.build(BuildContext(p, duration, 7, engine.rng_for(7, 'scenario')))
        res = engine.run_setup(setup, p, duration, sensor_seed, sc)
        s, t0 = res.sensors, p.start_time
        return res.topic('/scan'), (s['odom_t'] + t0, s['odom_vx'], s['odom_wz'])
    (ss, so), (rs, ro) = one(7, sim_sets), one(8, real_sets)
    return L.analyse_lidar({'/scan': ss}, {'/scan': rs}, so, ro)


def test_sweep_distortion_found_against_a_deskewed_simulation():
    out = _sim_pair(['lidar.motion_distortion=true'], ['lidar.motion_distortion=false'])
    found = [f for f in out['findings'] if f['effect'] == 'scan_distortion']
    assert found and abs(found[0]['parameters']['sweep_time'] - 0.1) <= 0.025, out['findings']
    assert {f['effect'] for f in out['findings']} == {'scan_distortion'}, out['findings']


def test_sweep_distortion_refused_without_turning(run):
    still = (run['odom'][0], run['odom'][1], 0.0 * run['odom'][2])
    out = _analyse(run, odom=still)
    assert any(j['channel'] == '/scan.sweep' and 'turning' in j['reason']
               for j in out['not_judged'])
    assert not [f for f in out['findings'] if f['effect'] == 'scan_distortion']


def test_sweep_finding_switches_the_simulated_sweep():
    import yaml

    from robot_calib.mismatch import export
    f = {'channel': '/scan.ranges', 'effect': 'scan_distortion', 'window': None,
         'parameters': {'sweep_time': -0.094}, 'confidence': 0.9}
    written = yaml.safe_load(export.sim_params_text({'verdict': 'mismatch', 'findings': [f]}))
    assert written['sim']['lidar']['motion_distortion'] is False
    f['parameters']['sweep_time'] = -0.05  # half a sweep: neither setting; said, not written
    text = export.sim_params_text({'verdict': 'mismatch', 'findings': [f]})
    assert 'motion_distortion' not in (yaml.safe_load(text)['sim'] or {}).get('lidar', {})
    assert 'scan_distortion' in text


def _one_dropout(out: dict) -> dict:
    """Return the only dropout finding of an analysis (asserting there is one)."""
    found = [f for f in out['findings'] if f['effect'] == 'dropout_rate']
    assert len(found) == 1, out['findings']
    return found[0]


def test_grazing_dropouts_found_by_incidence():
    # the real scanner loses a quarter of the beams meeting a surface beyond 1 rad from its
    # normal (the simulator's grazing dropouts): found by incidence, not by range
    out = _sim_pair(['lidar.dropout_incidence=1.0', 'lidar.dropout_incidence_rate=0.25'])
    found = _one_dropout(out)
    par = found['parameters']
    assert 'incidence' in par and 'beyond' not in par, par
    assert abs(par['incidence'] - 1.0) <= 0.25 and abs(par['rate'] - 0.25) <= 0.0625, par
    assert found['fit']['heldout_rmse_after'] < found['fit']['heldout_rmse_before']
    assert {f['effect'] for f in out['findings']} == {'dropout_rate'}, out['findings']


def test_range_dropouts_still_found_by_range():
    found = _one_dropout(_sim_pair(['lidar.dropout_beyond=3.5',
                                    'lidar.dropout_beyond_rate=0.12']))
    par = found['parameters']
    assert 'beyond' in par and 'incidence' not in par, par
    assert abs(par['beyond'] - 3.5) <= 0.875 and abs(par['rate'] - 0.12) <= 0.03, par
    assert not found.get('alternatives'), found


def test_clean_simulated_pair_names_no_dropout():
    assert _sim_pair([])['findings'] == []


def test_incidence_dropout_reaches_the_simulator_parameters():
    import yaml

    from robot_calib.mismatch import export
    f = {'channel': '/scan.ranges', 'effect': 'dropout_rate', 'window': None,
         'parameters': {'rate': 0.2, 'incidence': 1.1}, 'confidence': 0.9}
    lid = yaml.safe_load(export.sim_params_text({'verdict': 'mismatch',
                                                 'findings': [f]}))['sim']['lidar']
    assert lid['dropout_incidence'] == pytest.approx(1.1)
    assert lid['dropout_incidence_rate'] == pytest.approx(0.2)
    assert 'dropout_beyond' not in lid
    f['parameters'] = {'rate': 0.1, 'beyond': 4.0}
    lid = yaml.safe_load(export.sim_params_text({'verdict': 'mismatch',
                                                 'findings': [f]}))['sim']['lidar']
    assert lid['dropout_beyond'] == pytest.approx(4.0) and 'dropout_incidence' not in lid


def test_chord_incidence_is_less_biased_by_range_noise():
    from robot_calib.core.scan_incidence import incidence
    # a straight wall 2 m from the scanner seen over 0-85 deg of incidence, 1 cm noise
    ang = np.radians(np.arange(0.0, 85.0, 1.0))
    true = 2.0 / np.cos(ang)
    rng = np.random.default_rng(0)
    noisy = true[None, :] + rng.normal(0.0, 0.01, (200, ang.size))
    a = np.broadcast_to(ang, noisy.shape)
    ref = incidence(true[None, :], ang[None, :])[0]
    grazing = (ref > 1.0) & (ref < 1.4)
    err1 = (incidence(noisy, a) - ref)[:, grazing]
    err5 = (incidence(noisy, a, 5, 0.03) - ref)[:, grazing]
    assert np.abs(np.mean(err5)) < 0.5 * np.abs(np.mean(err1)), (err1.mean(), err5.mean())
    assert np.std(err5) < 0.5 * np.std(err1)


def test_range_and_incidence_told_apart_or_listed_as_alternative():
    from robot_calib.mismatch.lidar_beams import _jack
    from robot_calib.mismatch.lidar_dropout import dropout_findings
    # one straight wall 2 m away: range and incidence rise together (r = 2 / cos(inc)), so
    # a loss beyond 4 m is a loss beyond 60 deg: the other model must be listed
    ang = np.radians(np.arange(0.0, 80.0, 0.5))
    rs = np.tile(2.0 / np.cos(ang), (600, 1))
    rng = np.random.default_rng(3)
    rr = np.where((rs > 4.0) & (rng.random(rs.shape) < 0.2), np.nan, rs)
    blk = np.minimum(np.arange(600) * 6 // 600, 5)
    held = (np.minimum(np.arange(600) * 12 // 600, 11) % 3) == 2
    out = dropout_findings(rs, rr, ang, blk, held, '/scan', lambda f, b: _jack(f, b, 6), [],
                           0.0)
    assert len(out) == 1 and out[0]['alternatives'], out
    par, alt = out[0]['parameters'], out[0]['alternatives'][0]['parameters']
    assert {'beyond', 'incidence'} == (set(par) | set(alt)) - {'rate'}, (par, alt)
    thr = par.get('beyond', alt.get('beyond'))
    assert abs(thr - 4.0) < 0.1 and abs(par['rate'] - 0.2) < 0.03
    # a second wall head-on at 5 m (range far, incidence 0) without losses: range is wrong
    rs2 = np.c_[rs, np.full((600, 40), 5.0)]
    rr2 = np.c_[rr, np.full((600, 40), 5.0)]
    ang2 = np.r_[ang, np.radians(np.arange(100.0, 120.0, 0.5))]
    notes = []
    out = dropout_findings(rs2, rr2, ang2, blk, held, '/scan', lambda f, b: _jack(f, b, 6),
                           notes, 0.0)
    assert len(out) == 1 and 'incidence' in out[0]['parameters'], out
    assert not out[0].get('alternatives') and notes, (out, notes)
