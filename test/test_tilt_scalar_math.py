# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The improved tilt filter's scalar fast paths against their plain (list / numpy) forms."""

import copy
import math

import numpy as np
import pytest

from robot_calib.methods.tilt_detection.improved import AttitudeEstimator
from robot_calib.methods.tilt_detection.lowpass import LowPass, LowPass3
from robot_calib.methods.tilt_detection.params import ImprovedFilterParams


def test_lowpass3_equals_the_general_bank_to_the_bit():
    """LowPass3 (scalar state) gives what LowPass(3) gives: start, steady, new period, fill."""
    rng = np.random.default_rng(3)
    a, b = LowPass(3, 0.5, 0.005), LowPass3(3, 0.5, 0.005)
    xs = rng.normal(size=(400, 3)).tolist()
    for i, x in enumerate(xs):
        if i == 50:
            a.set_ts(0.01)
            b.set_ts(0.01)
        if i == 300:
            a.fill([1.0, -2.0, 3.0])
            b.fill([1.0, -2.0, 3.0])
        assert list(b.step(*x)) == a(x)
    assert a.ready and b.ready
    with pytest.raises(ValueError):
        LowPass3(2, 0.5, 0.005)


def test_lowpass_bank_is_direct_form_one():
    """LowPass(9) after its start is y = b0 x + b1 x1 + b2 x2 - a1 y1 - a2 y2, to the bit."""
    rng = np.random.default_rng(6)
    f = LowPass(9, 0.05, 0.005)
    xs = rng.normal(size=(100, 9)).tolist()
    for x in xs[:10]:
        f(x)
    assert f.ready
    b0, b1, b2, a1, a2 = f.coef
    x1, x2, y1, y2 = list(f.x1), list(f.x2), list(f.y1), list(f.y2)
    for x in xs[10:]:
        y = [b0 * x[i] + b1 * x1[i] + b2 * x2[i] - a1 * y1[i] - a2 * y2[i] for i in range(9)]
        out = f(x)
        assert out == y
        out[0] = 1e9  # the caller's list is its own
        x1, x2, y1, y2 = list(x), x1, y, y1


def _reference_update(f, ex, ey, dt, g):
    """Apply the bias/scale Kalman update as numpy matrices with an LU solve (the former code)."""
    p = f.p
    deg = math.pi / 180.0
    b, sc = f.bias, f.scale
    w, x, y, z = f.quat
    R = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
         2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
         2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
    RD = [R[i] * g[i % 3] for i in range(9)]
    eb = [b[i] + sc[i] * g[i] for i in range(3)]
    rb = [sum(R[3 * r + i] * eb[i] for i in range(3)) for r in range(2)]
    Rf, RDf, rbf = f.r_lp(R), f.rd_lp(RD), f.rb_lp(rb)
    P = np.array(f.P6)
    v = (0.1 * deg) ** 2 * dt / p.bias_forgetting_time
    vs = p.scale_sigma_init ** 2 * dt / (10.0 * p.bias_forgetting_time)
    if P[0, 0] < (p.bias_sigma_init * deg) ** 2:
        P[:3, :3] += np.eye(3) * v
    if P[3, 3] < p.scale_sigma_init ** 2:
        P[3:, 3:] += np.eye(3) * vs
    xs = np.array(b + sc)
    if f.rest:
        H = np.hstack((np.eye(3), np.zeros((3, 3))))
        e = np.array(f.rest_gyr) - xs[:3]
        s2 = (p.bias_sigma_rest * deg) ** 2
        W = np.eye(3) * (s2 * s2 / v + s2)
    else:
        H = np.hstack((np.array(Rf).reshape(3, 3), np.array(RDf).reshape(3, 3)))
        hx = H @ xs
        e = np.array([-ey / dt + rbf[0] - hx[0], ex / dt + rbf[1] - hx[1], -hx[2]])
        s2 = (p.bias_sigma_motion * deg) ** 2
        wm = s2 * s2 / v + s2
        W = np.diag([wm, wm, wm / p.bias_vertical_factor])
    clip = p.bias_clip * deg
    e = np.clip(e, -clip, clip)
    PHt = P @ H.T
    K = np.linalg.solve(H @ PHt + W, PHt.T).T
    xs = xs + K @ e
    P = P - K @ PHt.T
    return (np.clip(xs[:3], -clip, clip), np.clip(xs[3:], -p.scale_clip, p.scale_clip),
            0.5 * (P + P.T))


@pytest.mark.parametrize('rest', [False, True])
def test_bias_scale_update_matches_the_matrix_form(rest):
    """The scalar Kalman update (closed-form 3x3 inverse) equals the LU-solve form to rounding."""
    f = AttitudeEstimator(ImprovedFilterParams(), 0.005)
    rng = np.random.default_rng(5)
    t = 0.0
    for _ in range(3000):  # turning and tilting, so that bias and scale both move
        t += 0.005
        gx, gy, gz = 0.3 * math.sin(t), 0.2 * math.cos(0.7 * t), 1.5 * math.sin(0.3 * t)
        a = rng.normal(0.0, 0.05, 3)
        f.update(gx + 0.004, gy - 0.003, gz + 0.002, 0.5 * math.sin(t) + a[0],
                 0.3 * math.cos(t) + a[1], 9.7 + a[2], 0.005)
    assert max(abs(s) for s in f.scale) > 1e-5
    f.rest = rest
    f.rest_gyr = (0.004, -0.003, 0.002)
    ref = copy.deepcopy(f)
    args = (0.002, -0.001, 0.05, (0.3, -0.2, 1.1))
    f._bias_scale_update(*args)
    bias, scale, P = _reference_update(ref, *args)
    assert np.allclose(f.bias, bias, rtol=1e-12, atol=1e-18)
    assert np.allclose(f.scale, scale, rtol=1e-12, atol=1e-18)
    assert np.allclose(f.P6, P, rtol=1e-10, atol=1e-22)
    assert np.array_equal(np.array(f.P6), np.array(f.P6).T)
    assert not np.allclose(ref.bias, bias, rtol=1e-6, atol=0.0)  # the update did move it
