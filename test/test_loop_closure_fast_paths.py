# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The loop closure's shortcuts give the answers of the work they skip, point for point."""

import math

import numpy as np
from robot_calib.core import types as T
from robot_calib.core.frames import constant_motion, scan_points
from robot_calib.methods.loop_closure_correction import common, params as lc
from robot_calib.methods.loop_closure_correction.keyframe_map import OverlapGrid, similarities
from robot_calib.methods.loop_closure_correction.variants import make_estimator
from scipy.spatial import cKDTree


def _kdtree_within(tree, queries, gate):
    dist, _ = tree.query(queries, distance_upper_bound=gate)
    return np.isfinite(dist)


def test_overlap_grid_answers_as_the_kdtree_even_at_the_gate():
    rng = np.random.default_rng(7)
    for gate in (0.3, 0.1, 0.05):
        pts = rng.uniform(-6.0, 6.0, (400, 2))
        tree = cKDTree(pts)
        grid = OverlapGrid(pts, tree, gate)
        assert grid.occupied is not None
        # random queries, and queries just inside and just outside the gate of a scan point
        ang = rng.uniform(-math.pi, math.pi, 600)
        ring = np.column_stack((np.cos(ang), np.sin(ang)))
        base = pts[rng.integers(0, len(pts), 600)]
        queries = np.vstack((rng.uniform(-8.0, 8.0, (3000, 2)),
                             base + ring * gate * (1 - 1e-12), base + ring * gate * (1 + 1e-12),
                             base + ring * gate))
        got = grid.within(queries)
        want = _kdtree_within(tree, queries, gate)
        assert np.array_equal(got, want)
        assert 0 < got.sum() < len(got)


def test_overlap_grid_cells_are_within_the_gate_corner_to_corner():
    gate = 0.3
    pts = np.array([[0.0, 0.0], [5.0, 3.0]])
    cell = OverlapGrid(pts, cKDTree(pts), gate).cell
    eps = 1e-9
    corners = np.array([[k * cell + eps, k * cell + eps] for k in range(-3, 4)])
    grid = OverlapGrid(np.vstack((pts, corners)), cKDTree(np.vstack((pts, corners))), gate)
    far = corners + (cell - 2 * eps)                 # the opposite corner of the same cell
    assert np.array_equal(grid.within(far),
                          _kdtree_within(grid.tree, far, gate)) and grid.within(far).all()
    # beyond the gate diagonally from a lone point: not within, as the KD-tree says
    lone = np.array([[20.0, 20.0], [0.0, 0.0]])
    grid = OverlapGrid(lone, cKDTree(lone), gate)
    d = np.array([[math.sqrt(0.5), math.sqrt(0.5)]]) * gate * np.array([[1 - 1e-9], [1 + 1e-9]])
    q = lone[0] + d
    assert np.array_equal(grid.within(q), [True, False])


def test_overlap_grid_falls_back_to_the_kdtree():
    pts = np.array([[0.0, 0.0], [1e4, 0.0], [0.5, 0.5]])
    tree = cKDTree(pts)
    grid = OverlapGrid(pts, tree, 0.3)           # too many cells: the KD-tree answers alone
    assert grid.occupied is None
    queries = np.array([[0.1, 0.1], [5.0, 5.0], [1e4 + 0.2, 0.0], [0.7, 0.6]])
    assert np.array_equal(grid.within(queries), _kdtree_within(tree, queries, 0.3))
    assert OverlapGrid(np.zeros((0, 2)), None, 0.3).occupied is None


