# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The gyro error filter of the improved loop-closure variant: bias, bias drift rate and scale.

The gyro reads ``g = (1 + s) w + b(t)`` with ``b(t) = b + d (t - t0)`` (a
bias that drifts, e.g. with temperature, plus a random walk). The filter
keeps ``x = [b, d, s]`` (rad/s, rad/s^2, -) and its covariance; one
registration of the scan against a keyframe ``dt`` s ago measures the heading
change ``dth_scan`` (rad) the gyro integration (with the current estimates
removed) saw as ``dth_gyro``. To first order

``dth_gyro - dth_scan = (b - b_est) dt - (d - d_est) dt^2 / 2 + (s - s_est) dth_scan``

(the bias at the end of the interval; the scale error acts on the turn), a
linear measurement of the error state, so a Kalman update (Kalman 1960;
Groves, *Principles of GNSS, Inertial, and Multisensor Integrated
Navigation*, 2nd ed., ch. 3 and, for the bias states, ch. 14) corrects
``x``. The process model propagates ``b += d dt`` with random walks on ``b``
and ``d``; the scale is constant.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from robot_calib.methods.loop_closure_correction.params import MotionParams


class GyroErrorFilter:
    """Kalman filter of the residual gyro bias (rad/s), its drift (rad/s^2) and scale error."""

    def __init__(self, motion: MotionParams):
        """Start at zero errors with the prior sigmas of ``motion``."""
        self.motion = motion
        m = motion
        self.x = np.zeros(3)
        self.P = np.diag([m.initial_bias_sigma ** 2,
                          m.initial_bias_drift_sigma ** 2 if m.estimate_bias_drift else 0.0,
                          m.initial_scale_sigma ** 2 if m.estimate_gyro_scale else 0.0])
        self.t: Optional[float] = None

    def bias_at(self, t: float) -> float:
        """Return the bias estimate at ``t`` (s), extrapolated with the drift rate (rad/s)."""
        if self.t is None:
            return float(self.x[0])
        return float(self.x[0] + self.x[1] * (t - self.t))

    @property
    def scale(self) -> float:
        """Return the scale error estimate (-; reading = (1 + scale) rate)."""
        return float(self.x[2])

    def predict(self, t: float) -> None:
        """Propagate the state and covariance to ``t`` (s)."""
        m = self.motion
        if self.t is not None and t > self.t:
            dt = t - self.t
            f = np.array([[1.0, dt, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
            self.x = f @ self.x
            q = np.diag([m.bias_random_walk ** 2 * dt,
                         m.bias_drift_random_walk ** 2 * dt if m.estimate_bias_drift else 0.0,
                         0.0])
            self.P = f @ self.P @ f.T + q
        self.t = t if self.t is None else max(self.t, t)

    def update(self, t: float, dt: float, residual: float, turn: float,
               meas_var: float) -> bool:
        """
        Correct the state with one heading residual; return False when it is gated out.

        ``residual`` = gyro heading change minus scan heading change (rad) over
        the last ``dt`` s ending at ``t``, ``turn`` the scan heading change
        (rad), ``meas_var`` the residual's variance (rad^2).
        """
        m = self.motion
        self.predict(t)
        h = np.array([dt, -0.5 * dt * dt, turn])
        s = float(h @ self.P @ h) + meas_var
        if residual ** 2 > 9.0 * s:
            return False
        k = self.P @ h / s
        self.x = self.x + k * residual
        self.P = (np.eye(3) - np.outer(k, h)) @ self.P
        self.P = 0.5 * (self.P + self.P.T)
        self.x[0] = float(np.clip(self.x[0], -m.max_gyro_bias, m.max_gyro_bias))
        self.x[2] = float(np.clip(self.x[2], -m.max_gyro_scale, m.max_gyro_scale))
        return True
