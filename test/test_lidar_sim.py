# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The simulator's real-scanner lidar effects, each against its own truth; all off by default."""

import math

import numpy as np
import pytest

from robot_calib.core.scan_incidence import incidence
from robot_calib.sim import run_scenario, run_setup, Setup
from robot_calib.sim.engine import make_params
from robot_calib.sim.motion import Plan
from robot_calib.sim.world import World
from scan_helpers import box_ranges

QUIET = {'lidar.noise': 0.0, 'lidar.motion_distortion': 'false'}
"""A noiseless, deskewed scanner: the ranges are the geometry alone."""

BOX = (0.0, 0.0, 4.0, 2.5)


def run_plan(plan, overrides=None, world=None, start=(1.0, 1.2, 0.4), duration=None):
    """Simulate a plan in a world (default: a 4 x 2.5 m box) with SimParams defaults."""
    world = world if world is not None else World().add_room(4.0, 2.5)
    params = make_params(None, overrides)
    return run_setup(Setup(world=world, plan=plan, start=start), params,
                     duration if duration is not None else plan.duration)


@pytest.mark.parametrize('scenario, over, total, finite, nan', [
    ('drive', {}, 112065.22093143011, 29160, 0),
    ('bumpy_drive', {}, 131038.53431156088, 24090, 0),
    ('drive', {'lidar.dropout': 0.1, 'latency.scan': 0.03}, 100898.73158758305, 26238, 2922)])
def test_defaults_reproduce_the_scans_from_before_the_effects(scenario, over, total, finite,
                                                              nan):
    # figures recorded with the simulator before the lidar effects existed
    x = run_scenario(scenario, seed=4, duration=8.0, overrides=over).sensors['ranges']
    ok = np.isfinite(x)
    assert int(ok.sum()) == finite and int(np.isnan(x).sum()) == nan
    assert float(np.sum(x[ok])) == pytest.approx(total, rel=1e-12)


def test_effects_at_zero_change_nothing():
    zero = {'lidar.yaw_error': 0.0, 'lidar.x_error': 0.0, 'lidar.y_error': 0.0,
            'lidar.time_offset': 0.0, 'lidar.range_bias': 0.0, 'lidar.range_scale': 0.0,
            'lidar.noise_growth': 0.0, 'lidar.dropout_beyond': 0.0,
            'lidar.dropout_incidence': 0.0}
    a = run_scenario('drive', seed=2, duration=5.0).sensors['ranges']
    b = run_scenario('drive', seed=2, duration=5.0, overrides=zero).sensors['ranges']
    assert np.array_equal(a, b)


def test_range_scale_and_bias_with_truth():
    base = run_plan(Plan().stop(0.5), QUIET)
    r = run_plan(Plan().stop(0.5), dict(QUIET, **{'lidar.range_scale': 0.02}))
    ok = np.isfinite(base.sensors['ranges'])
    ratio = r.sensors['ranges'][ok] / base.sensors['ranges'][ok]
    assert np.allclose(ratio, 1.02, atol=1e-9)
    assert r.truth['lidar_effects']['range_scale']['scale'] == 0.02
    r = run_plan(Plan().stop(0.5), dict(QUIET, **{'lidar.range_bias': 0.03}))
    assert np.allclose(r.sensors['ranges'][ok] - base.sensors['ranges'][ok], 0.03, atol=1e-9)
    assert r.truth['lidar_effects']['range_bias']['bias'] == 0.03


def test_mounting_yaw_and_offset_draw_the_scan_from_the_true_mount():
    over = dict(QUIET, **{'lidar.x': 0.2, 'lidar.y': -0.1, 'lidar.yaw': 0.3,
                          'lidar.yaw_error': 0.05, 'lidar.x_error': 0.04,
                          'lidar.y_error': -0.03})
    r = run_plan(Plan().stop(0.5), over)
    scan = r.topic('/scan')[0]
    yaw, lx, ly = 0.4, 0.24, -0.13
    ox = 1.0 + lx * math.cos(yaw) - ly * math.sin(yaw)
    oy = 1.2 + lx * math.sin(yaw) + ly * math.cos(yaw)
    expected = box_ranges(ox, oy, yaw + 0.35 + scan.angles(), *BOX)
    assert np.max(np.abs(scan.ranges - expected)) < 1e-4
    tf = {t.child: t for t in r.topic('/tf_static')[0]}['laser']
    assert tf.translation[:2] == pytest.approx([0.2, -0.1])  # the nominal mounting
    eff = r.truth['lidar_effects']
    assert eff['lidar_mounting_yaw']['yaw'] == 0.05
    assert eff['lidar_mounting_offset']['x'] == 0.04
    assert eff['lidar_mounting_offset']['y'] == -0.03
    assert r.truth['lidar_yaw'] == pytest.approx(0.35)
    assert r.truth['lidar_x'] == pytest.approx(0.24)


def test_time_offset_of_one_period_shifts_the_scans_by_one():
    plan = Plan().turn(math.pi / 2, 4.0)  # a steady turn in place
    base = run_plan(plan, QUIET, duration=2.0)
    r = run_plan(plan, dict(QUIET, **{'lidar.time_offset': 0.1}), duration=2.0)
    a, b = base.sensors['ranges'], r.sensors['ranges']
    assert np.max(np.abs(a[1:-1] - a[2:])) > 0.01  # the scene does change between scans
    assert np.max(np.abs(b[2:] - a[1:-1])) < 1e-6
    assert r.truth['lidar_effects']['lidar_time_offset']['tau'] == pytest.approx(0.1)
    r = run_plan(plan, dict(QUIET, **{'lidar.time_offset': 0.05, 'latency.scan': 0.05}),
                 duration=2.0)
    assert np.max(np.abs(r.sensors['ranges'][2:] - a[1:-1])) < 1e-6
    assert r.truth['lidar_effects']['lidar_time_offset']['tau'] == pytest.approx(0.1)


