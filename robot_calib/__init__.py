# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""robot_calib: heading, tilt, fusion and wheel calibration for low-cost wheeled robots."""

__version__ = '0.1.0'
