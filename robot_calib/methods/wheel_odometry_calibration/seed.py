# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The seed-faithful variant (``mode: seed``): seed 003 stages, or Censi's closed form.

Steered drive wheel: the seed's straight stages, offset gate and stage
counter (:mod:`.stages`); the wheel base, steering scale and lidar pose stay
nominal. Differential drive (which seed 003 does not cover): the published
baseline, the closed form of Censi et al. (T-RO 2013) with the authors'
outlier trimming and Fisher-information uncertainty
(:func:`~.solver.censi_result`).
"""

from __future__ import annotations

from robot_calib.methods.wheel_odometry_calibration.common import CalibResult
from robot_calib.methods.wheel_odometry_calibration.solver import censi_result
from robot_calib.methods.wheel_odometry_calibration.variant_base import StreamingCalibrator


class SeedWheelCalibrator(StreamingCalibrator):
    """
    Seed-faithful wheel calibration, an :class:`robot_calib.core.estimator.Estimator`.

    ``update(sample)`` takes joint states, odometry and scans and returns a
    :class:`~.common.WheelUpdate` or None; ``result()`` a
    :class:`~.common.WheelCalibResult`; ``set_mounting(transform)`` the lidar
    mounting; ``reset()`` forgets the drive (see :class:`~.stream.StreamingCalibrator`).
    """

    def _estimate(self, final: bool, problems: list[str]) -> CalibResult:
        """Return the seed's stage result (steered wheel) or Censi's closed form (differential)."""
        if self.stage_gate is not None:
            return self.stage_gate.result(problems)
        return censi_result(list(self.front.segments), self.front.params, problems)
