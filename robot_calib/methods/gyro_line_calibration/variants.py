# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The two variants of gyro line calibration by ``GyroLineParams.mode``, and how to make one."""

from __future__ import annotations

from typing import Optional

from robot_calib.methods.gyro_line_calibration.improved import ImprovedGyroLine
from robot_calib.methods.gyro_line_calibration.params import GyroLineParams
from robot_calib.methods.gyro_line_calibration.seed import SeedGyroLine
from robot_calib.methods.gyro_line_calibration.variant_base import GyroLineBase

VARIANTS = {'seed': SeedGyroLine, 'improved': ImprovedGyroLine}
"""The estimator variant of each ``mode``."""


def make_estimator(params: Optional[GyroLineParams] = None) -> GyroLineBase:
    """Return the estimator variant ``params.mode`` selects (defaults when None)."""
    params = params if params is not None else GyroLineParams()
    return VARIANTS[params.mode](params)
