# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""``robot-calib fleet``: a small simulated fleet through the process pool, flags, resume."""

import csv
from pathlib import Path

import numpy as np
import pytest

from robot_calib.cli import main
from robot_calib.fleet import FleetError, run_fleet

pytestmark = pytest.mark.slow  # over a few seconds each: left out by -m "not slow"

BIAS = {'r1': (0.01, 0.01, 0.05), 'r2': (0.01, 0.01, 0.01)}  # r1's gyro bias jumps on day 3
NODES = ['odometry_fusion']


@pytest.fixture(scope='module')
def fleet(tmp_path_factory) -> Path:
    from robot_calib import sim
    root = tmp_path_factory.mktemp('fleet') / 'robots'
    for robot, biases in BIAS.items():
        (root / robot / 'bags').mkdir(parents=True)
        for day, bias in enumerate(biases, 1):
            sim.simulate('drive', root / robot / 'bags' / f'day{day}', seed=10 * day,
                         duration=20.0, overrides={'imu.gyro_bias': f'0,0,{bias}'})
    (root / 'r3').mkdir()
    (root / 'r3' / 'broken.mcap').write_bytes(b'\x89MCAP0\r\n' + b'garbage' * 50)
    return root


def _table(rows):
    return [{k: v for k, v in r.items() if k not in ('runtime_s', 'peak_rss_mb')} for r in rows]


def test_fleet_flags_the_drift_and_records_the_broken_bag(fleet, tmp_path):
    out = tmp_path / 'out'
    res = run_fleet(fleet, out, nodes=NODES, workers=1, progress=False)
    assert res['bags'] == 7 and res['failed'] == 1
    rows = res['rows']
    ok = [r for r in rows if r['status'] == 'ok']
    assert {(r['robot'], Path(r['bag']).name) for r in ok} == {
        (robot, f'day{d}') for robot in BIAS for d in (1, 2, 3)}
    assert all(isinstance(r['odometry_fusion.gyro_bias_std'], float) for r in ok)
    failed = [r for r in rows if r['status'] == 'failed']
    assert failed[0]['robot'] == 'r3' and 'broken' in failed[0]['bag'] and failed[0]['reason']
    with open(out / 'flags.csv', newline='') as f:
        flags = list(csv.DictReader(f))
    moved = [f for f in flags if f['reason'].startswith('moved')]
    # the drifting robot's third bag, and nothing else (the filter's other terms may move too)
    assert {(f['robot'], Path(f['bag']).name) for f in moved} == {('r1', 'day3')}
    assert 'gyro_bias' in {f['parameter'] for f in moved}
    assert [f['robot'] for f in flags if f['reason'].startswith('failed')] == ['r3']
    with open(out / 'results.csv', newline='') as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(rows) and 'odometry_fusion.gyro_bias' in table[0]
    import pyarrow.parquet as pq
    assert pq.read_table(out / 'results.parquet').num_rows == len(rows)
    report = (out / 'report.md').read_text()
    assert report.count('| r1 |') >= 1
    # the drifting robot's trends are shown under the flags, every robot's are drawn
    assert '![r1](plots/robots/r1.png)' in report and '![r2]' not in report
    assert '### r3\n\nno bag processed' in report
    assert {p.name for p in (out / 'plots' / 'robots').iterdir()} == {'r1.png', 'r2.png'}
    assert (out / 'plots' / 'estimates' / 'odometry_fusion.gyro_bias.png').is_file()
    assert all(r['peak_rss_mb'] > 50 for r in rows)
    day3 = out / 'bags' / 'r1' / 'day3'
    assert (day3 / 'summary.json').is_file() and (day3 / 'report.md').is_file()
    assert not (day3 / 'plots').exists()   # per-bag plots only when asked

    # resumed: nothing replayed again, the same table
    stamp = (day3 / 'summary.json').stat().st_mtime_ns
    again = run_fleet(fleet, out, nodes=NODES, workers=1, progress=False)
    assert _table(again['rows']) == _table(rows)
    assert (day3 / 'summary.json').stat().st_mtime_ns == stamp

    # asking for the per-bag plots redoes the bags, with the same rows
    plotted = run_fleet(fleet, out, nodes=NODES, workers=1, progress=False, bag_plots=True)
    assert _table(plotted['rows']) == _table(rows)
    assert (day3 / 'summary.json').stat().st_mtime_ns != stamp
    assert list((day3 / 'plots' / 'odometry_fusion').glob('*.png'))

    # two worker processes, from scratch: the same rows
    two = run_fleet(fleet, tmp_path / 'two', nodes=NODES, workers=2, progress=False)
    assert _table(two['rows']) == _table(rows)
    # ... and the same figures, drawn by the workers
    pngs = sorted(p.relative_to(out) for p in (out / 'plots').rglob('*.png'))
    assert pngs == sorted(p.relative_to(tmp_path / 'two')
                          for p in (tmp_path / 'two' / 'plots').rglob('*.png'))
    assert all((tmp_path / 'two' / p).read_bytes() == (out / p).read_bytes() for p in pngs)


