# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Obstacle grid, segment extraction and condition 1 against exact geometry."""

import math

import numpy as np
import pytest

from robot_calib.core.lines import (condition1, extract_lines, fit_line, line_from_endpoints,
                                    LineParams, ObstacleGrid, split_segments)


def _segment(p1, p2, n=40, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n)[:, None]
    pts = np.asarray(p1, float) + s * (np.asarray(p2, float) - np.asarray(p1, float))
    d = np.asarray(p2, float) - np.asarray(p1, float)
    nrm = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    return pts + rng.normal(0.0, noise, (n, 1)) * nrm if noise else pts


@pytest.mark.parametrize('deg', [0.0, 17.0, 45.0, 89.0, 90.0, 120.0, -60.0])
def test_total_least_squares_exact_in_every_direction(deg):
    a = math.radians(deg)
    pts = _segment((1.0, 2.0), (1.0 + 2.0 * math.cos(a), 2.0 + 2.0 * math.sin(a)))
    line = condition1(pts, LineParams())
    assert line is not None
    err = (line.angle - a + math.pi / 2) % math.pi - math.pi / 2
    assert abs(err) < 1e-9
    assert line.length == pytest.approx(2.0)
    assert line.variance < 1e-20
    assert -math.pi / 2 < line.angle <= math.pi / 2


def test_ordinary_least_squares_fails_on_a_vertical_wall():
    pts = _segment((0.0, 0.0), (0.0, 2.0))
    _, u_tls = fit_line(pts, 'total')
    _, u_ols = fit_line(pts, 'ordinary')
    assert abs(u_tls[1]) == pytest.approx(1.0)     # total LS: the vertical direction
    assert abs(u_ols[1]) < 0.1                     # ordinary LS (y on x): meaningless


def test_condition1_drops_short_lines():
    p = LineParams(min_length=0.6)
    assert condition1(_segment((0, 0), (0.5, 0.0), n=20), p) is None
    assert condition1(_segment((0, 0), (0.7, 0.0), n=20), p) is not None


def test_condition1_removes_farthest_cells_and_refits():
    p = LineParams(max_variance=1e-4, remove_count=2)
    pts = _segment((0, 0), (2.0, 0.0), n=40)
    pts[10] += [0.0, 0.3]   # two outliers (a chair leg next to the wall)
    pts[25] += [0.0, -0.25]
    line = condition1(pts, p)
    assert line is not None
    assert line.n_cells == 38
    assert abs(line.angle) < 1e-9
    assert line.variance < 1e-12


def test_condition1_gives_up_when_too_noisy():
    p = LineParams(max_variance=1e-4, remove_count=2, min_length=0.6, min_cells=20)
    pts = _segment((0, 0), (1.0, 0.0), n=30, noise=0.05)
    assert condition1(pts, p) is None      # 5 refits leave 20 cells, still too scattered
    p = LineParams(max_variance=1e-4, remove_count=2, min_length=0.6, min_cells=2)
    a = np.linspace(-1.0, 1.0, 40)
    arc = 0.5 * np.column_stack((np.cos(a), np.sin(a)))    # a round pillar, 0.84 m chord
    assert condition1(arc, p) is None      # refits shorten it below the preset length


def test_endpoints_are_ordered_along_the_direction():
    a = line_from_endpoints((2.0, 1.0), (0.0, 1.0))
    b = line_from_endpoints((0.0, 1.0), (2.0, 1.0))
    assert np.allclose(a.p1, b.p1) and np.allclose(a.p2, b.p2)
    assert np.allclose(a.p1, (0.0, 1.0))
    assert a.rho == pytest.approx(1.0)


def test_split_segments_separates_a_corner_and_a_gap():
    p = LineParams()
    wall_a = _segment((0.0, 0.0), (2.0, 0.0), n=41)
    wall_b = _segment((2.0, 0.0), (2.0, 1.5), n=31)[1:]
    wall_c = _segment((2.0, 2.5), (2.0, 3.5), n=21)         # after a 1 m gap (a door)
    pts = np.vstack((wall_a, wall_b, wall_c))
    segs = split_segments(pts, p)
    assert len(segs) == 3
    lines = extract_lines(pts, p)
    angles = sorted(round(math.degrees(line.angle)) for line in lines)
    assert angles == [0, 90, 90]


