# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The two ``tilt_detection`` variants by ``TiltParams.mode``, the one way to make one, a run."""

from __future__ import annotations

from typing import Any, Optional

from robot_calib.core.types import imu_samples
from robot_calib.methods.tilt_detection.common import (NOMINAL_PERIOD, nominal_period,
                                                       outputs_as_arrays)
from robot_calib.methods.tilt_detection.improved import ImprovedTiltEstimator
from robot_calib.methods.tilt_detection.params import TiltParams
from robot_calib.methods.tilt_detection.seed import SeedTiltEstimator
from robot_calib.methods.tilt_detection.variant_base import TiltEstimatorBase

VARIANTS: dict[str, type[TiltEstimatorBase]] = {
    SeedTiltEstimator.mode: SeedTiltEstimator,
    ImprovedTiltEstimator.mode: ImprovedTiltEstimator,
}
"""Estimator class by ``TiltParams.mode``."""


def make_estimator(params: Optional[TiltParams] = None,
                   ts: float = NOMINAL_PERIOD) -> TiltEstimatorBase:
    """Return the variant ``params.mode`` selects, for a nominal sampling period ``ts`` (s)."""
    params = params if params is not None else TiltParams()
    return VARIANTS[params.mode](params, ts)


def track(t: Any, gyro: Any, accel: Any, params: Optional[TiltParams] = None) -> dict:
    """
    Run the variant of ``params`` over a recording in arrays, one output row per sample.

    ``t`` (N,) s, ``gyro`` (N, 3) rad/s and ``accel`` (N, 3) m/s^2 in the IMU
    frame; returns the per-sample outputs as arrays (:func:`common.outputs_as_arrays`):
    a sample the estimator rejects (as the live node would) keeps its row, NaN.
    """
    est = make_estimator(params, nominal_period(t))
    return outputs_as_arrays([est.update(s) for s in imu_samples(t, gyro, accel)])
