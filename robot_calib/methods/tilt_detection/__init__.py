# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Tilt estimation and fall alerts from gyro and accelerometer (seed 002)."""

SEED = '002'
"""The patent this method reads (``shared/seeds/002_*``); methods are listed in this order."""
