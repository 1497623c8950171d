# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Tests of the shared 2D scan registration (kiss-icp coarse + point-to-line refinement)."""

import dataclasses
import math

import numpy as np
import pytest
from robot_calib.core import scan_match as sm
from robot_calib.core.geometry import se2_apply, se2_between, se2_inverse, wrap_angle


def _segments_room():
    """Return wall segments (K, 4) of an L-shaped room with a pillar and a shelf (m)."""
    poly = [(0, 0), (8, 0), (8, 3), (5, 3), (5, 6), (0, 6)]
    segs = [(*poly[i], *poly[(i + 1) % len(poly)]) for i in range(len(poly))]
    segs += [(2, 2, 2.6, 2), (2.6, 2, 2.6, 2.5), (2.6, 2.5, 2, 2.5), (2, 2.5, 2, 2)]
    segs += [(6.5, 0.8, 7.2, 1.5), (0.5, 4.5, 1.5, 5.2)]
    return np.array(segs, dtype=float)


def _corridor():
    """Return a long featureless corridor, 2 m wide, 60 m long (m)."""
    return np.array([(-30, -1, 30, -1), (-30, 1, 30, 1)], dtype=float)


def _raycast(segs, pose, n=361, fov=math.pi * 1.5, max_range=20.0, noise=0.0, seed=0):
    """Return the (N, 2) hit points (sensor frame, m) of rays from ``pose`` against ``segs``."""
    x, y, th = pose
    ang = th + np.linspace(-fov / 2, fov / 2, n)
    d = np.column_stack((np.cos(ang), np.sin(ang)))
    a = segs[:, :2]
    b = segs[:, 2:] - segs[:, :2]
    o = np.array([x, y])
    denom = d[:, None, 0] * b[None, :, 1] - d[:, None, 1] * b[None, :, 0]
    ao = a[None, :, :] - o[None, None, :]
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (ao[..., 0] * b[None, :, 1] - ao[..., 1] * b[None, :, 0]) / denom
        u = (ao[..., 0] * d[:, None, 1] - ao[..., 1] * d[:, None, 0]) / denom
    hit = (t > 0) & (u >= 0) & (u <= 1) & np.isfinite(t)
    t = np.where(hit, t, np.inf).min(axis=1)
    if noise > 0:
        t = t + np.random.default_rng(seed).normal(0, noise, t.size)
    ok = t < max_range
    pts_world = o + d[ok] * t[ok, None]
    return se2_apply(se2_inverse(pose), pts_world)


def _err(pose, truth):
    e = np.asarray(pose) - np.asarray(truth)
    return math.hypot(e[0], e[1]), abs(wrap_angle(e[2]))


def test_exactly_transformed_scan_is_recovered():
    target = _raycast(_segments_room(), (3.0, 1.5, 0.3))
    truth = np.array([0.25, -0.15, math.radians(7.0)])
    source = se2_apply(se2_inverse(truth), target)       # target = truth (+) source
    res = sm.register(source, target, (0.0, 0.0, 0.0))
    t_err, r_err = _err(res.pose, truth)
    assert t_err < 1e-4 and r_err < math.radians(0.01)
    assert res.converged and not res.degenerate and res.ok
    assert res.inlier_ratio > 0.99 and res.rmse < 1e-4
    assert res.covariance.shape == (3, 3) and np.all(np.isfinite(res.covariance))


def test_two_viewpoints_with_noise_and_wide_start():
    segs = _segments_room()
    pose_t = np.array([3.0, 1.2, 0.1])
    pose_s = np.array([3.4, 1.0, 0.35])
    target = _raycast(segs, pose_t, noise=0.01, seed=1)
    source = _raycast(segs, pose_s, noise=0.01, seed=2)
    truth = se2_between(pose_t, pose_s)
    rng = np.random.default_rng(3)
    worst = (0.0, 0.0)
    for _ in range(8):
        guess = truth + np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(-0.17, 0.17)])
        res = sm.register(source, target, guess)
        t_err, r_err = _err(res.pose, truth)
        worst = (max(worst[0], t_err), max(worst[1], r_err))
        assert res.ok
    assert worst[0] < 0.01 and worst[1] < math.radians(0.2)


