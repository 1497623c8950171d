# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The improved fusion filter's unit-vector update against the general scalar update."""

import copy

import numpy as np
import pytest
from robot_calib.methods.odometry_fusion.improved import IBG, ImprovedFusion, IV
from robot_calib.methods.odometry_fusion.params import FusionParams
from test_fusion_core import drive  # noqa: I100 - the test helper module


def _scalar_update(f, h, resid, r, consider=None):
    """Apply the general scalar update of observation ``h`` to filter ``f``; (s, NIS)."""
    Ph = f.P @ h
    return f._gain_update(Ph, float(h @ Ph) + r, resid, consider)


def _filter_after_a_drive():
    """Return an improved filter that has fused 30 s of a synthetic drive (P is dense)."""
    f = ImprovedFusion(FusionParams())
    samples, _ = drive(duration=30.0, seed=2)
    for kind, s in samples:
        if kind == 'tf_static':
            f.set_mounting(s)
        else:
            f.update(s)
    return f


@pytest.mark.parametrize('i, sign, consider', [(IV, 1.0, None), (IV, 1.0, 3), (IBG, -1.0, 3),
                                               (IBG, -1.0, None)])
def test_unit_update_equals_the_scalar_update_with_a_unit_h(i, sign, consider):
    """A column of P is P h for h = +-e_i: the same state and covariance, bit for bit."""
    a = _filter_after_a_drive()
    assert np.count_nonzero(a.P) > 40
    b = copy.deepcopy(a)
    h = np.zeros(8)
    h[i] = sign
    sa = a._unit_update(i, sign, 0.03, 1e-3, consider)
    sb = _scalar_update(b, h, 0.03, 1e-3, consider)
    assert sa == sb
    assert a.x == b.x
    assert np.array_equal(a.P, b.P)
    assert a.x != _filter_after_a_drive().x  # the update moved the state


@pytest.mark.parametrize('n', [3, 6])
def test_consider_update_keeps_the_leading_states(n):
    """A consider update of n leaves the first n states as they were and corrects the rest."""
    f = _filter_after_a_drive()
    x0 = list(f.x)
    asymmetry = np.abs(f.P - f.P.T).max()  # rounding the drive's predictions left
    h = np.zeros(8)
    h[IBG], h[6], h[7] = -1.0, 0.2, 0.5
    free = _filter_after_a_drive()
    _scalar_update(free, h, 0.05, 1e-3)
    assert all(a != b for a, b in zip(free.x[:3], x0[:3]))  # without consider they move
    _scalar_update(f, h, 0.05, 1e-3, n)
    assert f.x[:n] == x0[:n]
    assert f.x[6:] != x0[6:]
    assert np.abs(f.P - f.P.T).max() <= asymmetry + 1e-15


@pytest.mark.parametrize('n', [None, 3, 6])
def test_in_place_update_equals_the_full_expanded_form(n):
    """The in-place update gives the out-of-place full form's P and x, bit for bit."""
    f = _filter_after_a_drive()
    P0, x0 = f.P.copy(), list(f.x)
    h = np.zeros(8)
    h[IBG], h[6], h[7] = -1.02, 0.3, 0.8
    Ph = P0 @ h
    s = float(h @ Ph) + 1e-3
    k = Ph / s
    if n is None:
        P_ref = P0 - np.multiply.outer(k, Ph)
    else:
        k[:n] = 0.0
        kPh = np.multiply.outer(k, Ph)
        P_ref = P0 - kPh
        P_ref -= kPh.T
        P_ref += s * np.multiply.outer(k, k)
    x_ref = [a + b for a, b in zip(x0, (k * 0.05).tolist())]
    f._gain_update(Ph, s, 0.05, n)
    assert np.array_equal(f.P, P_ref)
    assert f.x == x_ref
    assert not np.array_equal(f.P, P0)


def test_yaw_rate_update_innovation_variance_is_h_P_h():
    """The sparse h' P h of the yaw-rate update equals the dense product to rounding."""
    a = _filter_after_a_drive()
    b = copy.deepcopy(a)
    t, v, w, gz = a.t + 0.02, 0.8, 0.1, 0.12
    x = b.x
    h = np.zeros(8)
    h[IBG], h[6], h[7] = -x[6], gz - x[IBG], v
    s_dense = float(h @ b.P @ h)
    seen = {}
    scale = a.noise.scales[1]  # before the update adapts it
    a._gain_update = lambda Ph, s, resid, consider: seen.update(s=s, Ph=Ph.copy())
    a._yaw_rate_update(t, v, w, 1e-4, gz, False, True)
    r_gyro = x[6] ** 2 * a.p.gyro_noise ** 2 / (t - a._last_upd_t) * scale
    r_eff = 1e-4 * scale + r_gyro
    assert seen['s'] - r_eff == pytest.approx(s_dense, rel=1e-12)
    assert np.array_equal(seen['Ph'], b.P @ h)
