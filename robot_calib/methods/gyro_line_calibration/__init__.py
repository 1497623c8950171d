# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Gyro heading calibration from wall lines (seed 000, robot vacuums)."""

SEED = '000'
"""The patent this method reads (``shared/seeds/000_*``); methods are listed in this order."""
