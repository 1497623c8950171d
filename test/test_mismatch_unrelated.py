# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
``robot-calib mismatch`` of two recordings that are not the same run, and findings that must hold.

A drive compared with a vacuum's cleaning pass used to give nine findings,
among them a ``timing_drift`` at confidence 0.99 whose fit made the residual
worse. Such a pair is refused (one line, exit status 2, no output folder);
a pair of the same run with real differences is still analysed; and a finding
never claims what its own fit does not show.
"""

import json

import pytest

sim = pytest.importorskip('robot_calib.sim')
cli = pytest.importorskip('robot_calib.cli')


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """Return simulated bags: a drive, the same drive with sensor errors, a vacuum run."""
    d = tmp_path_factory.mktemp('unrelated')
    out = {}
    for name, scenario, seed, sets in (
            ('drive', 'drive', 1, []),
            ('drive_errors', 'drive', 1, ['imu.gyro_bias=[0.0,0.0,0.02]',
                                          'imu.gyro_scale=[0.0,0.0,0.03]']),
            ('vacuum', 'vacuum', 2, [])):
        args = ['simulate', scenario, '--out', str(d / name), '--seed', str(seed),
                '--duration', '60']
        for s in sets:
            args += ['--set', s]
        assert cli.main(args) == 0
        out[name] = d / name
    return out


def test_a_drive_against_a_vacuum_run_is_refused_in_one_line(bags, tmp_path, capsys):
    out = tmp_path / 'mm'
    code = cli.main(['mismatch', '--sim', str(bags['drive']), '--real', str(bags['vacuum']),
                     '--out', str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1
    assert 'does not follow the simulated one' in err and 'not recordings of the same run' in err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if 'partial' in p.name]


def test_the_same_run_with_sensor_errors_is_still_explained(bags, tmp_path):
    out = tmp_path / 'mm'
    assert cli.main(['mismatch', '--sim', str(bags['drive']), '--real',
                     str(bags['drive_errors']), '--out', str(out)]) == 0
    res = json.loads((out / 'findings.json').read_text())
    assert res['verdict'] == 'mismatch'
    assert res['time_alignment']['clock']['correspondence'] > 0.9
    named = {(f['channel'], f['effect']) for f in res['findings']}
    assert ('/imu.angular_velocity.z', 'gyro_bias') in named or \
        any(e == 'gyro_bias' for _, e in named)


def test_findings_improve_what_they_claim_even_on_unrelated_runs(bags):
    """With the refusal switched off, no finding may make its own fit worse or be degenerate."""
    from robot_calib.mismatch import analyse_recordings, MismatchParams, read_bag
    res, _ = analyse_recordings(read_bag(bags['drive']), read_bag(bags['vacuum']),
                                MismatchParams(min_correspondence=0.0))
    for f in res['findings']:
        if f['effect'] == 'unexplained':
            continue
        fit = f['fit']
        assert fit['rmse_after'] < fit['rmse_before'], f
        if fit['heldout_rmse_before'] is not None:
            assert fit['heldout_rmse_after'] < fit['heldout_rmse_before'], f
        if f['effect'] == 'timing_drift':
            p = f['parameters']
            assert p['tau_start'] != p['tau_end'], f
    demoted = [f for f in res['weak_findings'] if 'Not reported:' in f['explanation']]
    assert all(f['effect'] != 'unexplained' for f in demoted)