def test_report_hands_every_figure_to_the_executor(fleet, tmp_path):
    """The figures (one a robot) go to the fleet's workers, not drawn in the parent."""
    from robot_calib.fleet import report, results
    rows = run_fleet(fleet, tmp_path / 'out', nodes=NODES, workers=1, progress=False)['rows']
    handed = []

    def draw_all(calls):
        handed.extend(calls)
        return [report.draw(call) for call in calls]
    report.write_report(rows, results.flags(rows), tmp_path / 'again', 1.0, draw_all)
    drawn = sorted((tmp_path / 'again').rglob('*.png'))
    assert sorted(args[-1] for _, args in handed) == drawn
    assert {p.name for p in drawn} >= {'r1.png', 'r2.png', 'fleet_histograms.png',
                                       'odometry_fusion.gyro_bias.png'}


def _dies_on_three(item: int) -> int:
    """Return ``item``, except that item 3 kills the worker process running it."""
    import os
    if item == 3:
        os._exit(1)
    return item


def test_a_worker_that_dies_costs_its_own_call_only():
    """A killed or crashed worker breaks the pool: its call is lost, every other one is run."""
    from robot_calib.fleet import _Pool, LOST_REASON
    pool = _Pool(2)
    try:
        got = list(pool.each(_dies_on_three, range(10), lost=lambda item, why: (item, why)))
        assert sorted(g for g in got if isinstance(g, int)) == [0, 1, 2, 4, 5, 6, 7, 8, 9]
        assert [g for g in got if not isinstance(g, int)] == [(3, LOST_REASON)]
        # the pool goes on working after it
        again = pool.each(_dies_on_three, [10, 11], lost=lambda item, why: (item, why))
        assert sorted(again) == [10, 11]
    finally:
        pool.close()


def test_a_bag_lost_with_its_worker_is_a_failed_row(fleet, tmp_path):
    """The row of a bag whose worker died goes through the table, the flags and the report."""
    from robot_calib.fleet import LOST_REASON, report, results
    from robot_calib.fleet.runner import failed_rows
    from robot_calib.fleet.source import discover
    rows = run_fleet(fleet, tmp_path / 'out', nodes=NODES, workers=1, progress=False)['rows']
    job = next(j for j in discover(fleet) if j.robot == 'r2')
    rows = results.sort_rows(rows + failed_rows(job, LOST_REASON, 0.0, None))
    found = results.flags(rows)
    (tmp_path / 'again').mkdir()
    results.write_table(rows, tmp_path / 'again')
    report.write_report(rows, found, tmp_path / 'again', 1.0)
    assert {'robot': 'r2', 'reason': f'failed: {LOST_REASON}'}.items() <= \
        next(f for f in found if f['robot'] == 'r2').items()
    assert 'r2' in (tmp_path / 'again' / 'report.md').read_text()


