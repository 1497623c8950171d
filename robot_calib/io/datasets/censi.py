# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loader of the Censi et al. (T-RO 2013) calibration tuples and the authors' results.

Each line of a ``*.tuple`` file is a JSON object ``{"T": s, "phi_l": ..., "phi_r":
..., "sm": [x, y, theta]}``: ``T`` is the interval (s), ``phi_l`` and
``phi_r`` are the wheel **angular velocities** (rad/s, constant over the
interval; the wheel rotation is ``T * phi``, which is how the authors' solver
uses them), and ``sm`` is the laser's own motion from scan matching (m, m,
rad). ``*_results.json`` holds the authors' estimate: ``axle`` (m), ``l_diam``
and ``r_diam`` (wheel diameters, m), ``l_x``, ``l_y`` (m), ``l_theta`` (rad)
and a 6x6 ``covariance`` (taken here as the order ``l_diam, r_diam, axle,
l_x, l_y, l_theta``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional, Union

import numpy as np

from robot_calib.core.kinematics import Segment

FILES = ('l90', 'l90_0', 'l90_1', 'l90_2', 'lmov', 'lmov_0', 'lmov_1', 'lmov_2',
         'lstraight', 'lstraight_0', 'lstraight_1', 'lstraight_2')


def load_tuples(path: Union[str, Path]) -> list[Segment]:
    """
    Read a ``*.tuple`` file into differential-drive segments (one step each).

    Lines that are not valid tuples or hold non-finite numbers are skipped.

    :param path: the tuple file
    """
    segments = []
    t = 0.0
    for line in Path(path).read_text().splitlines():
        line = line.strip()
        if not line:
            continue
        try:
            d = json.loads(line)
            dt = float(d['T'])
            steps = np.array([[dt * float(d['phi_l']), dt * float(d['phi_r'])]])
            sm = np.asarray(d['sm'], dtype=float).reshape(3)
        except (ValueError, KeyError, TypeError):
            continue
        if not (np.isfinite(dt) and np.all(np.isfinite(steps)) and np.all(np.isfinite(sm))):
            continue
        segments.append(Segment(t, t + dt, steps, sm))
        t += dt
    return segments


def load_results(path: Union[str, Path]) -> Optional[dict]:
    """
    Read an authors' ``*_results.json`` into SI names, with their standard deviations.

    Returns ``left_wheel_radius``, ``right_wheel_radius``, ``track_width``,
    ``lidar_x``, ``lidar_y``, ``lidar_yaw`` and the ``_std`` twins (radius std
    is half the diameter std), or None when the file is missing.

    :param path: the results file
    """
    path = Path(path)
    if not path.is_file():
        return None
    d = json.loads(path.read_text())
    cov = np.asarray(d.get('covariance', np.full((6, 6), np.nan)), dtype=float)
    std = np.sqrt(np.abs(np.diag(cov))) if cov.shape == (6, 6) else np.full(6, np.nan)
    return {
        'left_wheel_radius': d['l_diam'] / 2.0, 'right_wheel_radius': d['r_diam'] / 2.0,
        'track_width': d['axle'], 'lidar_x': d['l_x'], 'lidar_y': d['l_y'],
        'lidar_yaw': d['l_theta'],
        'left_wheel_radius_std': std[0] / 2.0, 'right_wheel_radius_std': std[1] / 2.0,
        'track_width_std': std[2], 'lidar_x_std': std[3], 'lidar_y_std': std[4],
        'lidar_yaw_std': std[5],
    }
