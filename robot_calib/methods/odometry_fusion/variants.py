# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The two variants of the fusion filter, chosen by ``params.mode``."""

from __future__ import annotations

from typing import Optional

from robot_calib.methods.odometry_fusion.improved import ImprovedFusion
from robot_calib.methods.odometry_fusion.params import FusionParams
from robot_calib.methods.odometry_fusion.seed import SeedFusion
from robot_calib.methods.odometry_fusion.variant_base import FusionFilter, Log


VARIANTS = {'seed': SeedFusion, 'improved': ImprovedFusion}
"""The filter variant of each ``mode``."""


def make_estimator(params: Optional[FusionParams] = None,
                   log: Optional[Log] = None) -> FusionFilter:
    """Return the filter selected by ``params.mode`` (``seed`` or ``improved``)."""
    params = params or FusionParams()
    return VARIANTS[params.mode](params, log)
