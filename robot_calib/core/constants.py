# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Physical constants and sensor facts shared by every module (SI units)."""

GRAVITY = 9.80665
"""Standard gravity (m/s^2), CGPM 1901; the nominal specific force of an IMU at rest."""

ZERO_GYRO_TURN = 0.05
"""Wheel yaw rate (rad/s) beyond which a gyro reading of exactly 0 counts as not provided.

A real gyro reads exactly 0 only inside a driver's deadband, at rest; while the
wheels turn, zeros mean a driver that fills no angular velocity."""

ZERO_GYRO_SAMPLES = 20
"""Such readings in a row after which the gyro is taken as not provided (until it reads)."""