def test_refinement_improves_on_kiss_icp_alone():
    segs = _segments_room()
    pose_t = np.array([2.5, 1.0, 0.0])
    pose_s = np.array([2.9, 1.3, 0.2])
    target = _raycast(segs, pose_t, n=721)
    source = _raycast(segs, pose_s, n=721)
    truth = se2_between(pose_t, pose_s)
    guess = truth + np.array([0.1, -0.1, 0.05])
    alone = sm.register(source, target, guess, sm.ScanMatchParams(refine=False))
    full = sm.register(source, target, guess)
    assert alone.coarse_pose is not None
    assert _err(full.pose, truth)[0] <= _err(alone.pose, truth)[0] + 1e-4
    assert _err(full.pose, truth)[0] < 0.005


def test_refinement_alone_without_kiss_icp():
    target = _raycast(_segments_room(), (3.0, 1.5, 0.3))
    truth = np.array([0.1, 0.05, 0.03])
    source = se2_apply(se2_inverse(truth), target)
    res = sm.register(source, target, (0, 0, 0), sm.ScanMatchParams(coarse='none'))
    assert _err(res.pose, truth)[0] < 1e-4
    assert res.coarse_pose is not None and np.allclose(res.coarse_pose, 0.0)


def test_corridor_is_degenerate():
    segs = _corridor()
    target = _raycast(segs, (0.0, 0.0, 0.0), noise=0.005, seed=4)
    source = _raycast(segs, (0.5, 0.0, 0.0), noise=0.005, seed=5)
    res = sm.register(source, target, (0.3, 0.0, 0.0))
    assert res.degenerate and not res.ok
    assert res.min_eigenvalue < sm.ScanMatchParams().degenerate_eigenvalue
    # A room is well conditioned by the same measure.
    room = _raycast(_segments_room(), (3.0, 1.5, 0.3))
    assert sm.register(room, room).min_eigenvalue > 0.05


def test_bad_input_is_reported_not_raised():
    target = _raycast(_segments_room(), (3.0, 1.5, 0.3))
    few = target[:5]
    res = sm.register(few, target)
    assert res.reason == 'few_points' and not res.ok
    np.testing.assert_allclose(res.pose, 0.0)
    noisy = target.copy()
    noisy[::3] = np.nan
    noisy[1::7, 0] = np.inf
    res = sm.register(noisy, target, (0.02, 0.0, 0.01))
    assert res.ok and _err(res.pose, (0, 0, 0))[0] < 1e-3
    assert res.n_source < len(target)
    res = sm.register(target, target, (math.nan, 0, 0))
    assert res.reason == 'bad_initial_guess'
    assert sm.register(np.zeros((0, 2)), target).reason == 'few_points'


def test_unrelated_scans_give_low_inlier_ratio():
    room = _raycast(_segments_room(), (3.0, 1.5, 0.3))
    other = _raycast(np.array([(-3, -3, 3, -3), (3, -3, 0, 4), (0, 4, -3, -3)], float),
                     (0.0, 0.0, 0.0))
    res = sm.register(other, room)
    assert res.inlier_ratio < 0.6


def test_prepared_target_gives_same_result():
    target = _raycast(_segments_room(), (3.0, 1.5, 0.3))
    truth = np.array([0.2, 0.1, 0.05])
    source = se2_apply(se2_inverse(truth), target)
    prepared = sm.PreparedScan(target)
    a = sm.register(source, prepared)
    b = sm.register(source, target)
    np.testing.assert_allclose(a.pose, b.pose, atol=1e-9)
    assert len(prepared) == len(target)


def test_intel_relations_slice(shared_data):
    from robot_calib.io.datasets import carmen
    folder = shared_data / 'carmen'
    log = carmen.read_log(folder / 'intel-corrected.log.gz')
    rel = carmen.read_relations(folder / 'intel.relations')
    pairs = [(i, j, d) for i, j, d in carmen.relation_pairs(log, rel) if i != j][:30]
    assert len(pairs) == 30
    rng = np.random.default_rng(0)
    errs = []
    for i, j, d in pairs:
        guess = d + np.array([*rng.uniform(-0.1, 0.1, 2), rng.uniform(-0.1, 0.1)])
        res = sm.register(log.scans[j].points(), log.scans[i].points(), guess)
        errs.append(_err(res.pose, d))
    errs = np.array(errs)
    assert np.median(errs[:, 0]) < 0.03
    assert np.median(errs[:, 1]) < math.radians(0.5)