def test_manifest_names_bags_and_dates(fleet, tmp_path):
    manifest = tmp_path / 'fleet.csv'
    manifest.write_text('robot,bag,date\n'
                        f'r2,{fleet / "r2" / "bags" / "day1"},2026-11-01\n'
                        f'r2,{fleet / "r2" / "bags" / "day2"},2026-11-02\n')
    res = run_fleet(manifest, tmp_path / 'out', nodes=NODES, workers=1, progress=False)
    assert [r['date'] for r in res['rows']] == ['2026-11-01', '2026-11-02']
    assert res['flags'] == 0
    # a misspelt column or a date bags cannot be ordered by: refused, not ignored (an audit)
    for header, date, words in (('robot,bag,parms', 'x.yaml', 'unknown column'),
                                ('robot,bag,date', '02/11/2026', 'ISO date')):
        manifest.write_text(f'{header}\nr2,{fleet / "r2" / "bags" / "day1"},{date}\n')
        with pytest.raises(FleetError, match=words):
            run_fleet(manifest, tmp_path / 'bad', nodes=NODES, workers=1, progress=False)


def test_bad_fleet_arguments_are_one_line_errors(tmp_path, capsys):
    assert main(['fleet', str(tmp_path / 'nothing'), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'neither a folder' in err[0]
    (tmp_path / 'empty').mkdir()
    with pytest.raises(FleetError, match='no bags'):
        run_fleet(tmp_path / 'empty', tmp_path / 'o', progress=False)
    with pytest.raises(FleetError, match='workers'):
        run_fleet(tmp_path / 'empty', tmp_path / 'o', workers=0, progress=False)


def test_settings_that_would_fail_every_bag_are_refused_first(fleet, tmp_path, capsys):
    """A typo in --set or --nodes gave a fleet whose every bag failed, and exit 0 (an audit)."""
    for extra, words in ((['--set', 'tilt_detection.fall_angel=1'], 'fall_angel'),
                         (['--nodes', 'tilt_detectin'], 'tilt_detectin'),
                         (['--nodes', 'tilt_detection', '--set', 'odometry_fusion.mode=seed'],
                          'not among the nodes run')):
        out = tmp_path / 'o'
        assert main(['fleet', str(fleet), '--out', str(out), '--no-progress'] + extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0]
        assert not out.exists()
    # every bag failing (here: the broken robot alone) is an error too
    only_broken = tmp_path / 'broken'
    (only_broken / 'r3').mkdir(parents=True)
    (only_broken / 'r3' / 'broken.mcap').write_bytes((fleet / 'r3' / 'broken.mcap').read_bytes())
    assert main(['fleet', str(only_broken), '--out', str(tmp_path / 'b'), '--workers', '1',
                 '--no-progress']) == 1
    assert 'every bag failed' in capsys.readouterr().err


def test_the_output_folder_is_never_a_robot_nor_someone_elses(fleet, tmp_path, capsys):
    """
    The output is skipped when it lies in the source, and a replay's folder is refused.

    --out inside the source read itself as a robot on the second run; a
    replay's folder given as --out was overwritten (an audit).
    """
    src = tmp_path / 'src'
    (src / 'r1').mkdir(parents=True)
    import shutil
    shutil.copytree(fleet / 'r1' / 'bags' / 'day1', src / 'r1' / 'day1')
    out = src / 'out'
    for _ in range(2):
        assert main(['fleet', str(src), '--out', str(out), '--nodes', 'tilt_detection',
                     '--workers', '1', '--no-progress']) == 0
        with open(out / 'results.csv', newline='') as f:
            assert {r['robot'] for r in csv.DictReader(f)} == {'r1'}
    other = tmp_path / 'replay_out'
    other.mkdir()
    (other / 'report.md').write_text('mine')
    assert main(['fleet', str(src), '--out', str(other), '--nodes', 'tilt_detection',
                 '--no-progress']) == 2
    assert 'previous fleet output' in capsys.readouterr().err
    assert (other / 'report.md').read_text() == 'mine'


def test_ray_executor_gives_the_same_rows(fleet, tmp_path):
    """A local Ray (the optional extra) runs the same jobs into the same table."""
    pytest.importorskip('ray')
    pool = run_fleet(fleet, tmp_path / 'pool', nodes=NODES, workers=1, progress=False)
    ray = run_fleet(fleet, tmp_path / 'ray', nodes=NODES, workers=2, progress=False, ray='auto')
    assert _table(ray['rows']) == _table(pool['rows'])
    assert (tmp_path / 'ray' / 'flags.csv').read_text() == \
        (tmp_path / 'pool' / 'flags.csv').read_text()
    # the report's figures, drawn as Ray tasks, are the ones drawn in-process
    pngs = sorted(p.relative_to(tmp_path / 'pool') for p in (tmp_path / 'pool').rglob('*.png'))
    assert pngs and all((tmp_path / 'ray' / p).read_bytes() == (tmp_path / 'pool' / p).read_bytes()
                        for p in pngs)


def test_trend_flags_a_steady_drift_not_noise():
    from robot_calib.fleet.results import flags, trend
    import numpy as np
    days = [0.0, 7.0, 14.0, 21.0, 28.0]
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 1e-5, 5)
    # a radius losing 0.1 % a week, measured with a 2e-5 m standard deviation
    wear = [0.05 * (1 - 0.001 * d / 7) + e for d, e in zip(days, noise)]
    slope, sigma = trend(days, wear, [2e-5] * 5)
    assert slope == pytest.approx(-0.05 * 0.001 / 7, rel=0.2) and abs(slope) > 4 * sigma
    # noise whose stated deviation is ten times too small: the scatter about the line rules
    flat = list(0.05 + 10 * noise)
    slope, sigma = trend(days, flat, [2e-6] * 5)
    assert abs(slope) < 4 * sigma
    assert trend(days[:3], wear[:3], [2e-5] * 3) is None      # too few bags for a trend

    def rows(values):
        return [{'robot': 'a', 'date': f'2026-01-{1 + int(d):02d}', 'bag': f'b{i}', 'node': 'n',
                 'status': 'ok', 'n.radius': v, 'n.radius_std': 2e-5}
                for i, (d, v) in enumerate(zip(days, values))]
    found = flags(rows(wear))
    assert [f['bag'] for f in found if f['reason'].startswith('trend')] == ['b4']
    assert not [f for f in flags(rows(list(0.05 + noise))) if f['reason'].startswith('trend')]


def test_simulated_fleet_drifts_as_its_truth_says(tmp_path):
    from robot_calib.fleet.source import discover
    from robot_calib.sim import fleet as F
    keys = ['fleet.robots=3', 'fleet.recordings=4', 'fleet.wear_fraction=0.34',
            'fleet.step_fraction=0.34', 'fleet.wear_per_week=0.01', 'odom.rate=20']
    rows = F.simulate_fleet(tmp_path / 'f', seed=5, duration=3.0, overrides=keys, workers=1,
                            progress=False)
    assert [r['bag'] for r in rows] == [r['bag'] for r in F.read_truth(tmp_path / 'f')]
    assert len(rows) == 12
    by = {}
    for r in F.read_truth(tmp_path / 'f'):
        by.setdefault(r['drift'], []).append(r)
    assert {k: len(v) for k, v in by.items()} == {'wear': 4, 'gyro_step': 4, 'unchanged': 4}
    radii = [float(r['left_radius_error']) for r in by['wear']]
    assert np.allclose(np.diff(radii), -0.01 * (1 + radii[0]), rtol=0.05)   # 1 % a week
    bias = [float(r['gyro_bias_z']) for r in by['gyro_step']]
    assert bias[3] - bias[2] == pytest.approx(0.02, abs=0.003)            # the step, last bag
    assert max(abs(b - bias[0]) for b in bias[:3]) < 0.003
    assert len({r['left_radius_error'] for r in by['unchanged']}) == 1
    jobs = discover(tmp_path / 'f')
    assert len(jobs) == 12 and {j.robot for j in jobs} == {'robot000', 'robot001', 'robot002'}
    import json
    last = by['wear'][3]
    truth = json.loads((tmp_path / 'f' / f'{last["bag"]}.truth.json').read_text())
    expected = 0.05 * (1 + float(last['left_radius_error']))
    assert truth['left_wheel_radius'] == pytest.approx(expected)
    assert truth['start_time'] > 1.7e9                      # the recording's date, not 1970
    # the same seed plans the same fleet; a bad key is a one-line error
    params, sim_keys = F.split_overrides(keys)
    assert F.plan(params, 5, sim_keys) == F.plan(params, 5, sim_keys)
    with pytest.raises(F.SimError, match='unknown --set key'):
        F.split_overrides(['fleet.robot=3'])
    assert main(['simulate', 'fleet', '--out', str(tmp_path / 'f')]) == 2    # exists


def test_simulated_fleet_is_written_in_the_storage_asked(tmp_path, capsys):
    """``simulate fleet --storage sqlite3`` wrote mcap bags all the same (an audit)."""
    from robot_calib.io import bags
    out = tmp_path / 'f'
    assert main(['simulate', 'fleet', '--out', str(out), '--duration', '2', '--storage',
                 'sqlite3', '--set', 'fleet.robots=1', '--set', 'fleet.recordings=2']) == 0, \
        capsys.readouterr().err
    folders = sorted(p for p in (out / 'robot000').iterdir() if p.is_dir())
    assert len(folders) == 2
    for folder in folders:
        assert [p.suffix for p in folder.iterdir() if p.name != 'metadata.yaml'] == ['.db3']
        with bags.BagSet([folder]) as bag:
            assert '/imu' in bag.topics()


def test_a_simulator_key_the_fleet_draws_is_refused(tmp_path, capsys):
    """``--set imu.gyro_bias`` was silently replaced by each robot's drawn bias (an audit)."""
    from robot_calib.sim import fleet as F
    out = tmp_path / 'f'
    small = ['--duration', '1', '--set', 'fleet.robots=1', '--set', 'fleet.recordings=1']
    for key, value, fleet_key in (('imu.gyro_bias', '0,0,0.01', 'fleet.gyro_bias_sigma'),
                                  ('wheels.track_width_error', '0.01',
                                   'fleet.track_width_error_sigma')):
        assert main(['simulate', 'fleet', '--out', str(out), '--set', f'{key}={value}']
                    + small) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and key in err[0] and fleet_key in err[0], err
        assert not out.exists()
    # the refused keys are exactly those the plan sets for every recording
    params, sim_keys = F.split_overrides(['fleet.robots=1', 'fleet.recordings=1'])
    [rec] = F.plan(params, 0, sim_keys)
    assert set(dict(rec.overrides)) == set(F.DRAWN)


def test_a_bag_with_a_corrupt_chunk_is_flagged_incomplete(tmp_path):
    """A corrupt mcap chunk skipped in a fleet bag left no trace in the fleet's results."""
    import shutil
    from robot_calib import sim
    from test_hostile_inputs import corrupt_chunk  # noqa: I100 - the test helper module
    src = tmp_path / 'src' / 'r1'
    src.mkdir(parents=True)
    sim.simulate('drive', src / 'day1', seed=1, duration=8.0)
    shutil.copytree(src / 'day1', src / 'day2')
    corrupt_chunk(src / 'day2')
    out = tmp_path / 'out'
    rows = run_fleet(src.parent, out, nodes=['tilt_detection'], workers=1, progress=False)['rows']
    assert {Path(r['bag']).name: r['corrupt_chunks'] for r in rows} == {'day1': 0, 'day2': 1}
    with open(out / 'results.csv', newline='') as f:
        assert [r['corrupt_chunks'] for r in csv.DictReader(f)] == ['0', '1']
    with open(out / 'flags.csv', newline='') as f:
        [flag] = list(csv.DictReader(f))
    assert Path(flag['bag']).name == 'day2' and flag['parameter'] == 'corrupt_chunks'
    assert '1 corrupt mcap chunk(s) skipped' in flag['reason']
    assert flag['reason'] in (out / 'report.md').read_text()
