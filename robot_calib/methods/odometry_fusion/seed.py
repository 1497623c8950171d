# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Seed 004 as written (``mode: seed``): a 6-state linear filter, IMU prediction, odometry state.

State ``[x, y, vx, vy, ax, ay]`` in the odometry frame: the IMU drives the
prediction (its acceleration, clamped to the robot's limits, rotated by the
integrated gyro heading), the wheel odometry (wheel speeds in rev/s ->
``v = (2 pi n_L r + 2 pi n_R r) / 2``, position by integration) is the
observation of the whole state, with its own covariance
``P_o = F P_o F' + R_o``, the "novel" covariance ``S = P + P_o`` and gain
``K = P S^-1``. Equations are tagged ``seed 004``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from robot_calib.core import types as T
from robot_calib.core.geometry import wrap_angle
from robot_calib.methods.odometry_fusion.common import FusionOutput
from robot_calib.methods.odometry_fusion.variant_base import FusionFilter

SX, SY, SVX, SVY, SAX, SAY = range(6)
"""Indices of the seed state."""


def transition(dt: float) -> np.ndarray:
    """Return F of the constant-acceleration model over ``dt`` (s)."""
    F = np.eye(6)
    F[SX, SVX] = F[SY, SVY] = dt
    F[SX, SAX] = F[SY, SAY] = 0.5 * dt * dt
    F[SVX, SAX] = F[SVY, SAY] = dt
    return F


class SeedFusion(FusionFilter):
    """Seed 004 as written: 6-state linear filter, IMU prediction, odometry state observation."""

    mode = 'seed'

    def _start(self) -> None:
        """Set the seed state: zero, with the seed's initial covariance, Q and R_o."""
        super()._start()
        sp = self.p.seed
        self.x = np.zeros(6)
        self.P = np.diag([1e-4, 1e-4, 1e-2, 1e-2, 1e-1, 1e-1])
        self.Q = np.diag([sp.q_position] * 2 + [sp.q_velocity] * 2 + [sp.q_accel] * 2)
        self.Ro = np.diag([sp.r_position] * 2 + [sp.r_velocity] * 2 + [sp.r_accel] * 2)
        self.Po = np.zeros((6, 6))
        self.z = np.zeros(6)
        self.heading = 0.0
        self.odom_yaw = 0.0
        self._z_t: Optional[float] = None

    def _init_pose(self, s: Optional[T.OdomSample]) -> None:
        """Start at the first odometry pose ``s`` (or 0) when ``initial_pose_from_odom``."""
        if self.initialised:
            return
        if s is not None and self.p.initial_pose_from_odom:
            self.x[SX], self.x[SY] = s.x, s.y
            self.z[SX], self.z[SY] = s.x, s.y
            self.heading = self.odom_yaw = s.yaw
        self.initialised = True

    def _imu_step(self, t: float, gz: float, ax: float, use_acc: bool) -> Optional[str]:
        """Predict with the IMU acceleration (seed 004); the gyro integrates the heading."""
        sp = self.p.seed
        if self.t is None:
            self.t = t
            return None
        dt = t - self.t
        if dt <= 0:
            return 'stale'
        # no motion is invented over a gap (or a clock jump, which validation turns into one):
        # the prediction may span time the IMU was running (its first samples go to the
        # front end's unit and mounting detection), never time it was silent
        gap = self.imu_run_start - self.t > self.p.sensor_timeout
        self.t = t
        if gap:
            return None
        self.heading = wrap_angle(self.heading + gz * dt)
        # IMU acceleration, clamped to the robot's limits (seed 004), into the odom frame
        a = max(-sp.max_accel, min(sp.max_accel, ax))
        F = transition(dt)
        x = F @ self.x  # seed 004, x_pred = F x
        x[SAX] = a * math.cos(self.heading)
        x[SAY] = a * math.sin(self.heading)
        sp_now = math.hypot(x[SVX], x[SVY])
        if sp_now > sp.max_speed:  # clamp the IMU velocity (seed 004)
            x[SVX] *= sp.max_speed / sp_now
            x[SVY] *= sp.max_speed / sp_now
        self.x = x
        self.P = F @ self.P @ F.T + self.Q  # seed 004, P = F P F' + Q
        self.path_length += math.hypot(x[SVX], x[SVY]) * dt
        return None

    def _wheel_step(self, t: float, v: float, w: float) -> Optional[str]:
        """Integrate the wheel odometry into the observed state and observe it (seed 004)."""
        if not self.initialised:
            self._init_pose(None)
        last = self._z_t
        self._z_t = t
        if last is None or t - last > self.p.sensor_timeout:  # first, or after a gap or jump
            self.z[SVX] = v * math.cos(self.odom_yaw)
            self.z[SVY] = v * math.sin(self.odom_yaw)
            if self.t is None:
                self.t = t
            return None
        dt = t - last
        if dt <= 0:
            return 'stale'
        # odometry by integration of the wheel speed (seed 004)
        self.odom_yaw = wrap_angle(self.odom_yaw + w * dt)
        vx, vy = v * math.cos(self.odom_yaw), v * math.sin(self.odom_yaw)
        z = self.z
        ax_o, ay_o = (vx - z[SVX]) / dt, (vy - z[SVY]) / dt
        z[SX] += vx * dt
        z[SY] += vy * dt
        z[SVX], z[SVY], z[SAX], z[SAY] = vx, vy, ax_o, ay_o
        F = transition(dt)
        self.Po = F @ self.Po @ F.T + self.Ro  # seed 004, P_o = F P_o F' + R_o
        self._observe(z)
        return None

    def _observe(self, z: np.ndarray) -> None:
        """Apply seed 004's observation step with the odometry state ``z``."""
        S = self.P + self.Po  # seed 004, "novel" covariance S = P + P_o
        K = self.P @ np.linalg.inv(S)  # seed 004, K = P S^-1
        self.x = self.x + K @ (z - self.x)  # seed 004, x = x_pred + K (z - x_pred)
        self.P = (np.eye(6) - K) @ self.P  # seed 004, P = (I - K) P

    def _output(self) -> Optional[FusionOutput]:
        """Return the current estimate (heading from the gyro integration), or None."""
        if self.t is None or not self.initialised:
            return None
        x, P = self.x, self.P
        v = math.hypot(x[SVX], x[SVY])
        c, s = math.cos(self.heading), math.sin(self.heading)
        fwd = c * x[SVX] + s * x[SVY]
        pose_cov = np.zeros((3, 3))
        pose_cov[:2, :2] = P[:2, :2]
        pose_cov[2, 2] = float('nan')  # the seed state has no heading
        twist_cov = np.diag([P[SVX, SVX] + P[SVY, SVY], float('nan'), float('nan')])
        return FusionOutput(self.t, float(x[SX]), float(x[SY]), self.heading,
                            math.copysign(v, fwd), float('nan'), pose_cov, twist_cov)

    def _estimates(self) -> dict:
        """Return the seed filter's state (velocity, acceleration)."""
        return {'vx': float(self.x[SVX]), 'vy': float(self.x[SVY]),
                'ax': float(self.x[SAX]), 'ay': float(self.x[SAY])}

    def _variant_result(self) -> dict:
        """Return the observed odometry state and its covariance P_o."""
        return {'odometry_state': self.z.copy(), 'odometry_covariance': self.Po.copy()}
