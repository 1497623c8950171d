# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Tests of the CARMEN log loader (synthetic files and the shared real logs)."""

import gzip
import math

import numpy as np
import pytest

from robot_calib.core.geometry import se2_between, wrap_angle
from robot_calib.io.datasets import carmen


def _flaser(n, ranges, pose, odom, t):
    vals = ' '.join(f'{r:.2f}' for r in ranges)
    return (f'FLASER {n} {vals} {pose[0]} {pose[1]} {pose[2]} {odom[0]} {odom[1]} {odom[2]} '
            f'{t} host {t - 100:.3f}\n')


def test_read_synthetic_clf(tmp_path):
    path = tmp_path / 'a.clf'
    ranges = np.full(361, 2.0)
    ranges[10] = 81.91
    with open(path, 'w') as fh:
        fh.write('# comment line\nPARAM robot_frontlaser_offset 0.0 nohost 0\n')
        fh.write('ODOM 1.0 2.0 0.5 0.3 0.1 0.0 100.0 host 0.0\n')
        fh.write(_flaser(361, ranges, (1, 2, 0.5), (1.1, 2.1, 0.6), 100.5))
        fh.write('FLASER 361 1.0 2.0 garbage\n')
        fh.write(_flaser(361, ranges, (2, 2, 0.5), (2.1, 2.1, 0.6), 101.0))
    log = carmen.read_log(path)
    assert len(log.scans) == 2 and len(log.odom) == 1
    scan = log.scans[0]
    assert scan.t == pytest.approx(100.5)
    assert scan.angle_min == pytest.approx(-math.pi / 2)
    assert scan.angle_increment == pytest.approx(math.radians(0.5))
    assert math.isinf(scan.ranges[10])
    assert scan.points().shape == (360, 2)
    np.testing.assert_allclose(log.scan_odom[1], [2.1, 2.1, 0.6])
    assert log.params['robot_frontlaser_offset'] == '0.0'
    assert log.odom[0].vx == pytest.approx(0.3) and log.odom[0].wz == pytest.approx(0.1)
    keys = [k for k, _ in log.messages()]
    assert keys == ['odom', 'scan', 'scan']


def test_odometry_from_scans_when_no_odom_lines(tmp_path):
    path = tmp_path / 'b.log.gz'
    with gzip.open(path, 'wt') as fh:
        fh.write(_flaser(180, np.ones(180), (0, 0, 0), (0, 0, 0), 10.0))
        fh.write(_flaser(180, np.ones(180), (0, 0, 0), (0.5, 0, 0.1), 11.0))
    log = carmen.read_log(path)
    assert log.scans[0].angle_increment == pytest.approx(math.pi / 180)
    odo = log.odometry()
    assert len(odo) == 2
    assert odo[1].vx == pytest.approx(0.5) and odo[1].wz == pytest.approx(0.1)


def test_not_a_log(tmp_path):
    path = tmp_path / 'c.clf'
    path.write_text('hello world\n')
    with pytest.raises(ValueError, match='no FLASER'):
        carmen.read_log(path)


def test_relations_time_offset_and_matching(tmp_path):
    path = tmp_path / 'r.relations'
    off = carmen.INTEL_RELATIONS_TIME_OFFSET
    path.write_text(f'{off + 10.0} {off + 12.0} 0.5 -0.1 0 0 0 0.2\n')
    rel = carmen.read_relations(path)
    np.testing.assert_allclose(rel[0], [10.0, 12.0, 0.5, -0.1, 0.2], atol=1e-6)
    idx = carmen.match_times(np.array([9.0, 10.004, 12.0, 13.0]), np.array([10.0, 12.0, 11.0]))
    assert list(idx) == [1, 2, -1]


def test_mit_csail(shared_data):
    log = carmen.read_log(shared_data / 'carmen' / 'mit-csail.clf')
    assert len(log.scans) == 1988
    assert log.scans[0].ranges.size == 361
    assert log.scans[0].angle_increment == pytest.approx(math.radians(0.5))
    duration = log.scans[-1].t - log.scans[0].t
    assert 420 < duration < 430
    steps = np.linalg.norm(np.diff(log.scan_odom[:, :2], axis=0), axis=1)
    assert 300 < steps.sum() < 450  # 374 m of driving per the data README


def test_intel_relations_agree_with_corrected_poses(shared_data):
    folder = shared_data / 'carmen'
    log = carmen.read_log(folder / 'intel-corrected.log.gz')
    rel = carmen.read_relations(folder / 'intel.relations')
    pairs = carmen.relation_pairs(log, rel, tolerance=0.01)
    assert len(pairs) > 50
    err = np.array([se2_between(log.scan_poses[i], log.scan_poses[j]) - d
                    for i, j, d in pairs])
    # The SLAM-corrected poses match the ground-truth relations to a few cm / deg;
    # a wrong sign convention or time offset would give errors of metres.
    assert np.median(np.hypot(err[:, 0], err[:, 1])) < 0.1
    assert np.median(np.abs(wrap_angle(err[:, 2]))) < math.radians(2.0)
