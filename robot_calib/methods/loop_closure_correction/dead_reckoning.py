# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loop closure's dead reckoning: heading from the gyro (or the odometry), distance from the wheels.

:class:`DeadReckoning` is a mixin of
:class:`robot_calib.methods.loop_closure_correction.variant_base.LoopClosureBase`;
it expects of it ``params``, the raw pose ``raw`` (x m, y m, yaw rad), the
learnt gyro terms (``gyro_bias``, ``gyro_bias_rate``, ``gyro_scale``,
``_bias_t``), the uncertainties ``sigma_yaw`` and ``sigma_xy``, ``path``,
``rate``, ``using_imu``, ``counts``, and the state ``_last_imu``,
``_last_odom``, ``zero_gyro`` and ``_odom_turn``.
"""

from __future__ import annotations

import math

import numpy as np
from robot_calib.core.geometry import rot2, se2_between, wrap_angle


class DeadReckoning:
    """The gyro and odometry integration of the loop-closure corrector (see the module)."""

    def _integrate_gyro(self, t: float, gyro_z: float) -> None:
        """
        Integrate the gyro yaw rate (rad/s, in base_link) up to time ``t`` (s).

        The heading comes from the gyro once the first IMU sample arrives (unless
        ``heading_source`` is ``odom``); the learned bias is subtracted.
        """
        if self.params.heading_source == 'odom' or not math.isfinite(gyro_z):
            return
        if gyro_z == 0.0:
            if self._gyro_absent(t):
                return
        else:
            self.zero_gyro.reading()
        self.using_imu = True
        plain = self.gyro_scale == 0.0 and self.gyro_bias_rate == 0.0
        bias = self.gyro_bias if plain or self._bias_t is None \
            else self.gyro_bias + self.gyro_bias_rate * (t - self._bias_t)
        self.rate = gyro_z - bias if plain else (gyro_z - bias) / (1.0 + self.gyro_scale)
        if self._last_imu is not None:
            t0, w0 = self._last_imu
            dt = t - t0
            if 0 < dt < 1.0:
                # trapezoidal integration of the bias- (and scale-) corrected rate
                if plain:
                    self.raw[2] = wrap_angle(self.raw[2] + 0.5 * (w0 + gyro_z) * dt
                                             - self.gyro_bias * dt)
                else:
                    self.raw[2] = wrap_angle(self.raw[2] + (0.5 * (w0 + gyro_z) - bias) * dt
                                             / (1.0 + self.gyro_scale))
                self.sigma_yaw += self.params.motion.heading_drift_rate * dt
        self._last_imu = (t, gyro_z)

    def _gyro_absent(self, t: float) -> bool:
        """
        Return True when a gyro z of exactly 0 means the IMU gives no yaw rate.

        (:mod:`robot_calib.core.zero_gyro`.) The heading then comes from the
        odometry until the gyro reads again.
        """
        was = self.zero_gyro.missing
        if not self.zero_gyro.zero(t, self._odom_turn):
            return False
        if not was:  # the heading from the odometry now, with the turn the zeros hid
            self.raw[2] = wrap_angle(self.raw[2] + self.zero_gyro.hidden_turn)
            self.using_imu = False
            self._last_imu = None
            self.counts['gyro_missing_periods'] += 1
        return True

    def _advance_odom(self, t: float, x: float, y: float, yaw: float) -> None:
        """Advance the dead reckoning with one odometry pose (m, m, rad) at ``t`` (s)."""
        m = self.params.motion
        cur = np.array([x, y, yaw], dtype=float)
        if self._last_odom is not None:
            t_prev, prev = self._last_odom
            d = se2_between(prev, cur)
            ds = math.hypot(d[0], d[1])
            if t > t_prev:
                self._odom_turn = d[2] / (t - t_prev)
            if self.using_imu:
                heading = self.raw[2]
            else:
                heading = self.raw[2] + 0.5 * d[2]
                self.raw[2] = wrap_angle(self.raw[2] + d[2])
                if t > t_prev:
                    self.sigma_yaw += m.heading_drift_rate * (t - t_prev)
                    self.rate = d[2] / (t - t_prev)
            # body-frame increment rotated by the (gyro) heading
            self.raw[:2] += rot2(heading) @ d[:2]
            self.path += ds
            self.sigma_yaw += m.heading_noise * abs(d[2])
            self.sigma_xy += m.odom_noise * ds + self.sigma_yaw * ds
        self._last_odom = (t, cur)
