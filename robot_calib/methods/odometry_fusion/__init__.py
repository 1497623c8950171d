# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Adaptive Kalman fusion of IMU and wheel odometry (seed 004)."""

SEED = '004'
"""The patent this method reads (``shared/seeds/004_*``); methods are listed in this order."""
