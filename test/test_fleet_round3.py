# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""``robot-calib fleet`` against hostile inputs and environments (issue 39, round 3)."""

import csv
import os
from pathlib import Path
import shutil
import subprocess
import sys
import time

import pytest

from robot_calib.cli import main
from robot_calib.fleet import run_fleet

REPO = Path(__file__).resolve().parents[1]
NODES = ['odometry_fusion']
SECONDS = 6.0   # bags are tiny: a fleet test runs many of them


def _bag(path: Path, seed: int, bias: float = 0.01, duration: float = SECONDS) -> Path:
    from robot_calib import sim
    path.parent.mkdir(parents=True, exist_ok=True)
    sim.simulate('drive', path, seed=seed, duration=duration,
                 overrides={'imu.gyro_bias': f'0,0,{bias}'})
    return path


@pytest.fixture(scope='module')
def bags(tmp_path_factory) -> Path:
    """Two recordings called ``day1`` in two places, with gyro biases far apart."""
    root = tmp_path_factory.mktemp('bags')
    _bag(root / 'a' / 'day1', seed=1, bias=0.01)
    _bag(root / 'b' / 'day1', seed=2, bias=0.05)
    return root


def _csv(path: Path) -> list:
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


def _cli(args: list) -> list:
    """Return the command line running ``robot-calib`` with ``args`` in a fresh interpreter."""
    return [sys.executable, '-m', 'robot_calib.cli'] + [str(a) for a in args]


def _env() -> dict:
    return {**os.environ, 'PYTHONPATH': str(REPO) + os.pathsep + os.environ.get('PYTHONPATH', '')}


# --- item 2: a done bag is identified by what it is, not by its name ---------------------------

def test_a_manifest_row_pointed_at_another_recording_is_redone(bags, tmp_path, capsys):
    """Resume after a row names another ``day1``: the old bag's path and estimates came back."""
    manifest = tmp_path / 'fleet.csv'
    out = tmp_path / 'out'
    manifest.write_text(f'robot,bag\nr1,{bags / "a" / "day1"}\n')
    args = ['fleet', str(manifest), '--out', str(out), '--nodes', 'odometry_fusion',
            '--workers', '1', '--no-progress']
    assert main(args) == 0
    first = _csv(out / 'results.csv')
    manifest.write_text(f'robot,bag\nr1,{bags / "b" / "day1"}\n')
    capsys.readouterr()
    assert main(args) == 0
    said = capsys.readouterr().out
    resumed = _csv(out / 'results.csv')
    fresh = run_fleet(manifest, tmp_path / 'fresh', nodes=NODES, workers=1, progress=False)
    [row], [new] = resumed, fresh['rows']
    assert row['bag'] == str(bags / 'b' / 'day1')
    assert float(row['odometry_fusion.gyro_bias']) == pytest.approx(
        new['odometry_fusion.gyro_bias'], rel=1e-9)
    assert row['odometry_fusion.gyro_bias'] != first[0]['odometry_fusion.gyro_bias']
    # said on the terminal and in the report
    assert 'r1/day1' in said and 'changed' in said
    assert 'changed' in (out / 'report.md').read_text()


def test_a_bag_replaced_in_place_is_redone(bags, tmp_path):
    """The same path with another recording in it (copied with its times kept) is redone."""
    src = tmp_path / 'src'
    shutil.copytree(bags / 'a' / 'day1', src / 'r1' / 'day1')
    out = tmp_path / 'out'
    first = run_fleet(src, out, nodes=NODES, workers=1, progress=False)
    shutil.rmtree(src / 'r1' / 'day1')
    shutil.copytree(bags / 'b' / 'day1', src / 'r1' / 'day1')   # copy2: mtimes of the other bag
    again = run_fleet(src, out, nodes=NODES, workers=1, progress=False)
    fresh = run_fleet(src, tmp_path / 'fresh', nodes=NODES, workers=1, progress=False)
    key = 'odometry_fusion.gyro_bias'
    assert again['rows'][0][key] == pytest.approx(fresh['rows'][0][key], rel=1e-9)
    assert abs(again['rows'][0][key] - first['rows'][0][key]) > 0.01
    assert any('r1/day1' in n and 'changed' in n for n in again['notes'])
    # unchanged: reused, not replayed again, and nothing said
    stamp = (out / 'bags' / 'r1' / 'day1' / 'summary.json').stat().st_mtime_ns
    third = run_fleet(src, out, nodes=NODES, workers=1, progress=False)
    assert (out / 'bags' / 'r1' / 'day1' / 'summary.json').stat().st_mtime_ns == stamp
    assert third['notes'] == [] and third['rows'][0][key] == again['rows'][0][key]


