# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""``robot-calib fleet``: a small simulated fleet through the process pool, flags, resume."""

import csv
from pathlib import Path

import pytest

from robot_calib.cli import main
from robot_calib.fleet import FleetError, run_fleet

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
    return [{k: v for k, v in r.items() if k != 'runtime_s'} for r in rows]


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
    assert (out / 'report.md').read_text().count('| r1 |') >= 1
    assert (out / 'bags' / 'r1' / 'day3' / 'summary.json').is_file()

    # resumed: nothing replayed again, the same table
    stamp = (out / 'bags' / 'r1' / 'day3' / 'summary.json').stat().st_mtime_ns
    again = run_fleet(fleet, out, nodes=NODES, workers=1, progress=False)
    assert _table(again['rows']) == _table(rows)
    assert (out / 'bags' / 'r1' / 'day3' / 'summary.json').stat().st_mtime_ns == stamp

    # two worker processes, from scratch: the same rows
    two = run_fleet(fleet, tmp_path / 'two', nodes=NODES, workers=2, progress=False)
    assert _table(two['rows']) == _table(rows)


def test_manifest_names_bags_and_dates(fleet, tmp_path):
    manifest = tmp_path / 'fleet.csv'
    manifest.write_text('robot,bag,date\n'
                        f'r2,{fleet / "r2" / "bags" / "day1"},2026-11-01\n'
                        f'r2,{fleet / "r2" / "bags" / "day2"},2026-11-02\n')
    res = run_fleet(manifest, tmp_path / 'out', nodes=NODES, workers=1, progress=False)
    assert [r['date'] for r in res['rows']] == ['2026-11-01', '2026-11-02']
    assert res['flags'] == 0


def test_bad_fleet_arguments_are_one_line_errors(tmp_path, capsys):
    assert main(['fleet', str(tmp_path / 'nothing'), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'neither a folder' in err[0]
    (tmp_path / 'empty').mkdir()
    with pytest.raises(FleetError, match='no bags'):
        run_fleet(tmp_path / 'empty', tmp_path / 'o', progress=False)
    with pytest.raises(FleetError, match='workers'):
        run_fleet(tmp_path / 'empty', tmp_path / 'o', workers=0, progress=False)


def test_ray_executor_gives_the_same_rows(fleet, tmp_path):
    """A local Ray (the optional extra) runs the same jobs into the same table."""
    pytest.importorskip('ray')
    pool = run_fleet(fleet, tmp_path / 'pool', nodes=NODES, workers=1, progress=False)
    ray = run_fleet(fleet, tmp_path / 'ray', nodes=NODES, workers=2, progress=False, ray='auto')
    assert _table(ray['rows']) == _table(pool['rows'])
    assert (tmp_path / 'ray' / 'flags.csv').read_text() == \
        (tmp_path / 'pool' / 'flags.csv').read_text()
