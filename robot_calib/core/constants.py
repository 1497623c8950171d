# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Physical constants shared by every module (SI units)."""

GRAVITY = 9.80665
"""Standard gravity (m/s^2), CGPM 1901; the nominal specific force of an IMU at rest."""
