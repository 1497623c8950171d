# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Ideal scans: the grid ray caster against analytic walls, map files, ``ideal`` end to end."""

import json
import math

import numpy as np
import pytest

from robot_calib import cli
from robot_calib.core.raycast import (grid_from_points, grid_from_segments, OccupancyGrid,
                                      raycast)
from robot_calib.io.occupancy_map import load_map, MapError, read_pgm, write_map
from robot_calib.mismatch.ideal_scan import read_scans
from scan_helpers import box_ranges

RES = 0.05


def box_grid(width=80, height=60, x0=-1.0, y0=-2.0, yaw=0.0):
    """Return a box of one-cell walls on the grid's border (cells)."""
    occ = np.zeros((height, width), dtype=bool)
    occ[0, :] = occ[-1, :] = True
    occ[:, 0] = occ[:, -1] = True
    return OccupancyGrid(occ, RES, x0, y0, yaw)


def wall_centres(grid):
    """Return the box's wall centre lines (m): x0, y0, x1, y1."""
    h, w = grid.occupied.shape
    return (grid.origin_x + 0.5 * RES, grid.origin_y + 0.5 * RES,
            grid.origin_x + (w - 0.5) * RES, grid.origin_y + (h - 0.5) * RES)


def test_raycast_hits_the_wall_cells_centres_within_half_a_cell():
    grid = box_grid()
    rng = np.random.default_rng(0)
    ox, oy = rng.uniform(-0.8, 2.7, 200), rng.uniform(-1.8, 0.7, 200)
    ang = rng.uniform(-math.pi, math.pi, (200, 90))
    r = raycast(grid, ox[:, None], oy[:, None], ang)
    exact = box_ranges(ox[:, None], oy[:, None], ang, *wall_centres(grid))
    assert np.all(np.isfinite(r))
    err = np.abs(r - exact)
    # the cell's centre projected on the ray, within the ray's span in the cell: off by at
    # most half a cell over the cosine of the incidence (a beam grazing a wall crosses many
    # of its cells), and unbiased
    x0, y0, x1, y1 = wall_centres(grid)
    hit_x = np.isclose(np.abs(ox[:, None] + exact * np.cos(ang) - 0.5 * (x0 + x1)),
                       0.5 * (x1 - x0))
    cos_inc = np.where(hit_x, np.abs(np.cos(ang)), np.abs(np.sin(ang)))
    hy = oy[:, None] + exact * np.sin(ang)
    hx = ox[:, None] + exact * np.cos(ang)
    corner = (np.minimum(np.abs(hx - x0), np.abs(hx - x1)) < 2 * RES) & \
        (np.minimum(np.abs(hy - y0), np.abs(hy - y1)) < 2 * RES)
    assert np.all((err <= 0.5 * RES / cos_inc + 1e-9) | corner)
    assert np.max(err[(cos_inc > 0.5) & ~corner]) <= RES
    assert np.median(err) < 0.3 * RES
    assert abs(np.median(r - exact)) < 0.15 * RES
    # straight along an axis the hit is exactly the wall's centre line
    r = raycast(grid, np.array([0.5, 0.5]), np.array([0.0, 0.0]), np.array([0.0, math.pi / 2]))
    x1, y1 = wall_centres(grid)[2:]
    assert r == pytest.approx([x1 - 0.5, y1], abs=1e-9)


def test_raycast_limits_inside_and_outside():
    grid = box_grid()
    assert np.isinf(raycast(grid, 0.5, 0.0, 0.0, range_max=1.0))
    assert np.isfinite(raycast(grid, 0.5, 0.0, 0.0, range_max=5.0))
    assert raycast(grid, -0.99, 0.0, 0.0) == 0.0  # starting inside a wall cell
    assert np.isinf(raycast(grid, -5.0, 0.0, math.pi))  # outside, pointing away
    assert np.isfinite(raycast(grid, -5.0, 0.0, 0.0))  # outside, pointing at the box


def test_turned_map_origin_turns_the_rays():
    plain = box_grid(x0=0.0, y0=0.0)
    turned = box_grid(x0=1.0, y0=2.0, yaw=0.7)
    ang = np.linspace(-3.0, 3.0, 50)
    a = raycast(plain, 1.3, 0.9, ang)
    c, s = math.cos(0.7), math.sin(0.7)
    px, py = 1.0 + c * 1.3 - s * 0.9, 2.0 + s * 1.3 + c * 0.9
    b = raycast(turned, px, py, ang + 0.7)
    assert np.allclose(a, b, atol=1e-9)


