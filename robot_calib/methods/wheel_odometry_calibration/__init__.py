# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Wheel odometry calibration against lidar scan matching (seed 003)."""

SEED = '003'
"""The patent this method reads (``shared/seeds/003_*``); methods are listed in this order."""