def test_grid_centroids_average_hits_and_keep_beam_order():
    g = ObstacleGrid(LineParams(resolution=0.1))
    pts = np.array([[0.01, 0.01], [0.03, 0.05], [0.55, 0.05], [0.05, 0.03]])
    out = g.add_points(pts, 0.0)
    assert out.shape == (2, 2)
    assert np.allclose(out[0], [0.03, 0.03])   # cell (0, 0) averages its three hits
    assert np.allclose(out[1], [0.55, 0.05])
    assert len(g) == 2


def test_grid_is_bounded_and_forgets_stale_cells():
    p = LineParams(resolution=0.05, max_cells=500, cell_lifetime=2.0)
    g = ObstacleGrid(p)
    rng = np.random.default_rng(0)
    for k in range(100):
        g.add_points(rng.uniform(-50, 50, (200, 2)), 0.1 * k)
        assert len(g) <= 500
    g.add_points(np.array([[0.0, 0.0]]), 100.0)
    assert len(g) == 1            # everything older than the lifetime is gone
    g.clear()
    assert len(g) == 0 and g.centroids().shape == (0, 2)


def _grid_reference(scans, p):
    """Per-hit reference of ObstacleGrid: running sums per cell, capped after each scan."""
    cells, out = {}, []
    for pts in scans:
        keys = [tuple(k) for k in np.floor(pts / p.resolution).astype(np.int64).tolist()]
        starts = [i for i in range(len(keys)) if i == 0 or keys[i] != keys[i - 1]]
        sums = np.add.reduceat(pts, starts, axis=0)
        ends = starts[1:] + [len(keys)]
        order = []
        for (i, j), s in zip(zip(starts, ends), sums):
            c = cells.setdefault(keys[i], [np.zeros(2), 0.0])
            c[0] = c[0] + s
            c[1] += float(j - i)
            if keys[i] not in order:
                order.append(keys[i])
        for k in order:
            if cells[k][1] > p.max_hits_per_cell:
                cells[k][0] = cells[k][0] * (p.max_hits_per_cell / cells[k][1])
                cells[k][1] = float(p.max_hits_per_cell)
        out.append(np.array([cells[k][0] / cells[k][1] for k in order]))
    return out


def test_grid_matches_a_per_hit_reference_exactly():
    # scans along a grazing wall hit a cell, its neighbour, then the cell again (repeats
    # that are not consecutive), others hit each cell once: both update paths, to the bit
    p = LineParams(resolution=0.05, max_hits_per_cell=5)
    rng = np.random.default_rng(4)
    scans = []
    for k in range(30):
        x = np.linspace(0.0, 1.0, 60)
        wall = np.column_stack((x, 0.049 + rng.normal(0.0, 0.002, x.size)))
        scans.append(wall if k % 2 else np.array([[0.01 + 0.05 * i, 0.3] for i in range(20)]))
    g = ObstacleGrid(p)
    for pts, ref in zip(scans, _grid_reference(scans, p)):
        got = g.add_points(pts, 0.0)
        assert got.shape == ref.shape
        assert np.array_equal(got, ref)


def test_extract_lines_is_condition1_of_every_segment():
    # extract_lines skips segments shorter along their cells than min_length: each of them
    # would fail condition 1 at its first fit, so the lines are exactly those of every segment
    p = LineParams()
    rng = np.random.default_rng(7)
    skipped = 0
    for k in range(40):
        pieces = []
        for _ in range(6):  # walls of 0.2 to 1.5 m in random places, some of them clutter
            a = rng.uniform(-math.pi, math.pi)
            c = rng.uniform(-4.0, 4.0, 2)
            half = 0.5 * rng.uniform(0.2, 1.5) * np.array([math.cos(a), math.sin(a)])
            n = max(int(2 * np.linalg.norm(half) / 0.05), 2)
            pieces.append(_segment(c - half, c + half, n, noise=0.003 * (k % 3), seed=k))
        pts = np.concatenate(pieces)
        want = [line for line in (condition1(s, p, 1.0) for s in split_segments(pts, p))
                if line is not None]
        got = extract_lines(pts, p, 1.0)
        key = [(ln.p1.tolist(), ln.p2.tolist(), ln.angle, ln.length, ln.variance, ln.n_cells)
               for ln in want]
        assert key == [(ln.p1.tolist(), ln.p2.tolist(), ln.angle, ln.length, ln.variance,
                        ln.n_cells) for ln in got]  # bit for bit
        skipped += sum(float(np.linalg.norm(np.diff(s, axis=0), axis=1).sum()) < p.min_length
                       for s in split_segments(pts, p))
    assert skipped > 20  # the short-segment rule was exercised