# --- item 7: a killed parent takes its workers with it; one run per output folder --------------

def _children(pid: int) -> list:
    found = []
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / 'stat').read_text()
        except OSError:
            continue
        fields = stat.rsplit(')', 1)[1].split()
        if int(fields[1]) == pid:
            found.append(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state not in ('Z', 'X')


@pytest.fixture(scope='module')
def slow_fleet(tmp_path_factory) -> Path:
    """Six bags, long enough that a run with two workers is still going after seconds."""
    root = tmp_path_factory.mktemp('slow')
    for robot in ('r1', 'r2'):
        for day in (1, 2, 3):
            _bag(root / robot / f'day{day}', seed=day, duration=40.0)
    return root


def _start(source: Path, out: Path, workers: int = 2) -> subprocess.Popen:
    proc = subprocess.Popen(_cli(['fleet', source, '--out', out, '--nodes', 'odometry_fusion',
                                  '--workers', workers, '--no-progress']),
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(_children(proc.pid)) < workers:
        time.sleep(0.1)
    time.sleep(1.0)   # the workers are replaying now
    assert proc.poll() is None
    return proc


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='reads /proc')
def test_workers_die_with_a_killed_parent(slow_fleet, tmp_path):
    """SIGKILL of the fleet (the OOM killer): its workers stayed alive for minutes."""
    proc = _start(slow_fleet, tmp_path / 'out')
    children = _children(proc.pid)
    assert len(children) >= 2
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(_alive(c) for c in children):
        time.sleep(0.1)
    assert not [c for c in children if _alive(c)]


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='reads /proc')
def test_one_run_at_a_time_in_an_output_folder(slow_fleet, tmp_path, capsys):
    """A second run on a live run's --out is refused; a dead run's lock is taken over."""
    out = tmp_path / 'out'
    proc = _start(slow_fleet, out)
    try:
        assert main(['fleet', str(slow_fleet), '--out', str(out), '--nodes', 'odometry_fusion',
                     '--workers', '1', '--no-progress']) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0] and str(proc.pid) in err[0], err
        assert proc.poll() is None
    finally:
        proc.kill()
        proc.wait()
    time.sleep(0.5)
    res = run_fleet(slow_fleet, out, nodes=NODES, workers=2, progress=False)
    assert res['bags'] == 6 and res['failed'] == 0
    # what the killed run left half-written is gone
    assert not [p for p in out.rglob('*') if '.partial-' in p.name or p.suffix == '.tmp']


