# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Hostile inputs, round 3, through the command line and the bag reader.

YAML bombs and absurd nesting in every YAML a user hands us, a corrupt chunk
in an mcap whose chunks overlap in time, a full disk, ``replay X --out X``,
joint states naming a joint twice, and a set-up without a C tool chain.
"""

import errno
import io
import json
import os
from pathlib import Path
import subprocess
import sys

import pytest

from robot_calib.cli import main
from robot_calib.sim.engine import simulate

REPO = Path(__file__).resolve().parents[1]


def one_line_error(capsys, code, expect=None):
    """Assert a one-line error and exit status 2; return the line."""
    out = capsys.readouterr()
    assert code == 2, out.err
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in out.err, out.err
    assert 'internal error' not in lines[0] and 'error' in lines[0], lines[0]
    if expect is not None:
        assert expect in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope='module')
def drive(tmp_path_factory):
    """Return a 4 s simulated drive bag."""
    folder = tmp_path_factory.mktemp('drive')
    simulate('drive', folder / 'bag', seed=3, duration=4.0)
    return folder / 'bag'


# -- 1. YAML bombs and absurd nesting -------------------------------------------------------
def alias_bomb(levels=9, width=10):
    """Return a flow-style "billion laughs" of about 600 bytes: width ** levels nodes expanded."""
    items = ['&a0 [' + ', '.join(['lol'] * width) + ']']
    items += [f'&a{i} [' + ', '.join([f'*a{i - 1}'] * width) + ']' for i in range(1, levels + 1)]
    return '[' + ', '.join(items) + ']'


def run_limited(args, timeout=120.0, memory=1.5 * 2**30):
    """
    Run ``robot-calib args`` in a child limited to ``memory`` bytes of address space.

    Returns ``(exit status, stderr, seconds)``; a child that overran ``timeout``
    s counts as status None. Without the limit a bomb would take the machine.
    """
    import resource
    import time

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (int(memory), int(memory)))
    env = dict(os.environ, PYTHONPATH=f'{REPO}{os.pathsep}{os.environ.get("PYTHONPATH", "")}',
               OPENBLAS_NUM_THREADS='1', OMP_NUM_THREADS='1')
    t0 = time.monotonic()
    try:
        proc = subprocess.run([sys.executable, '-m', 'robot_calib.cli', *map(str, args)],
                              capture_output=True, text=True, timeout=timeout, env=env,
                              preexec_fn=limit)
    except subprocess.TimeoutExpired:
        return None, 'timed out', time.monotonic() - t0
    return proc.returncode, proc.stderr, time.monotonic() - t0


linux_only = pytest.mark.skipif(not sys.platform.startswith('linux'),
                                reason='the address-space limit that keeps a bomb small')


@linux_only
def test_an_alias_bomb_in_params_is_refused_at_once(drive, tmp_path):
    params = tmp_path / 'bomb.yaml'
    params.write_text('tilt_detection:\n  ros__parameters:\n    fall_angle: 0.7\n'
                      f'    clear_angle: {alias_bomb()}\n')
    assert params.stat().st_size < 1024
    code, err, seconds = run_limited(['replay', drive, '--out', tmp_path / 'out', '--nodes',
                                      'tilt_detection', '--params', params, '--no-progress'])
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and 'billion laughs' in err, err
    assert str(params) in err and not (tmp_path / 'out').exists()
    assert seconds < 60.0  # the interpreter's start-up on a shared machine; the check is ms


@linux_only
def test_an_alias_bomb_in_a_fleet_manifest_is_refused_at_once(drive, tmp_path):
    manifest = tmp_path / 'fleet.yaml'
    manifest.write_text(f'- robot: r1\n  bag: {alias_bomb()}\n')
    code, err, _ = run_limited(['fleet', manifest, '--out', tmp_path / 'out', '--workers', 1,
                                '--no-progress'])
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert 'manifest' in err and 'billion laughs' in err, err
    assert not (tmp_path / 'out').exists()


def test_params_nested_100000_deep_is_refused(drive, tmp_path, capsys):
    params = tmp_path / 'deep.yaml'
    params.write_text('tilt_detection:\n  ros__parameters:\n    fall_angle: '
                      + '[' * 100_000 + ']' * 100_000 + '\n')
    code = main(['replay', str(drive), '--out', str(tmp_path / 'out'), '--nodes',
                 'tilt_detection', '--params', str(params), '--no-progress'])
    one_line_error(capsys, code, 'nested deeper than')
    assert not (tmp_path / 'out').exists()


@linux_only
def test_a_fleet_row_params_file_with_a_bomb_is_refused(drive, tmp_path):
    (tmp_path / 'bomb.yaml').write_text(f'tilt_detection:\n  ros__parameters:\n'
                                        f'    clear_angle: {alias_bomb()}\n')
    manifest = tmp_path / 'fleet.csv'
    manifest.write_text(f'robot,bag,params\nr1,{drive},bomb.yaml\n')
    code, err, _ = run_limited(['fleet', manifest, '--out', tmp_path / 'out', '--workers', 1,
                                '--nodes', 'tilt_detection', '--no-progress'])
    results = tmp_path / 'out' / 'results.csv'
    # refused before any replay, or the bag's row failed with the reason: never a blow-up
    assert 'billion laughs' in (err + (results.read_text() if results.exists() else '')), err
    assert 'internal error' not in err and code in (1, 2), err


def test_a_bag_whose_metadata_is_a_bomb_is_refused(drive, tmp_path, capsys):
    import shutil
    bag = tmp_path / 'bag'
    shutil.copytree(drive, bag)
    meta = bag / 'metadata.yaml'
    meta.write_text(meta.read_text().rstrip('\n') + f'\n  custom_data_bomb: {alias_bomb(12)}\n')
    code = main(['replay', str(bag), '--out', str(tmp_path / 'out'), '--nodes',
                 'tilt_detection', '--no-progress'])
    one_line_error(capsys, code, 'metadata.yaml')


def test_ordinary_anchors_and_merge_keys_still_load(drive, tmp_path, capsys):
    params = tmp_path / 'anchors.yaml'
    params.write_text('tilt_detection:\n  ros__parameters:\n'
                      '    <<: &common {fall_angle: 0.7, clear_duration: 0.5}\n'
                      '    fall_min_duration: 0.05\n')
    code = main(['replay', str(drive), '--out', str(tmp_path / 'out'), '--nodes',
                 'tilt_detection', '--params', str(params), '--no-progress'])
    assert code == 0, capsys.readouterr().err
    got = json.loads((tmp_path / 'out' / 'summary.json').read_text())
    assert got['nodes']['tilt_detection']['params']['fall_angle'] == 0.7


# -- 8. a corrupt chunk in an mcap whose chunks overlap in time -----------------------------
def chunk_index(bag):
    """Return the chunk index of a one-file mcap bag folder."""
    from robot_calib.io import bags
    with bags.BagSet([bag]) as b:
        return list(b._readers[0][0].storage.storages[0].chunks)


@pytest.fixture(scope='module')
def unordered(tmp_path_factory):
    """
    Return a 30 s fusion drive rewritten with /odom after everything else (its chunks overlap).

    A recorder that buffers per topic writes such files: the messages are not in
    time order in the file, so the chunks' time spans overlap.
    """
    from robot_calib.io import bags
    folder = tmp_path_factory.mktemp('unordered')
    simulate('fusion_drive', folder / 'ordered', seed=1, duration=30.0)
    with bags.BagSet([folder / 'ordered']) as src:
        messages = list(src.messages())
    with bags.BagWriter(folder / 'bag') as out:
        for stream, time_ns, raw in sorted(messages, key=lambda m: m[0].topic == '/odom'):
            out.write_raw(stream.topic, stream.msgtype, raw, time_ns)
    chunks = chunk_index(folder / 'bag')
    assert any(b.message_start_time < a.message_end_time
               for a, b in zip(chunks, chunks[1:]))
    return folder / 'bag', messages


def test_a_corrupt_chunk_among_overlapping_chunks_is_skipped_and_listed(unordered, tmp_path,
                                                                        capsys):
    import shutil
    bag = tmp_path / 'bag'
    shutil.copytree(unordered[0], bag)
    chunk = chunk_index(bag)[1]
    mcap = next(bag.glob('*.mcap'))
    data = bytearray(mcap.read_bytes())
    data[chunk.chunk_start_offset + 49 + len(chunk.compression) + chunk.compressed_size // 10] ^= 4
    mcap.write_bytes(bytes(data))
    out = tmp_path / 'out'
    code = main(['replay', str(bag), '--out', str(out), '--nodes',
                 'odometry_fusion,tilt_detection', '--no-progress'])
    err = capsys.readouterr().err
    assert code == 0, err
    assert 'corrupt mcap chunk' in err and len(err.strip().splitlines()) == 1, err
    summary = json.loads((out / 'summary.json').read_text())
    [bad] = summary['corrupt_chunks']
    assert bad['offset'] == chunk.chunk_start_offset and bad['messages']['/imu'] > 100
    imu = summary['nodes']['tilt_detection']['inputs']['imu']
    assert imu['read'] == summary['topics']['/imu']['count'] - bad['messages']['/imu']
    # what is read is every other message, in time order (rosbags' merge: time, then chunk)
    from robot_calib.io import bags
    with bags.BagSet([bag]) as b:
        got = [(s.topic, t, bytes(raw)) for s, t, raw in b.messages()]
        [lost] = b.corrupt_chunks
    assert [m[1] for m in got] == sorted(m[1] for m in got)
    kept = [(s.topic, t, bytes(raw)) for s, t, raw in unordered[1]]
    assert set(got) <= set(kept) and len(got) == len(kept) - sum(lost['messages'].values())


# -- 11. replay X --out X -------------------------------------------------------------------
@pytest.mark.parametrize('case', ['same', 'file_inside', 'symlink', 'inside', 'contains'])
def test_replay_never_replaces_its_own_input(drive, tmp_path, capsys, case):
    first = tmp_path / 'first'
    assert main(['replay', str(drive), '--out', str(first), '--nodes', 'tilt_detection',
                 '--no-plots', '--no-progress']) == 0
    capsys.readouterr()
    before = sorted((p.name, p.stat().st_size) for p in first.iterdir())
    bag, out = first, first
    if case == 'file_inside':
        bag = first / 'output.mcap'
    elif case == 'symlink':
        (tmp_path / 'link').symlink_to(first)
        out = tmp_path / 'link'
    elif case == 'inside':
        out = first / 'plots' / 'again'
    elif case == 'contains':
        out = tmp_path
        (tmp_path / 'summary.json').write_text('{}')  # looks like an earlier output
    code = main(['replay', str(bag), '--out', str(out), '--nodes', 'tilt_detection',
                 '--no-progress'])
    one_line_error(capsys, code, 'its own input')
    assert sorted((p.name, p.stat().st_size) for p in first.iterdir()) == before


# -- 9. a full disk -------------------------------------------------------------------------
class FullDisk:
    """
    A file opened for writing on a disk that fills after ``budget`` bytes (shared by all).

    Every write past the budget raises OSError(code), as the kernel does on a
    full disk (ENOSPC), an exhausted quota (EDQUOT) or a read-only mount (EROFS).
    """

    def __init__(self, raw, state):
        """Wrap the open file ``raw``; ``state`` holds the bytes left and the error code."""
        self._raw, self._state = raw, state

    def write(self, data):
        """Write ``data`` or raise once the disk is full."""
        if len(data) > self._state['left']:
            raise OSError(self._state['code'], os.strerror(self._state['code']))
        self._state['left'] -= len(data)
        return self._raw.write(data)

    def __enter__(self):
        """Return self."""
        return self

    def __exit__(self, *exc):
        """Close the file."""
        self._raw.close()

    def __iter__(self):
        """Iterate the file's lines."""
        return iter(self._raw)

    def __getattr__(self, name):
        """Everything else as the file does."""
        return getattr(self._raw, name)


