# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Gyro correction by loop closure: scan matching against stored key frames (seed 001)."""

SEED = '001'
"""The patent this method reads (``shared/seeds/001_*``); methods are listed in this order."""
