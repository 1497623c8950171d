# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Tests of the registration of many pairs at once (robot_calib.core.scan_match_many)."""

import math

import numpy as np
import pytest
from robot_calib.core import scan_match as sm
from robot_calib.core.geometry import se2_apply, se2_inverse
from robot_calib.core.scan_match_many import register_many

from test_scan_match import _corridor, _raycast, _segments_room


def _pairs(n=12, seed=0):
    """Return n (source, target, guess) of a room and a corridor, some of them failing."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        if k % 5 == 4:              # a corridor: degenerate along it (test_scan_match)
            segs = _corridor()
            out.append((_raycast(segs, (0.5, 0.0, 0.0), noise=0.005, seed=2 * k + 1),
                        _raycast(segs, (0.0, 0.0, 0.0), noise=0.005, seed=2 * k),
                        np.array([0.3, 0.0, 0.0])))
            continue
        pose = (3.0 + 0.2 * k % 1.0, 1.5, 0.1 * k)
        target = _raycast(_segments_room(), pose, noise=0.01, seed=2 * k)
        truth = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(-0.1, 0.1)])
        source = se2_apply(se2_inverse(truth), _raycast(_segments_room(), pose, noise=0.01,
                                                        seed=2 * k + 1))
        guess = truth + np.array([*rng.normal(0.0, 0.03, 2), rng.normal(0.0, 0.01)])
        out.append((source, target, guess))
    out.append((out[0][0][:5], out[0][1], out[0][2]))                 # too few points
    out.append((out[1][0], out[1][1], np.array([0.0, math.nan, 0.0])))  # bad guess
    return out


def test_many_at_once_gives_what_one_by_one_gives():
    pairs = _pairs()
    params = sm.ScanMatchParams(coarse='none')
    targets = [sm.PreparedScan(t) for _, t, _ in pairs]
    many = register_many([s for s, _, _ in pairs], targets, [g for _, _, g in pairs], params)
    assert len(many) == len(pairs)
    for (s, _, g), t, a in zip(pairs, targets, many):
        b = sm.register(s, t, g, params)
        flags = ('ok', 'converged', 'degenerate', 'reason', 'iterations', 'inliers')
        assert [getattr(a, f) for f in flags] == [getattr(b, f) for f in flags]
        np.testing.assert_allclose(a.pose, b.pose, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.min_eigenvalue, b.min_eigenvalue, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-9, atol=1e-18)
    # the set holds matches, degenerate corridors and both reasons
    assert sum(r.ok for r in many) >= 8 and any(r.degenerate and not r.reason for r in many)
    assert {r.reason for r in many} == {'', 'few_points', 'bad_initial_guess'}


def test_many_ignores_the_coarse_stage_and_takes_raw_targets():
    pairs = _pairs(4, seed=1)
    many = register_many(*zip(*pairs))                  # default: coarse none, raw targets
    for (s, t, g), a in zip(pairs, many):
        b = sm.register(s, t, g, sm.ScanMatchParams(coarse='none'))
        np.testing.assert_allclose(a.pose, b.pose, rtol=0, atol=1e-12)
        assert a.reason or np.array_equal(a.coarse_pose, np.asarray(g))


@pytest.mark.parametrize('chunk', [1, 3, 256])
def test_rematch_chunks_give_the_same_segments(monkeypatch, chunk):
    from robot_calib.methods.wheel_odometry_calibration import segmenter
    pairs = _pairs(6, seed=2)
    targets = [sm.PreparedScan(t) for _, t, _ in pairs]
    one = [segmenter.default_rematcher(s, t, g) for (s, _, g), t in zip(pairs, targets)]
    monkeypatch.setattr(segmenter, 'REMATCH_CHUNK', chunk)
    many = segmenter.default_rematch_many([s for s, _, _ in pairs], targets,
                                          [g for _, _, g in pairs])
    assert [m is None for m in many] == [m is None for m in one]
    for a, b in zip(many, one):
        if a is not None:
            np.testing.assert_allclose(a[0], b[0], rtol=0, atol=1e-12)
            assert a[1].keys() == b[1].keys()