@pytest.fixture
def full_disk(monkeypatch):
    """Return ``fill(budget, code)``: from then on, writes fail once ``budget`` bytes are used."""
    import builtins
    import pathlib
    real_open, real_path_open = builtins.open, pathlib.Path.open
    state = {'left': None, 'code': errno.ENOSPC, 'only': ''}

    def wrap(f, file, mode):
        if state['left'] is None or not any(c in mode for c in 'wax+') \
                or state['only'] not in str(file):
            return f
        return FullDisk(f, state)

    def fake_open(file, mode='r', *args, **kwargs):
        return wrap(real_open(file, mode, *args, **kwargs), file, mode)

    def fake_path_open(self, mode='r', *args, **kwargs):
        return wrap(real_path_open(self, mode, *args, **kwargs), self, mode)
    monkeypatch.setattr(builtins, 'open', fake_open)
    monkeypatch.setattr(io, 'open', fake_open)
    monkeypatch.setattr(pathlib.Path, 'open', fake_path_open)

    def fill(budget, code=errno.ENOSPC, only=''):
        state.update(left=budget, code=code, only=only)
    return fill


def no_partial_files(folder):
    """Return the files and folders left in ``folder`` that a clean failure must not leave."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith('.')
                  or 'partial' in p.name or p.suffix == '.tmp')


@pytest.mark.parametrize('code', [errno.ENOSPC, errno.EDQUOT, errno.EROFS])
@pytest.mark.parametrize('budget', [200_000])
def test_replay_on_a_full_disk_is_an_environment_error(drive, tmp_path, capsys, full_disk,
                                                       code, budget):
    target = tmp_path / 'results'
    target.mkdir()
    full_disk(budget, code)
    rc = main(['replay', str(drive), '--out', str(target / 'out'), '--nodes',
               'odometry_fusion,tilt_detection', '--no-progress'])
    line = one_line_error(capsys, rc, str(target))
    assert os.strerror(code) in line
    assert not (target / 'out').exists() and no_partial_files(target) == []


@pytest.mark.parametrize('budget,only', [(100_000, ''), (10, 'truth.json')])
def test_simulate_on_a_full_disk_is_an_environment_error(tmp_path, capsys, full_disk, budget,
                                                         only):
    full_disk(budget, only=only)
    rc = main(['simulate', 'drive', '--out', str(tmp_path / 'sim'), '--duration', '3'])
    line = one_line_error(capsys, rc, str(tmp_path))
    assert 'No space left' in line
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize('budget', [100_000])
def test_ideal_on_a_full_disk_is_an_environment_error(drive, tmp_path, capsys, full_disk,
                                                      budget):
    full_disk(budget)
    rc = main(['ideal', str(drive), '--out', str(tmp_path / 'ideal'), '--truth-topic',
               '/ground_truth/odom'])
    one_line_error(capsys, rc, str(tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# -- 13. a joint named twice in one JointState ----------------------------------------------
def test_joint_states_naming_a_joint_twice_are_rejected_and_counted(tmp_path, capsys):
    import numpy as np

    from robot_calib.core import types as T
    from robot_calib.io import bags
    simulate('diff_segments', tmp_path / 'clean', seed=1, duration=12.0)
    doubled = seen = 0
    with bags.BagSet([tmp_path / 'clean']) as src, bags.BagWriter(tmp_path / 'bag') as out:
        for stream, time_ns, raw, samples in src.decoded():
            if stream.topic != '/joint_states':
                out.write_raw(stream.topic, stream.msgtype, raw, time_ns)
                continue
            for js in samples:
                seen += 1
                if len(js.names) and seen % 10 == 3:
                    # the same joint first with another value: "the first" would be wrong
                    js = T.JointStateSample(js.t, (js.names[0],) + tuple(js.names),
                                            np.r_[js.position[0] + 50.0, js.position],
                                            np.r_[js.velocity[0] * 3, js.velocity],
                                            js.stamp_ns)
                    doubled += 1
                out.write(stream.topic, js, time_ns)
    assert doubled > 20
    code = main(['replay', str(tmp_path / 'bag'), '--out', str(tmp_path / 'out'), '--nodes',
                 'wheel_odometry_calibration,odometry_fusion', '--set',
                 'odometry_fusion.wheel_source=joint_states', '--no-plots', '--no-progress'])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f'warning: {doubled} joint_states message(s) name a joint twice' in err, err
    summary = json.loads((tmp_path / 'out' / 'summary.json').read_text())
    for node in ('wheel_odometry_calibration', 'odometry_fusion'):
        inputs = summary['nodes'][node]['inputs']['joint_states']
        assert inputs['rejected_duplicate_joint'] == doubled, (node, inputs)


def test_a_live_node_counts_and_warns_of_a_joint_named_twice(ros, monkeypatch):
    import numpy as np

    from robot_calib import codec
    from robot_calib.core import types as T
    from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
    from robot_calib.nodes import base
    said = []

    class Log:
        def __init__(self, logger):
            pass

        def __call__(self, level, message, **kwargs):
            said.append((level, message))
    monkeypatch.setattr(base, 'NodeLog', Log)
    node = base.PipelineNode(FusionPipeline)
    try:
        for i in range(3):
            ns = (i + 1) * 10**8
            names = ('left_wheel_joint', 'right_wheel_joint') + (('left_wheel_joint',) * (i > 0))
            js = T.JointStateSample(ns * 1e-9, names, np.full(len(names), 0.1 * i),
                                    np.zeros(len(names)), ns)
            msgtype, raw = codec.serialize(js)
            node._on_message('joint_states', msgtype, raw)
        node._publish_health()
    finally:
        node.destroy_node()
    assert node.pipeline.counts['joint_states']['rejected_duplicate_joint'] == 2
    assert [m for level, m in said if level == 'warn' and 'name a joint twice' in m]


# -- 14. set-up without cmake or a C compiler -----------------------------------------------
def test_setup_without_build_tools_says_what_is_missing_and_goes_on(tmp_path):
    """
    tools/build_tf2_msgs.sh with cmake, make and the compilers hidden, into a scratch target.

    The target's python is a stub that fails (no tf2_msgs there, and nothing can be
    installed), so the shared environment is never touched; the script must not
    stop the set-up (exit 0) and must say in one line what is missing.
    """
    import shutil
    tools = tmp_path / 'path'
    tools.mkdir()
    for name in ('dirname', 'sha256sum', 'cut', 'cat', 'env', 'mktemp', 'rm', 'mkdir', 'tail',
                 'nproc', 'sh', 'bash'):
        found = shutil.which(name)
        if found is None:
            pytest.skip(f'{name} is not on this machine')
        (tools / name).symlink_to(found)
    venv = tmp_path / 'venv'
    (venv / 'bin').mkdir(parents=True)
    (venv / 'bin' / 'python').write_text('#!/bin/sh\nexit 1\n')
    (venv / 'bin' / 'python').chmod(0o755)
    proc = subprocess.run([str(tools / 'bash'), str(REPO / 'tools' / 'build_tf2_msgs.sh'),
                           str(venv)], capture_output=True, text=True, timeout=60,
                          env={'PATH': str(tools), 'HOME': str(tmp_path)})
    assert proc.returncode == 0, proc.stderr
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(lines) == 1, lines
    for word in ('cmake', 'cc', 'not built', '/tf', 'tools/build_tf2_msgs.sh'):
        assert word in lines[0], lines[0]
    assert sorted(p.name for p in venv.rglob('*')) == ['bin', 'python']


@pytest.fixture
def no_tf2_msgs(monkeypatch):
    """Hide tf2_msgs (as on a machine where it could not be built)."""
    monkeypatch.setitem(sys.modules, 'tf2_msgs', None)
    monkeypatch.setitem(sys.modules, 'tf2_msgs.msg', None)


def test_a_node_without_tf2_msgs_says_that_tf_needs_it(ros, no_tf2_msgs, monkeypatch):
    from rclpy.parameter import Parameter

    from robot_calib.core.params import ParamError
    from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
    from robot_calib.nodes import base
    said = []

    class Log:
        def __init__(self, logger):
            pass

        def __call__(self, level, message, **kwargs):
            said.append((level, message))
    monkeypatch.setattr(base, 'NodeLog', Log)
    node = base.PipelineNode(FusionPipeline)
    node.destroy_node()
    [warning] = [m for level, m in said if 'tf2_msgs' in m]
    assert '/tf_static' in warning and 'tools/build_tf2_msgs.sh' in warning, warning
    with pytest.raises(ParamError, match=r'cannot publish /tf: .*build_tf2_msgs.sh .*cmake'):
        base.PipelineNode(FusionPipeline, parameter_overrides=[
            Parameter('publish_tf', Parameter.Type.BOOL, True)])


def test_replay_live_without_tf2_msgs_says_that_tf_needs_it(drive, no_tf2_msgs, capsys):
    code = main(['replay', str(drive), '--live', '--rate', '50', '--duration', '0.5'])
    out = capsys.readouterr().out
    assert code == 0, out
    [line] = [ln for ln in out.splitlines() if ln.startswith('not published /tf_static')]
    assert 'tools/build_tf2_msgs.sh' in line and 'cmake' in line, line