def test_similarities_of_many_keyframes_equal_each_alone():
    rng = np.random.default_rng(3)
    cur = rng.uniform(-5.0, 5.0, (300, 2))
    tree = cKDTree(cur)
    dp = lc.DetectionParams()
    kfs = [common.Keyframe(i, 0.0, np.zeros(3), (cur[::2] + rng.normal(0, 0.1, (150, 2)))
                           .astype(np.float32)[:n], 0.0, 0, (0, 0))
           for i, n in enumerate((150, 90, 130))]
    guesses = [np.array([0.05, -0.02, 0.03]), np.zeros(3), np.array([0.3, 0.2, -0.1])]
    grid = OverlapGrid(cur, tree, dp.similarity_gate)
    together = similarities(kfs, guesses, grid, dp, 0.05)
    assert together == [similarities([k], [g], grid, dp, 0.05)[0] for k, g in zip(kfs, guesses)]
    # the same as querying every point of every yaw hypothesis in the KD-tree
    offsets = np.linspace(-0.15, 0.15, dp.similarity_yaw_steps)
    for kf, g, (sim, off) in zip(kfs, guesses, together):
        pts = kf.points.astype(float)
        pts = pts[::max(1, len(pts) // 120)] if len(pts) > 120 else pts
        fracs = []
        for o in offsets:
            c, s = math.cos(g[2] + o), math.sin(g[2] + o)
            shift = np.array([[math.cos(o), -math.sin(o)], [math.sin(o), math.cos(o)]]) @ g[:2]
            q = pts @ np.array([[c, -s], [s, c]]).T + shift
            fracs.append(_kdtree_within(tree, q, dp.similarity_gate).mean())
        assert sim == max(fracs) and sim > 0.3


def _scan(t, ranges, time_increment=1e-4):
    return T.ScanSample(t, -math.pi, 2 * math.pi / len(ranges), ranges,
                        range_max=30.0, time_increment=time_increment)


def test_surely_within_only_when_every_point_is():
    rng = np.random.default_rng(5)
    sensor = (0.3, -0.1, 0.2)
    seen = {True: 0, False: 0}
    for _ in range(300):
        r = rng.uniform(0.5, rng.uniform(5.0, 25.0), 360)
        r[rng.random(360) < 0.1] = np.inf
        scan = _scan(0.0, r, rng.choice([0.0, 1e-4, -2e-4]))
        speed, rate = rng.uniform(-2.0, 2.0), rng.uniform(-1.0, 1.0)
        pts, idx = scan_points(scan, sensor, motion=constant_motion(speed, rate))
        sure = common.surely_within(scan, scan.beams()[1], sensor, speed, rate, 20.0)
        seen[sure] += 1
        if sure:
            assert np.all(np.isfinite(pts)) and np.all(np.hypot(pts[:, 0], pts[:, 1]) <= 20.0)
    assert seen[True] > 20 and seen[False] > 20
    r = np.full(360, 19.9)
    # de-skewed at 2 m/s over 0.36 s, the forward beams end 20.6 m away
    moving = _scan(0.0, r, 1e-3)
    pts, _ = scan_points(moving, None, motion=constant_motion(2.0, 0.0))
    assert np.max(np.hypot(pts[:, 0], pts[:, 1])) > 20.0
    assert not common.surely_within(moving, r, None, 2.0, 0.0, 20.0)
    assert not common.surely_within(_scan(0.0, r), r, sensor, 1.0, 0.0, 20.0)
    assert not common.surely_within(_scan(0.0, r), r, None, math.nan, 0.0, 20.0)
    assert common.surely_within(_scan(0.0, r), r, None, 0.0, 0.0, 20.0)


def test_counted_scans_give_the_counts_of_processed_ones():
    """Scans only counted (neither checked nor keyframes) count as when their points are made."""
    rng = np.random.default_rng(11)
    scans = []
    for i in range(200):
        r = rng.uniform(1.0, 12.0, 360)
        r[:: 3 + i % 5] = 25.0 if i % 3 == 0 else 8.0    # some beams beyond max_range
        if i % 4 == 0:
            r[20:] = 21.0                                 # too few beams within it
        r[: 340 if i % 7 == 0 else 10] = np.inf           # some scans with few valid beams
        scans.append(_scan(0.1 * (i + 1), r))
    fast = make_estimator(lc.LoopClosureParams())
    slow = make_estimator(lc.LoopClosureParams())
    slow._scan_needed = lambda t: True                    # every scan's points are made
    slow._process_points = lambda t, pts: fast_counts(slow, pts)

    def fast_counts(est, pts):
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= est.params.keyframes.max_range]
        key = 'scans_used' if len(pts) >= est.params.min_valid_beams \
            else 'scans_rejected_few_beams'
        est.counts[key] += 1

    fast._keyframe_due = lambda: False                    # no keyframes: only counting
    for s in scans:
        fast.update(s)
        slow.update(s)
    assert fast.scans_refused_few_beams == slow.scans_refused_few_beams > 0
    assert dict(fast.counts) == dict(slow.counts)
    assert fast.counts['scans_used'] > 0 and fast.counts['scans_rejected_few_beams'] > 0


def test_level_imu_gyro_is_the_rotated_gyro_bit_for_bit():
    est = make_estimator(lc.LoopClosureParams())
    est.set_mounting(T.StaticTransform('base_link', 'imu_link', np.zeros(3),
                                       np.array([1.0, 0.0, 0.0, 0.0])))
    eye = np.eye(3)
    rng = np.random.default_rng(2)
    values = [0.0, -0.0, 1e-300, -2.5, math.inf, -math.inf, math.nan]
    gyros = [np.array([a, b, c]) for a in values for b in values for c in values]
    gyros += list(rng.normal(0.0, 0.5, (200, 3)))
    with np.errstate(invalid='ignore'):             # inf * 0 in the rotation
        for g in gyros:
            z = est._gyro_z(T.ImuSample(0.0, g, np.zeros(3), frame_id='imu_link'))
            assert np.float64(z).tobytes() == (eye @ g)[2].tobytes()
    assert est._imu_rotation('imu_link') is not None