def test_sweep_distortion_and_its_truth():
    plan = Plan().turn(math.pi / 2, 4.0)
    skew = run_plan(plan, {'lidar.noise': 0.0}, duration=2.0)
    flat = run_plan(plan, QUIET, duration=2.0)
    a, b = skew.sensors['ranges'][5], flat.sensors['ranges'][5]
    assert abs(a[0] - b[0]) < 1e-6  # beam 0 is taken at the stamp in both
    assert np.max(np.abs(a - b)) > 0.01  # later beams see the pose of their own time
    assert skew.truth['lidar_effects']['scan_distortion'] == {'sweep_time': 0.1,
                                                              'deskewed': False}
    assert flat.truth['lidar_effects']['scan_distortion'] == {'sweep_time': 0.0,
                                                              'deskewed': True}


def test_noise_grows_with_range():
    world = World().add_room(12.0, 3.0)
    over = {'lidar.motion_distortion': 'false', 'lidar.noise': 0.005,
            'lidar.noise_growth': 0.01, 'lidar.x': 0.0}
    r = run_plan(Plan().stop(10.0), over, world, start=(1.0, 1.5, 0.0))
    exact = box_ranges(1.0, 1.5, r.topic('/scan')[0].angles(), 0.0, 0.0, 12.0, 3.0)
    err = r.sensors['ranges'] - exact[None, :]
    near, far = exact < 2.0, exact > 8.0
    sd_near = np.std(err[:, near])
    sd_far = np.std(err[:, far])
    mean_near, mean_far = np.mean(0.005 + 0.01 * exact[near]), np.mean(0.005 + 0.01 * exact[far])
    assert sd_near == pytest.approx(mean_near, rel=0.15)
    assert sd_far == pytest.approx(mean_far, rel=0.15)
    assert r.truth['lidar_effects']['range_noise_growth'] == {'s0': 0.005, 's1': 0.01}


def test_dropouts_beyond_a_range():
    world = World().add_room(12.0, 3.0)
    over = dict(QUIET, **{'lidar.dropout_beyond': 6.0, 'lidar.dropout_beyond_rate': 0.3,
                          'lidar.x': 0.0})
    r = run_plan(Plan().stop(5.0), over, world, start=(1.0, 1.5, 0.0))
    exact = box_ranges(1.0, 1.5, r.topic('/scan')[0].angles(), 0.0, 0.0, 12.0, 3.0)
    lost = ~np.isfinite(r.sensors['ranges'])
    assert not lost[:, exact < 5.9].any()
    assert lost[:, exact > 6.1].mean() == pytest.approx(0.3, abs=0.05)
    assert np.all(np.isposinf(r.sensors['ranges'][lost]))  # a lost return is "no return"
    eff = r.truth['lidar_effects']['dropout_rate']
    assert eff['beyond'] == 6.0 and eff['beyond_rate'] == 0.3


def test_incidence_of_beams_in_a_box_is_the_angle_to_the_wall_normal():
    ang = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    r = box_ranges(2.0, 1.25, ang, *BOX)
    inc = incidence(r[None, :], ang[None, :])[0]
    x = 2.0 + r * np.cos(ang)
    on_right = (np.abs(x - 4.0) < 1e-9)
    corner = np.abs(np.diff(r, prepend=r[-1])) > 0.05
    sel = on_right & ~corner & ~np.roll(corner, -1)
    assert np.allclose(inc[sel], np.abs(ang[sel]), atol=1e-6)


def test_dropouts_at_grazing_incidence():
    over = dict(QUIET, **{'lidar.dropout_incidence': 1.2, 'lidar.x': 0.0})
    r = run_plan(Plan().stop(0.5), over, World().add_room(12.0, 2.5), start=(2.0, 1.25, 0.0))
    ang = r.topic('/scan')[0].angles()
    exact = box_ranges(2.0, 1.25, ang, 0.0, 0.0, 12.0, 2.5)
    inc = incidence(exact[None, :], ang[None, :])[0]
    lost = ~np.isfinite(r.sensors['ranges'][0])
    assert lost[inc > 1.25].all() and not lost[inc < 1.15].any()
    assert lost.sum() > 20
    assert r.truth['lidar_effects']['dropout_rate']['incidence'] == 1.2


def test_an_effect_leaves_the_noise_and_the_other_sensors_alone():
    a = run_scenario('drive', seed=6, duration=4.0)
    b = run_scenario('drive', seed=6, duration=4.0,
                     overrides={'lidar.range_bias': 0.03, 'lidar.dropout_beyond': 5.0,
                                'lidar.dropout_beyond_rate': 0.5})
    ok = np.isfinite(a.sensors['ranges']) & np.isfinite(b.sensors['ranges'])
    assert ok.mean() > 0.5
    assert np.allclose(b.sensors['ranges'][ok] - 0.03, a.sensors['ranges'][ok], atol=1e-12)
    for key in ('gyro', 'accel', 'odom_x', 'js_pos', 'gt_x'):
        assert np.array_equal(a.sensors[key], b.sensors[key])