@pytest.mark.parametrize('yaw', [-3.0, 3.0])
def test_pose_is_wrapped(yaw):
    target = _raycast(_segments_room(), (3.0, 1.5, 0.3))
    truth = np.array([0.0, 0.0, yaw])
    source = se2_apply(se2_inverse(truth), target)
    res = sm.register(source, target, truth + np.array([0.02, 0.0, 0.02]))
    assert -math.pi < res.pose[2] <= math.pi
    assert _err(res.pose, truth)[1] < 1e-4


def _plain_query(self, moved, gate):
    """Search the KD-tree as before the tracker: every point, every query."""
    _, idx = self.target.tree.query(moved, distance_upper_bound=gate)
    offset = moved - self.target.padded[idx]
    return idx, np.einsum('ij,ij->i', offset, offset), offset


def test_tracked_nearest_is_the_kd_tree_answer():
    rng = np.random.default_rng(3)
    target = sm.PreparedScan(_raycast(_segments_room(), (3.0, 1.5, 0.3), noise=0.01))
    source = target.points[::2] + rng.normal(0.0, 0.05, (len(target.points[::2]), 2))
    tracker = sm._Nearest(target, len(source))
    pose = np.zeros(3)
    searched = []
    for k in range(60):
        # large, small and zero steps; the gate shrinks, stays and grows again
        step = rng.normal(0.0, [0.05, 0.05, 0.01]) * (0.5 ** (k % 12)) * (k % 7 != 0)
        pose = pose + step
        gate = [0.8, 0.5, 0.3, 0.1, 0.1, np.nextafter(0.1, 1.0), 0.4][k % 7]
        moved = source @ sm.rot2(pose[2]).T + pose[:2]
        before = tracker.searched
        idx, sq, _ = tracker.query(moved, gate)
        searched.append(tracker.searched - before)
        dist, ref = target.tree.query(moved, distance_upper_bound=gate)
        np.testing.assert_array_equal(idx, ref)
        found = ref < len(target)
        np.testing.assert_array_equal(np.sqrt(sq[found]), dist[found])
    # the point of tracking: most queries search few points again
    assert np.median(searched) < 0.25 * len(source)


@pytest.mark.parametrize('coarse', ['kiss_icp', 'none'])
def test_tracking_leaves_the_registration_unchanged(monkeypatch, coarse):
    target = _raycast(_segments_room(), (3.0, 1.5, 0.3), noise=0.01, seed=1)
    truth = np.array([0.3, -0.1, 0.08])
    source = se2_apply(se2_inverse(truth), _raycast(_segments_room(), (3.0, 1.5, 0.3),
                                                    noise=0.01, seed=2))
    params = sm.ScanMatchParams(coarse=coarse)
    tracked = sm.register(source, target, (0.1, 0.0, 0.0), params)
    monkeypatch.setattr(sm._Nearest, 'query', _plain_query)
    plain = sm.register(source, target, (0.1, 0.0, 0.0), params)
    assert tracked.iterations == plain.iterations > 3
    for name in ('pose', 'covariance', 'hessian', 'min_eigenvalue', 'inliers', 'rmse'):
        np.testing.assert_array_equal(getattr(tracked, name), getattr(plain, name))


def _room_pairs(count, offset_m, offset_rad, seed):
    """Yield (source, prepared target, truth, guess) of scan pairs in the room, guesses off."""
    segs = _segments_room()
    rng = np.random.default_rng(seed)
    for k in range(count):
        pt = np.array([rng.uniform(1, 4), rng.uniform(0.8, 2.2), rng.uniform(-3, 3)])
        ps = pt + np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3),
                            rng.uniform(-0.3, 0.3)])
        target = _raycast(segs, pt, noise=0.01, seed=k)
        source = _raycast(segs, ps, noise=0.01, seed=k + 100)
        truth = se2_between(pt, ps)
        ang = rng.uniform(0, 2 * math.pi)
        guess = truth + np.array([offset_m * math.cos(ang), offset_m * math.sin(ang),
                                  offset_rad * rng.choice([-1, 1])])
        yield source, sm.PreparedScan(target), truth, guess


