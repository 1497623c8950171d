# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The tilt estimator of a parameter set (the seed-faithful or the improved variant), and a run."""

from __future__ import annotations

from typing import Optional

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.estimator import run_batch
from robot_calib.methods.tilt_detection.common import stack_states, TiltBase
from robot_calib.methods.tilt_detection.improved import ImprovedTilt
from robot_calib.methods.tilt_detection.params import TiltParams
from robot_calib.methods.tilt_detection.seed import SeedTilt


def make_estimator(params: Optional[TiltParams] = None, ts: float = 0.005) -> TiltBase:
    """Return the variant ``params.mode`` names, for a nominal sampling period ``ts`` (s)."""
    params = params if params is not None else TiltParams()
    return (SeedTilt if params.mode == 'seed' else ImprovedTilt)(params, ts)


def track(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray,
          params: Optional[TiltParams] = None) -> dict[str, np.ndarray]:
    """
    Run the variant of ``params`` over a recording in arrays, through the generic batch runner.

    :param t: sample times (s), shape (N,)
    :param gyro: rates (rad/s), shape (N, 3), IMU frame
    :param accel: specific force (m/s^2), shape (N, 3), IMU frame
    :param params: parameters (defaults when None)
    :return: the per-sample states as arrays (:func:`common.stack_states`)
    """
    t = np.asarray(t, dtype=float)
    ts = float(np.median(np.diff(t))) if t.size > 1 else 0.005
    states = run_batch(make_estimator(params, ts), T.imu_samples(t, gyro, accel)).outputs
    return stack_states(states)
