# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The two variants of wheel calibration by ``WheelCalibParams.mode``, and the way to make one."""

from __future__ import annotations

from typing import Any, Optional

from robot_calib.methods.wheel_odometry_calibration.improved import ImprovedWheelCalibrator
from robot_calib.methods.wheel_odometry_calibration.params import WheelCalibParams
from robot_calib.methods.wheel_odometry_calibration.seed import SeedWheelCalibrator
from robot_calib.methods.wheel_odometry_calibration.variant_base import StreamingCalibrator

VARIANTS = {'seed': SeedWheelCalibrator, 'improved': ImprovedWheelCalibrator}
"""The estimator variant of each ``mode``."""


def make_estimator(params: Optional[WheelCalibParams] = None, **options: Any
                   ) -> StreamingCalibrator:
    """Return the variant ``params.mode`` selects; ``options`` go to its constructor."""
    params = params if params is not None else WheelCalibParams()
    return VARIANTS[params.mode](params, **options)