def test_wheel_first_match_refines_first_and_is_no_worse_than_kiss_icp_first():
    """Wheel calibration's matcher: refinement from the guess, kiss-icp only when it fails."""
    from robot_calib.methods.wheel_odometry_calibration.segmenter import default_matcher
    right = {'kiss_icp_first': 0, 'matcher': 0}
    wrong = {'kiss_icp_first': 0, 'matcher': 0}
    for source, target, truth, guess in _room_pairs(16, 0.5, 0.2, seed=4):
        full = sm.register(source, target, guess)
        found = default_matcher(source, target, guess)
        for name, pose in (('kiss_icp_first', full.pose if full.ok else None),
                           ('matcher', None if found is None else found[0])):
            if pose is not None:
                t_err, r_err = _err(pose, truth)
                (right if t_err < 0.03 and r_err < 0.01 else wrong)[name] += 1
    assert right['matcher'] >= right['kiss_icp_first'] >= 10, right
    assert wrong['matcher'] <= wrong['kiss_icp_first'], wrong


def test_wheel_first_match_falls_back_to_kiss_icp(monkeypatch):
    """A refinement the quality check refuses is registered again, kiss-icp first."""
    from robot_calib.methods.wheel_odometry_calibration import segmenter
    source, target, truth, guess = next(_room_pairs(1, 0.1, 0.05, seed=5))
    real = sm.register
    coarse_stages = []

    def refine_fails(src, tgt, g, params=None):
        coarse = (params or sm.ScanMatchParams()).coarse
        coarse_stages.append(coarse)
        res = real(src, tgt, g, params)
        return res if coarse != 'none' else dataclasses.replace(res, reason='refused')

    monkeypatch.setattr(sm, 'register', refine_fails)
    found = segmenter.default_matcher(source, target, guess)
    assert coarse_stages == ['none', 'kiss_icp']
    assert found is not None and _err(found[0], truth)[0] < 0.03


def test_line_normals_are_the_least_spread_eigenvectors():
    """The closed-form normals agree with a numerical eigen-decomposition, up to the sign."""
    from scipy.spatial import cKDTree
    pts = _raycast(_segments_room(), (3.0, 1.5, 0.3), noise=0.01, seed=4)
    pts = np.vstack((pts, np.random.default_rng(5).normal(size=(40, 2))))  # blobs: not lines
    tree = cKDTree(pts)
    normals, ok = sm._normals(pts, tree, 5, 0.3)
    _, idx = tree.query(pts, k=5)
    nb = pts[idx] - pts[idx].mean(axis=1, keepdims=True)
    evals, evecs = np.linalg.eigh(np.einsum('nki,nkj->nij', nb, nb) / 5)
    cross = normals[:, 0] * evecs[:, 1, 0] - normals[:, 1] * evecs[:, 0, 0]
    assert np.allclose(np.hypot(*normals.T), 1.0) and np.max(np.abs(cross)) < 1e-9
    assert np.array_equal(ok, evals[:, 0] / evals[:, 1] <= 0.3) and 0 < ok.sum() < len(pts)


def test_gauss_newton_step_is_the_damped_solve():
    """The cofactor step equals numpy's solve of the damped normal equations; None if singular."""
    rng = np.random.default_rng(7)
    for scale in (1.0, 1e-3, 1e3):
        rows = rng.normal(size=(50, 4)) * scale
        sums = rows.T @ rows
        want = -np.linalg.solve(sums[:3, :3] + 1e-9 * np.eye(3), sums[:3, 3])
        assert np.allclose(sm._gauss_newton_step(sums), want, rtol=1e-10, atol=0.0)
    flat = np.zeros((4, 4))
    flat[:3, :3] = -1e-9 * np.eye(3)                  # the damping makes it exactly singular
    assert sm._gauss_newton_step(flat) is None


@pytest.mark.parametrize('rank', [3, 2, 0])
def test_symmetric_pseudo_inverse_is_numpy_pinv(rank):
    """Full rank, rank-deficient (a corridor) and zero Hessians: numpy's pinv to rounding."""
    rng = np.random.default_rng(rank)
    jac = rng.normal(size=(40, 3))
    jac[:, rank:] = 0.0
    h = jac.T @ jac
    assert np.allclose(sm._pseudo_inverse(h), np.linalg.pinv(h), rtol=1e-10, atol=1e-14)