def test_grid_from_points_keeps_the_mean_surface_and_refuses_strays():
    # a wall at x = 2.013 seen through many points, and one stray point
    y = np.linspace(-1.0, 1.0, 2000)
    x = np.full_like(y, 2.013)
    grid = grid_from_points(np.append(x, 1.0), np.append(y, 0.0), RES, min_hits=2)
    ang = np.linspace(-0.4, 0.4, 41)
    r = raycast(grid, 0.0, 0.0, ang)
    err = r * np.cos(ang) - 2.013
    assert np.max(np.abs(err)) < 0.4 * RES and abs(np.median(err)) < 0.1 * RES


def test_grid_from_segments_casts_onto_the_lines():
    grid = grid_from_segments(np.array([[3.0, -2.0, 3.0, 2.0], [-2.0, 1.5, 3.0, 1.5]]), RES)
    ang = np.linspace(-0.5, 0.4, 30)
    r = raycast(grid, 0.0, 0.0, ang)
    assert np.allclose(r, box_ranges(0.0, 0.0, ang, -9, -9, 3.0, 1.5), atol=0.3 * RES)


def test_map_round_trip_and_map_server_conventions(tmp_path):
    grid = box_grid()
    write_map(tmp_path / 'm.yaml', grid)
    back = load_map(tmp_path / 'm.yaml')
    assert np.array_equal(back.occupied, grid.occupied)
    assert (back.resolution, back.origin_x, back.origin_y) == (RES, -1.0, -2.0)
    # ASCII PGM, negate, thresholds: with negate 1 bright pixels are occupied
    (tmp_path / 'a.pgm').write_text('P2\n# comment\n3 2\n255\n0 128 255\n255 200 0\n')
    assert read_pgm(tmp_path / 'a.pgm')[0].tolist() == [0.0, 128.0, 255.0]
    (tmp_path / 'a.yaml').write_text('image: a.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n'
                                     'negate: 1\noccupied_thresh: 0.65\nfree_thresh: 0.2\n')
    m = load_map(tmp_path / 'a.yaml')
    assert m.occupied.tolist() == [[True, True, False], [False, False, True]]  # row 0 bottom


def test_png_map(tmp_path):
    from matplotlib import image as mpimg
    img = np.full((4, 5), 254, dtype=np.uint8)
    img[0, 1] = 0  # top row in the image: the top row of the map
    mpimg.imsave(tmp_path / 'p.png', img, cmap='gray', vmin=0, vmax=255)
    (tmp_path / 'p.yaml').write_text('image: p.png\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]'
                                     '\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.25\n')
    m = load_map(tmp_path / 'p.yaml')
    assert m.occupied.shape == (4, 5)
    assert np.argwhere(m.occupied).tolist() == [[3, 1]]


@pytest.mark.parametrize('text, image, words', [
    ('- just\n- a list\n', None, 'mapping'),
    ('resolution: 0.05\norigin: [0, 0, 0]\n', None, 'image'),
    ('image: m.pgm\nresolution: -1\norigin: [0, 0, 0]\n', None, 'resolution'),
    ('image: m.pgm\nresolution: 0.05\norigin: [0, 0]\nnegate: 7\n', None, 'negate'),
    ('image: m.pgm\nresolution: 0.05\norigin: zero\n', None, 'origin'),
    ('image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.9\n', None, 'thresh'),
    ('image: gone.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n', None, 'not found'),
    ('image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n', b'P5\n100000 100000\n255\n',
     'refused'),
    ('image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n', b'P5\n10 10\n255\n\x00\x00',
     'truncated'),
    ('image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n', b'GIF89a', 'not a PGM'),
    ('image: m.jpg\nresolution: 0.05\norigin: [0, 0, 0]\n', None, 'not found'),
    ('a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n'
     'c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n'
     'e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d]\nf: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e]\n'
     'g: [*f, *f, *f, *f, *f, *f, *f, *f, *f]\n', None, 'refused'),
])
def test_bad_maps_are_one_line_errors(tmp_path, text, image, words):
    (tmp_path / 'm.yaml').write_text(text)
    if image is not None:
        (tmp_path / 'm.pgm').write_bytes(image)
    with pytest.raises(MapError) as info:
        load_map(tmp_path / 'm.yaml')
    assert words in str(info.value)
    assert '\n' not in str(info.value)


