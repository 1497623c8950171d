# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Chi-square tail probabilities and quantiles without scipy.

The gates of fusion and wheel calibration need a few quantiles once at start;
importing ``scipy.special`` for them is about 0.2 s, a tenth of a short replay
and all of the scipy a bag without scans needs. Accurate to about 1e-13
relative against ``scipy.special.chdtrc`` / ``chdtri`` (tested).
"""

from __future__ import annotations

import math
from statistics import NormalDist

_EPS = 1e-16
_TINY = 1e-300


def _gamma_series(a: float, x: float) -> float:
    """Return the regularized lower incomplete gamma P(a, x) by its series (x < a + 1)."""
    # Abramowitz & Stegun 6.5.29: P = x^a e^-x / Gamma(a + 1) * sum x^n / ((a+1)...(a+n))
    term = total = 1.0 / a
    ap = a
    for _ in range(100000):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gamma_fraction(a: float, x: float) -> float:
    """Return the regularized upper incomplete gamma Q(a, x) by its continued fraction."""
    # Abramowitz & Stegun 6.5.31, evaluated with the modified Lentz method
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, 100000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _tails(x: float, dof: float) -> tuple[float, float]:
    """Return (P(X <= x), P(X > x)), the smaller of the two computed directly."""
    if x <= 0.0:
        return 0.0, 1.0
    if math.isinf(x):
        return 1.0, 0.0
    a, half = 0.5 * dof, 0.5 * x
    if half < a + 1.0:
        cdf = _gamma_series(a, half)
        return cdf, 1.0 - cdf
    sf = _gamma_fraction(a, half)
    return 1.0 - sf, sf


def chi2_sf(x: float, dof: float) -> float:
    """Return P(X > x) for X chi-square with ``dof`` > 0 degrees of freedom."""
    if dof == 1.0 and x > 0.0:
        return math.erfc(math.sqrt(0.5 * x))
    return _tails(x, dof)[1]


def _log_pdf(x: float, dof: float) -> float:
    a = 0.5 * dof
    return (a - 1.0) * math.log(x) - 0.5 * x - a * math.log(2.0) - math.lgamma(a)


def chi2_isf(p: float, dof: float) -> float:
    """Return x with P(X > x) = ``p`` for X chi-square with ``dof`` degrees of freedom."""
    if not 0.0 <= p <= 1.0 or not dof > 0.0:
        raise ValueError(f'chi-square quantile of p={p}, dof={dof}: expected 0 <= p <= 1, '
                         'dof > 0')
    if p == 0.0:
        return math.inf
    if p == 1.0:
        return 0.0
    a = 0.5 * dof
    upper = p <= 0.5          # solve on the smaller tail, in logs (both are accurate there)
    goal = p if upper else 1.0 - p
    target = math.log(goal)
    # Wilson-Hilferty start (A&S 26.4.17); in the lower tail P(a, x/2) <= (x/2)^a / Gamma(a+1)
    # gives a lower bound, the better start for few degrees of freedom
    z = -NormalDist().inv_cdf(p)
    h = 2.0 / (9.0 * dof)
    x = dof * max(1.0 - h + z * math.sqrt(h), 0.0) ** 3
    if not upper:
        x = max(x, 2.0 * math.exp((math.lgamma(a + 1.0) + target) / a))
    x = max(x, 1e-300)
    lo, hi = 0.0, math.inf
    for _ in range(300):
        cdf, sf = _tails(x, dof)
        tail = sf if upper else cdf
        if (tail > goal) == upper:
            lo = x
        else:
            hi = x
        pdf = math.exp(_log_pdf(x, dof))
        nxt = math.nan
        if tail > 0.0 and pdf > 0.0:
            step = (math.log(tail) - target) * tail / pdf
            nxt = x + step if upper else x - step
        if not lo < nxt < hi:  # outside the bracket: bisect it (geometrically when wide)
            if math.isinf(hi):
                nxt = 4.0 * x
            elif lo == 0.0:
                nxt = 0.25 * hi
            else:
                nxt = math.sqrt(lo * hi) if hi > 4.0 * lo else 0.5 * (lo + hi)
        if abs(nxt - x) <= 4e-16 * x:
            return nxt
        x = nxt
    return x


def chi2_ppf(probability: float, dof: float) -> float:
    """Return the chi-square quantile of ``probability`` with ``dof`` degrees of freedom."""
    return chi2_isf(1.0 - probability, dof)
