# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Replay's output writer gives the records and errors of codec.serialize + write_raw."""

from collections import defaultdict

import numpy as np
import pytest

from robot_calib import codec
from robot_calib.core import types as T
from robot_calib.io import bags
from robot_calib.replay.run import _Emitter, RunStats


class _Run:
    """The part of a NodeRun the emitter uses: declared outputs and error counts."""

    def __init__(self):
        self.outputs = {'imu': ('/out/imu', 'sensor_msgs/msg/Imu', False),
                        'odom': ('/out/odom', 'nav_msgs/msg/Odometry', False),
                        'alert': ('/out/alert', 'std_msgs/msg/Bool', True),
                        'diag': ('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray', False),
                        'tf': ('/tf', 'tf2_msgs/msg/TFMessage', False)}
        self.errors = defaultdict(int)
        self.first_errors = []

    def error(self, where, exc):
        self.errors[where] += 1
        self.first_errors.append(f'{where}: {type(exc).__name__}: {exc}')


def _outputs():
    """Return batches of (key, sample): odd stamps, odd fields, wrong and undeclared keys."""
    rng = np.random.default_rng(7)
    stamps = [(1.5, -1), (2.25, 2_250_000_001), (-1.0, 7), (3.0, 2**62), (3.0, 2**63),
              (4.0, np.int64(4_000_000_000)), (5.0, 5e9), (2.0**31, -1), (6.0, None),
              (float('nan'), -1)]
    batches = []
    for i in range(400):
        t, ns = (stamps[i % len(stamps)] if i % 3 == 0
                 else (10.0 + i * 0.01, -1 if i % 2 else 10**10 + i * 10**7))
        cov = [rng.normal(size=(3, 3)), np.full((3, 3), np.nan), None][i % 3]
        imu = T.ImuSample(t, rng.normal(size=3), rng.normal(size=3), 'imu_link',
                          None if i % 2 else rng.normal(size=4), cov, cov, cov, ns)
        odom = T.OdomSample(t, *rng.normal(size=3), 0.1, 0.0, 0.2, 'odom', 'base',
                            rng.normal(size=(3, 3)), cov, stamp_ns=ns)
        tf = T.StaticTransform('map', 'odom', rng.normal(size=3), np.array([1.0, 0, 0, 0]),
                               t=abs(t) if t == t else 0.0)
        batch = [('imu', imu), ('odom', odom)]
        if i % 5 == 0:
            batch += [('alert', T.BoolSample(t, bool(i % 2), ns)),
                      ('diag', T.DiagnosticSample(t, (T.DiagnosticStatus('n', 0, 'ok'),), ns)),
                      ('tf', [tf]), ('tf', []), ('imu', odom), ('nope', imu), ('odom', 'x')]
        batches.append(batch)
    return batches


def _reference(writer, stats, run, outs):
    """Write outputs as replay did before its fast path: codec.serialize, then write_raw."""
    for out_key, sample in outs:
        spec = run.outputs.get(out_key)
        try:
            if spec is None:
                raise KeyError(f'output {out_key!r} is not declared in outputs')
            msgtype, data = codec.serialize(sample)
            if msgtype != spec[1]:
                raise TypeError(f'output {out_key!r} is {msgtype}, declared {spec[1]}')
            writer.write_raw(spec[0], msgtype, data, codec.sample_time_ns(
                sample if not isinstance(sample, list) else sample[0]))
        except Exception as exc:  # noqa: B902 - as replay counts it
            run.error('output', exc)
            continue
        stats.out_counts[spec[0]] += 1
        if isinstance(sample, T.OdomSample):
            stats.out_traj[spec[0]].append((sample.t, sample.x, sample.y, sample.yaw))


@pytest.mark.parametrize('fast', [True, False])
def test_emitter_writes_what_serialize_and_write_raw_write(tmp_path, fast):
    batches = _outputs()
    results = []
    for how in ('reference', 'emitter'):
        stats, run = RunStats(), _Run()
        (tmp_path / how).mkdir()
        writer = bags.BagWriter(tmp_path / how / 'bag', compress=True, latched=['/out/alert'])
        writer.fast_mcap = fast
        with writer as w:
            emit = _Emitter(w, stats)
            for outs in batches:
                if how == 'reference':
                    _reference(w, stats, run, outs)
                else:
                    emit(run, outs)
            counts = (w.count, dict(w.counts))
        files = {p.name: p.read_bytes() for p in (tmp_path / how / 'bag').iterdir()}
        results.append((files, counts, dict(stats.out_counts), dict(run.errors),
                        run.first_errors, {k: list(v) for k, v in stats.out_traj.items()}))
    assert results[0] == results[1]
    assert results[0][3]['output'] > 100 and results[0][1][0] > 800
    messages = list(bags.BagSet([tmp_path / 'emitter' / 'bag']).messages())
    assert len(messages) == results[0][1][0]