@pytest.fixture(scope='module')
def sim_pair(tmp_path_factory):
    """Return a folder with a noiseless deskewed simulation and one with range_scale 0.02."""
    d = tmp_path_factory.mktemp('ideal_scan')
    base = ['--duration', '12', '--seed', '5', '--set', 'lidar.noise=0',
            '--set', 'lidar.motion_distortion=false']
    assert cli.main(['simulate', 'drive', '--out', str(d / 'plain'), *base]) == 0
    assert cli.main(['simulate', 'drive', '--out', str(d / 'scaled'), *base,
                     '--set', 'lidar.range_scale=0.02']) == 0
    return d


def matched(real, ideal):
    """Return the ranges of both at the shared stamps where both are finite."""
    a, b = read_scans(real), read_scans(ideal)
    assert np.allclose(a.t, b.t)
    ok = np.isfinite(a.ranges) & np.isfinite(b.ranges)
    return a.ranges[ok], b.ranges[ok], ok.mean()


def test_ideal_from_scans_matches_the_real_scans(sim_pair, capsys):
    out = sim_pair / 'ideal_self'
    assert cli.main(['ideal', str(sim_pair / 'plain'), '--out', str(out),
                     '--map-from-scans']) == 0
    text = capsys.readouterr().out
    assert 'ideal scans of 360 beams' in text and 'absorbs' in text
    real, ideal, both = matched(sim_pair / 'plain', out)
    assert both > 0.95
    assert np.median(np.abs(real - ideal)) < 0.015


def test_ideal_from_a_map_shows_the_range_scale(sim_pair, tmp_path):
    from robot_calib.sim import SCENARIOS
    from robot_calib.sim.engine import BuildContext, make_params, rng_for
    truth = json.loads((sim_pair / 'scaled.truth.json').read_text())
    params = make_params(SCENARIOS['drive'], None)
    setup = SCENARIOS['drive'].build(BuildContext(params, 12.0, 5, rng_for(5, 'scenario')))
    x0, y0, yaw0 = truth['start_pose']
    c, s = math.cos(yaw0), math.sin(yaw0)
    seg = setup.world.segments.copy()
    for k in (0, 2):  # the world in the odom frame (the start pose at the origin)
        dx, dy = seg[:, k] - x0, seg[:, k + 1] - y0
        seg[:, k], seg[:, k + 1] = c * dx + s * dy, -s * dx + c * dy
    write_map(tmp_path / 'map.yaml', grid_from_segments(seg, 0.02))
    ratio = {}
    for name in ('plain', 'scaled'):
        out = tmp_path / f'ideal_{name}'
        assert cli.main(['ideal', str(sim_pair / name), '--out', str(out), '--map',
                         str(tmp_path / 'map.yaml')]) == 0
        real, ideal, both = matched(sim_pair / name, out)
        assert both > 0.95
        ratio[name] = np.median(real / ideal)
    # the grid's cells stand a little in front of the walls (about a quarter cell)
    assert ratio['plain'] == pytest.approx(1.0, abs=0.006)
    assert ratio['scaled'] / ratio['plain'] == pytest.approx(1.02, abs=0.002)


def test_ideal_scan_errors_are_one_line(sim_pair, tmp_path, capsys):
    bag = str(sim_pair / 'plain')
    (tmp_path / 'bad.yaml').write_text('image: x.pgm\n')
    assert cli.main(['ideal', bag, '--out', str(tmp_path / 'a'), '--map',
                     str(tmp_path / 'bad.yaml')]) == 2
    assert cli.main(['ideal', bag, '--out', str(tmp_path / 'b'), '--map-from-scans',
                     '--scan-topic', '/nothing']) == 2
    assert cli.main(['ideal', bag, '--out', str(tmp_path / 'c'), '--map-from-scans', '--map',
                     str(tmp_path / 'bad.yaml')]) == 2
    err = capsys.readouterr().err
    assert 'resolution' in err and '/nothing' in err and 'not both' in err
    assert all(line.startswith('robot-calib ideal: error:') for line in err.splitlines())