def _hold_worker_lock(out: Path) -> subprocess.Popen:
    """Start a process that holds ``out`` as a fleet worker does (an orphan, for the test)."""
    code = ('import sys, time\n'
            'from robot_calib.fleet import worker_start\n'
            'worker_start(sys.argv[1], None)\n'
            'print("ready", flush=True)\n'
            'time.sleep(60)\n')
    proc = subprocess.Popen([sys.executable, '-c', code, str(out)], env=_env(),
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == 'ready'
    return proc


def test_a_live_orphan_worker_keeps_a_new_run_out(bags, tmp_path, capsys):
    """A worker whose parent died (where no parent-death signal exists) still owns --out."""
    src = tmp_path / 'src'
    shutil.copytree(bags / 'a' / 'day1', src / 'r1' / 'day1')
    out = tmp_path / 'out'
    assert run_fleet(src, out, nodes=NODES, workers=1, progress=False)['failed'] == 0
    orphan = _hold_worker_lock(out)
    try:
        assert main(['fleet', str(src), '--out', str(out), '--nodes', 'odometry_fusion',
                     '--workers', '1', '--no-progress', '--force']) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and 'earlier fleet run' in err[0], err
    finally:
        orphan.kill()
        orphan.wait()
    assert main(['fleet', str(src), '--out', str(out), '--nodes', 'odometry_fusion',
                 '--workers', '1', '--no-progress']) == 0


# --- item 9: a full disk ------------------------------------------------------------------------

def _can_mount_tmpfs(tmp_path: Path) -> bool:
    if shutil.which('unshare') is None:
        return False
    (tmp_path / 'probe').mkdir()
    ok = subprocess.run(['unshare', '-rm', 'sh', '-c',
                         f'mount -t tmpfs -o size=64k tmpfs {tmp_path / "probe"}'],
                        capture_output=True)
    return ok.returncode == 0


@pytest.mark.parametrize('size_kb', [64, 200, 340])
def test_a_full_disk_is_one_line_and_leaves_nothing_half_written(bags, tmp_path, size_kb):
    """ENOSPC ended in "internal error", exit 1, with ``.results.csv.tmp`` left behind."""
    if not _can_mount_tmpfs(tmp_path):
        pytest.skip('needs unshare and a tmpfs mount in a user namespace')
    src = tmp_path / 'src'
    for day in (1, 2, 3, 4):
        shutil.copytree(bags / 'a' / 'day1', src / 'r1' / f'day{day}')
    disk = tmp_path / 'disk'
    disk.mkdir()
    out = disk / 'out'
    script = (f'mount -t tmpfs -o size={size_kb}k tmpfs {disk} || exit 99\n'
              f'{sys.executable} -m robot_calib.cli fleet {src} --out {out} '
              '--nodes odometry_fusion --workers 1 --no-progress\n'
              'code=$?\n'
              f'echo "exit $code"; find {disk} -mindepth 1 | sed "s/^/file /"\n')
    run = subprocess.run(['unshare', '-rm', 'sh', '-c', script], env=_env(),
                         capture_output=True, text=True, timeout=300)
    assert 'exit 99' not in run.stdout and run.returncode != 99
    lines = run.stdout.splitlines()
    assert 'exit 2' in lines, (run.stdout, run.stderr)
    err = run.stderr.strip().splitlines()
    assert len(err) == 1 and str(out) in err[0] and 'space' in err[0], err
    files = [line[5:] for line in lines if line.startswith('file ')]
    half = [f for f in files if f.endswith('.tmp') or '.partial' in f or '.old-' in f]
    assert not half, files


# --- item 10: names that escape, folders reached twice -------------------------------------------

@pytest.mark.parametrize('robot', ['.', '..', '...'])
def test_robot_names_made_of_dots_are_refused(bags, tmp_path, capsys, robot):
    """Robot ``..`` wrote its bag's replay into OUT/<bag>, outside OUT/bags/<robot>/."""
    manifest = tmp_path / 'fleet.csv'
    manifest.write_text(f'robot,bag\n{robot},{bags / "a" / "day1"}\n')
    out = tmp_path / 'out'
    assert main(['fleet', str(manifest), '--out', str(out), '--nodes', 'odometry_fusion',
                 '--workers', '1', '--no-progress']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'robot name' in err[0], err
    assert not out.exists()


def test_a_bag_whose_output_name_escapes_is_refused(bags, tmp_path, capsys):
    """A bag file ``...mcap`` (output folder ``..``) left a ``....old-*`` folder behind."""
    src = tmp_path / 'src'
    (src / 'r1').mkdir(parents=True)
    [mcap] = [p for p in (bags / 'a' / 'day1').iterdir() if p.suffix == '.mcap']
    shutil.copy(mcap, src / 'r1' / '...mcap')
    out = tmp_path / 'out'
    assert main(['fleet', str(src), '--out', str(out), '--nodes', 'odometry_fusion',
                 '--workers', '1', '--no-progress']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and '...mcap' in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['src']


def test_symlinked_robot_folders_count_each_bag_once(bags, tmp_path, capsys):
    """``robotlink -> robot000`` and a link to the root counted the same bags three times."""
    src = tmp_path / 'src'
    shutil.copytree(bags / 'a' / 'day1', src / 'robot000' / 'day1')
    shutil.copytree(bags / 'b' / 'day1', src / 'robot000' / 'day2')
    (src / 'robotlink').symlink_to('robot000')
    (src / 'all').symlink_to(src)
    out = tmp_path / 'out'
    assert main(['fleet', str(src), '--out', str(out), '--nodes', 'odometry_fusion',
                 '--workers', '1', '--no-progress']) == 0
    said = capsys.readouterr().out
    rows = _csv(out / 'results.csv')
    assert [(r['robot'], Path(r['bag']).name) for r in rows] == [('robot000', 'day1'),
                                                                 ('robot000', 'day2')]
    assert sorted(p.name for p in (out / 'bags').iterdir()) == ['robot000']
    assert 'same bag' in said and '4' in said
    assert 'same bag' in (out / 'report.md').read_text()
    # two manifest rows naming one recording (one through a link): counted once too
    manifest = tmp_path / 'fleet.csv'
    manifest.write_text(f'robot,bag\nrobot000,{src / "robot000" / "day1"}\n'
                        f'robot000,{src / "robotlink" / "day1"}\n')
    res = run_fleet(manifest, tmp_path / 'm', nodes=NODES, workers=1, progress=False)
    assert res['bags'] == 1 and any('same bag' in n for n in res['notes'])


# --- item 16: a move is flagged from the second bag on -------------------------------------------

def _rows(values: list, stds: list) -> list:
    return [{'robot': 'a', 'date': f'2026-01-0{i + 1}', 'bag': f'b{i}', 'node': 'n',
             'status': 'ok', 'n.radius': v, 'n.radius_std': s}
            for i, (v, s) in enumerate(zip(values, stds))]


def test_a_move_at_the_second_bag_is_judged_by_both_deviations():
    """A 1 % wheel change at about 50 sigma between the first two bags was never flagged."""
    from robot_calib.fleet.results import flags
    moved = [f for f in flags(_rows([0.0500, 0.0505], [7e-6, 7e-6]), 4.0)
             if f['reason'].startswith('moved')]
    assert [f['bag'] for f in moved] == ['b1']
    assert '50.5 sigma' in moved[0]['reason'] and 'b0' not in moved[0]['reason']
    # within both deviations: z = 3e-5 / hypot(1e-5, 1e-5) = 2.1, not flagged at 4 sigma
    assert not flags(_rows([0.05, 0.05003], [1e-5, 1e-5]), 4.0)
    # judged by both: a first bag with a wide deviation takes the move in (z = 3.98)
    assert not flags(_rows([0.05, 0.0504], [1e-4, 1e-5]), 4.0)
    assert flags(_rows([0.05, 0.0504], [1e-4, 1e-5]), 3.9)


def test_a_gyro_bias_step_at_the_second_bag_is_flagged_end_to_end(bags, tmp_path):
    """Through the fleet: robot r1's bias steps at its second bag, r2's does not move."""
    src = tmp_path / 'src'
    shutil.copytree(bags / 'a' / 'day1', src / 'r1' / 'day1')
    shutil.copytree(bags / 'b' / 'day1', src / 'r1' / 'day2')
    _bag(src / 'r2' / 'day1', seed=3, bias=0.01)
    _bag(src / 'r2' / 'day2', seed=4, bias=0.01)
    out = tmp_path / 'out'
    run_fleet(src, out, nodes=NODES, workers=1, progress=False)
    moved = [f for f in _csv(out / 'flags.csv') if f['reason'].startswith('moved')]
    assert {(f['robot'], Path(f['bag']).name, f['parameter']) for f in moved} >= {
        ('r1', 'day2', 'gyro_bias')}
    assert not [f for f in moved if f['robot'] == 'r2']
