# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Exact scans of simple rooms, shared by the lidar tests."""

import numpy as np


def box_ranges(ox, oy, angles, x0, y0, x1, y1):
    """Return the exact ranges (m) from (ox, oy) along ``angles`` (rad) inside a box."""
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide='ignore', invalid='ignore'):
        tx = np.where(c > 0, (x1 - ox) / c, (x0 - ox) / c)
        ty = np.where(s > 0, (y1 - oy) / s, (y0 - oy) / s)
    return np.minimum(np.where(c == 0, np.inf, tx), np.where(s == 0, np.inf, ty))
