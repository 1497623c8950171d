# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The seed-faithful ``tilt_detection`` variant: seed 002's per-axis Kalman filter.

State ``X = [angle, gyro_bias]`` for roll and for pitch, the gyro rate as the
control input, the accelerometer roll/pitch as the observation,
``A = [[1, -dt], [0, 1]]``, ``B = [dt, 0]'``, ``H = [1, 0]``,
``Q = diag(Q_angle, Q_gyro)``, scalar ``R``. The fall decision is the seed's
"angle outside a preset range": ``|roll| > fall_angle or |pitch| > fall_angle``.

Units: time s, rates rad/s, specific force m/s^2, angles rad.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from robot_calib.core.geometry import quat_tuple_from_rpy
from robot_calib.methods.tilt_detection.params import SeedFilterParams
from robot_calib.methods.tilt_detection.quaternion import positive_w, qrot, tilt_of
from robot_calib.methods.tilt_detection.variant_base import TiltEstimatorBase


class SeedKalmanAxis:
    """One axis of the seed's 2-state Kalman filter (seed 002), state [angle rad, bias rad/s]."""

    def __init__(self, q_angle: float, q_gyro: float, r_angle: float, angle0: float = 0.0):
        """Create the filter with the seed's noise values and an initial angle (rad)."""
        self.q_angle = q_angle
        self.q_gyro = q_gyro
        self.r = r_angle
        self.x = np.array([angle0, 0.0])
        self.P = np.zeros((2, 2))

    def step(self, rate: float, z_angle: float, dt: float) -> float:
        """
        Run one predict/update: gyro rate (rad/s), accel angle (rad), dt (s); return angle.

        The matrix products are written out for A = [[1, -dt], [0, 1]],
        B = [dt, 0]', H = [1, 0], Q = diag(Q_angle, Q_gyro).
        """
        angle, bias = float(self.x[0]), float(self.x[1])
        (p00, p01), (p10, p11) = self.P
        # seed 002, X(k|k-1) = A X(k-1|k-1) + B U(k)
        angle = angle - dt * bias + dt * rate
        # seed 002, P(k|k-1) = A P A' + Q
        q00 = p00 - dt * (p10 + p01) + dt * dt * p11 + self.q_angle
        q01 = p01 - dt * p11
        q10 = p10 - dt * p11
        q11 = p11 + self.q_gyro
        # seed 002, K = P H' / (H P H' + R)
        s = q00 + self.r
        k0 = q00 / s
        k1 = q10 / s
        # seed 002, X(k|k) = X(k|k-1) + K (Z(k) - H X(k|k-1))
        innov = z_angle - angle
        angle += k0 * innov
        bias += k1 * innov
        # seed 002, P(k|k) = (I - K H) P(k|k-1)
        self.P = np.array([[q00 - k0 * q00, q01 - k0 * q01],
                           [q10 - k1 * q00, q11 - k1 * q01]])
        self.x = np.array([angle, bias])
        return angle


def accel_roll_pitch(ax: float, ay: float, az: float) -> tuple:
    """
    Return the accelerometer roll and pitch (rad) as the seed uses them as observations.

    roll = atan2(a_y, a_z), pitch = atan2(-a_x, sqrt(a_y^2 + a_z^2)) (REP-103, z up).
    """
    return math.atan2(ay, az), math.atan2(-ax, math.sqrt(ay * ay + az * az))


class SeedEstimator:
    """The seed's roll and pitch Kalman filters; the attitude is Rx(roll) Ry(pitch), yaw 0."""

    def __init__(self, p: SeedFilterParams):
        """Create the two axis filters (initialised from the first accelerometer sample)."""
        self.p = p
        self.roll: Optional[SeedKalmanAxis] = None
        self.pitch: Optional[SeedKalmanAxis] = None

    def reset(self) -> None:
        """Restart from the next accelerometer sample."""
        self.roll = None
        self.pitch = None

    def update(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
               dt: float) -> tuple:
        """Return (quaternion, roll, pitch) after one sample; rates rad/s, accel m/s^2, dt s."""
        r_acc, p_acc = accel_roll_pitch(ax, ay, az)
        if self.roll is None:
            p = self.p
            self.roll = SeedKalmanAxis(p.q_angle, p.q_gyro, p.r_angle, r_acc)
            self.pitch = SeedKalmanAxis(p.q_angle, p.q_gyro, p.r_angle, p_acc)
            roll, pitch = r_acc, p_acc
        else:
            # The seed feeds each axis its own gyro rate (small-angle Euler rates).
            roll = self.roll.step(gx, r_acc, dt)
            pitch = self.pitch.step(gy, p_acc, dt)
        return quat_tuple_from_rpy(roll, pitch, 0.0), roll, pitch


class SeedTiltEstimator(TiltEstimatorBase):
    """
    Tilt and fall alert from the seed's filter (``mode: seed``; Estimator protocol).

    The seed's filter works in the body frame: the measurements are rotated
    by the mounting first. Its attitude is Rx(roll) Ry(pitch) (yaw 0), its
    fall decision ``max(|roll|, |pitch|)``.
    """

    mode = 'seed'

    def _new_filter(self) -> None:
        """Create the two axis filters (they start from the next accelerometer sample)."""
        self._filter = SeedEstimator(self.params.seed)

    def _restart_filter(self) -> None:
        """Restart both axes from the next accelerometer sample."""
        self._filter.reset()

    def _estimate(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
                  dt: float) -> tuple:
        """Run the seed's filter on one sample (see :meth:`TiltEstimatorBase._estimate`)."""
        m = self._mount
        gx, gy, gz = qrot(m, gx, gy, gz)
        ax, ay, az = qrot(m, ax, ay, az)
        f = self._filter
        q, roll, pitch = f.update(gx, gy, gz, ax, ay, az, dt)
        bias = (f.roll.x[1], f.pitch.x[1], 0.0)
        q = positive_w(q)
        # seed 002: fallen when an angle leaves the preset range
        return q, tilt_of(q), roll, pitch, bias, False, max(abs(roll), abs(pitch))
