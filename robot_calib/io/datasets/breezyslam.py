# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loader of BreezySLAM's Mines ParisTech rover logs (``exp1.dat``, ``exp2.dat``).

Format (as BreezySLAM's ``examples`` readers parse it): one line per scan,
whitespace separated; field 0 is the timestamp (microseconds), fields 2 and
3 are the left and right wheel encoder counts, fields 24..705 are the 682
ranges (mm, 0 = no return) of a Hokuyo URG-04LX (240 deg field of view, 10
Hz). The last field is ignored, like BreezySLAM does. BreezySLAM's rover
model (``examples/mines.py``): wheel radius 77 mm, half axle 165 mm, encoder
counts to degrees ``ticks * 180 / 2000`` (4000 counts per wheel turn); laser
145 mm ahead of the axle centre. Its odometry (``vehicles.py``) moves the robot
by ``r (dphi_l + dphi_r)`` (no halving) and turns it by ``r (dphi_r - dphi_l) /
half_axle``: in the convention of :mod:`robot_calib.core.kinematics` that is an
effective wheel radius of 2 x 77 mm with a 330 mm track, the nominal values
used here. The beams are taken counter-clockwise from
-120 deg (the URG convention).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Union

import numpy as np
from robot_calib.core import types as T

WHEEL_RADIUS = 0.154
"""Nominal effective wheel radius of BreezySLAM's rover model (m, see the module docstring)."""
TRACK_WIDTH = 0.330
"""Nominal track width (m): twice BreezySLAM's half axle length."""
LIDAR_X = 0.145
"""Laser offset ahead of base_link (m)."""
TICKS_PER_REV = 4000.0
"""Encoder counts per wheel revolution."""
FOV = math.radians(240.0)
"""URG-04LX field of view (rad)."""


def load(path: Union[str, Path], swap_wheels: bool = False) -> list:
    """
    Return time-ordered core samples: JointStateSample (wheel angles, rad) and ScanSample.

    :param path: the ``.dat`` file
    :param swap_wheels: take field 3 as the left wheel (to test the assignment)
    """
    samples = []
    names = ('left_wheel_joint', 'right_wheel_joint')
    for line in Path(path).read_text().splitlines():
        tok = line.split()
        if len(tok) < 24 + 682:
            continue
        try:
            t = int(tok[0]) * 1e-6
            left, right = float(tok[2]), float(tok[3])
            ranges = np.array([float(v) for v in tok[24:24 + 682]]) * 1e-3
        except ValueError:
            continue
        if swap_wheels:
            left, right = right, left
        pos = np.array([left, right]) * 2 * math.pi / TICKS_PER_REV
        ranges[ranges <= 0.0] = np.nan
        samples.append(T.JointStateSample(t, names, pos, np.full(2, np.nan)))
        samples.append(T.ScanSample(t + 1e-6, -FOV / 2, FOV / 681, ranges, range_min=0.02,
                                    range_max=5.6, frame_id='laser'))
    return samples
