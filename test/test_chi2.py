# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Chi-square tails and quantiles without scipy, against scipy."""

import math

import numpy as np
import pytest

from robot_calib.core import chi2

special = pytest.importorskip('scipy.special')
DOFS = [0.5, 1, 2, 3, 4, 5, 7.5, 10, 30, 100, 300, 1000, 5000]


@pytest.mark.parametrize('dof', DOFS)
def test_tail_probability_matches_scipy(dof):
    for x in np.logspace(-6, 4, 60):
        expected = special.chdtrc(dof, x)
        if expected > 1e-280:
            assert chi2.chi2_sf(x, dof) == pytest.approx(expected, rel=1e-11), x


@pytest.mark.parametrize('dof', DOFS)
def test_quantile_matches_scipy(dof):
    for p in [1e-200, 1e-30, 1e-10, 1e-3, 0.025, 0.5, 0.975, 0.999999, 1 - 1e-12]:
        x = chi2.chi2_isf(p, dof)
        assert x == pytest.approx(special.chdtri(dof, p), rel=1e-12), p
    assert chi2.chi2_ppf(0.99, dof) == pytest.approx(special.chdtri(dof, 0.01), rel=1e-12)


def test_quantile_edges_and_bad_input():
    assert chi2.chi2_isf(0.0, 3) == math.inf and chi2.chi2_isf(1.0, 3) == 0.0
    assert chi2.chi2_sf(0.0, 3) == 1.0 and chi2.chi2_sf(math.inf, 3) == 0.0
    for p, dof in [(-0.1, 3), (1.5, 3), (0.5, 0.0), (math.nan, 2), (0.5, math.nan)]:
        with pytest.raises(ValueError, match='chi-square'):
            chi2.chi2_isf(p, dof)


def test_fusion_starts_without_scipy(fresh_python):
    code = ('import sys\n'
            'from robot_calib.methods.odometry_fusion.variants import make_estimator\n'
            'from robot_calib.methods.odometry_fusion.params import FusionParams\n'
            'make_estimator(FusionParams())\n'
            'print(sorted(m for m in sys.modules if m.startswith("scipy")))\n')
    assert fresh_python(code) == '[]'
