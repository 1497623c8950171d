# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The one rule that tells an accelerometer's units from the gravity it reads: m/s^2 or g.

An accelerometer measures specific force, gravity included: a robot standing
level reads ``|a| = g``, 9.81 in m/s^2 and 1.0 in g. While it drives, ``|a| =
|g - a_lin|`` with ``a_lin`` its own acceleration: a ground robot's lasting
accelerations (starting, braking, turning, slopes) stay within about 0.3 g, so
the median ``|a|`` over a few samples stays within 30 % of g in either unit,
bumps and vibration being short and left out by the median. The two bands,
0.7-1.3 read in g and 6.86-12.75 read in m/s^2, are a factor of 5 apart,
so no robot that reads gravity falls between them or into both. Whatever falls
outside both is neither: a driver that took gravity out (|a| near 0 at rest), a
sensor in free fall, or another unit; then the accelerometer cannot tell up and
a method says so rather than guess.

Units: specific force in m/s^2 unless said otherwise.
"""

from __future__ import annotations

from robot_calib.core.constants import GRAVITY

GRAVITY_BAND = (0.7, 1.3)
"""|a| within this share of g (9.81 m/s^2, or 1 in g) is gravity in that unit (ratio)."""

UNITS_SAMPLES = 10
"""Samples whose median |a| tells the units when one sample alone does not."""


def accel_units_of(norm: float) -> str:
    """
    Return the units whose gravity a specific-force magnitude ``norm`` reads as.

    ``'mps2'`` for 6.86-12.75 (m/s^2), ``'g'`` for 0.7-1.3 (g), ``''`` for neither.
    """
    lo, hi = GRAVITY_BAND
    if lo * GRAVITY <= norm <= hi * GRAVITY:
        return 'mps2'
    return 'g' if lo <= norm <= hi else ''
