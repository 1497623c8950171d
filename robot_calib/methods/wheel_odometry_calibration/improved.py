# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The improved variant (``mode: improved``): the joint ML fit over all segments, both drives.

Every segment (straight and turning) enters a maximum-likelihood fit of all
intrinsic parameters and the lidar pose (:func:`~.solver.calibrate`: outlier
rejection, per-axis noise, covariance, observability check and verdict).
While streaming, each solve starts from the previous estimate; the final solve
starts from the global initialisation, then deskews the key-frame scans again
with the calibrated odometry, re-matches them and solves once more
(``redeskew``), which removes the bias a wrong nominal geometry leaves.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np
from robot_calib.methods.wheel_odometry_calibration.common import CalibResult
from robot_calib.methods.wheel_odometry_calibration.solver import calibrate
from robot_calib.methods.wheel_odometry_calibration.variant_base import StreamingCalibrator


class ImprovedWheelCalibrator(StreamingCalibrator):
    """
    Improved wheel calibration, an :class:`robot_calib.core.estimator.Estimator`.

    ``update(sample)`` takes joint states, odometry and scans and returns a
    :class:`~.common.WheelUpdate` or None; ``result()`` a
    :class:`~.common.WheelCalibResult`; ``set_mounting(transform)`` the lidar
    mounting; ``reset()`` forgets the drive (see :class:`~.stream.StreamingCalibrator`).
    The seed's stage counter of a steered drive wheel is reported beside the
    estimate (``seed_counter``), for comparison.
    """

    _warm: Optional[np.ndarray] = None

    def _on_restart(self) -> None:
        """Forget the warm start: a new drive type has other parameters."""
        self._warm = None

    def _estimate(self, final: bool, problems: list[str]) -> CalibResult:
        """Return the joint fit (warm-started while streaming; final: re-deskewed, re-solved)."""
        front = self.front
        warm = None if final else self._warm
        res = calibrate(front.drive, list(front.segments), front.params, problems, x0=warm)
        if 'x' in res.details and np.all(np.isfinite(res.details['x'])):
            self._warm = np.asarray(res.details['x'])
            if final and self.params.redeskew:
                segs = front.redeskew(self._warm)
                if segs is not None and len(segs) >= 3:
                    res = calibrate(front.drive, segs, front.params, problems, x0=self._warm)
                    res = dataclasses.replace(res, details={**res.details, 'redeskewed': True})
        return res
