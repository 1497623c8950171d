# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loader for the Ferraris-protocol IMU recording (``shared/data/imucal/``).

``ferraris.csv`` holds one row per sample (``n_samples, gyr_x, gyr_y, gyr_z,
acc_x, acc_y, acc_z``; gyro in deg/s, accelerometer in m/s^2) at 102.4 Hz;
``ferraris_sections.json`` gives the sample ranges of the six static poses
(``x_p``: x axis up, ``x_a``: x axis down, likewise y and z) and of the three
rotations of exactly 360 deg about x, y and z (``x_rot`` ...).
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import os
from pathlib import Path

import numpy as np

RATE = 102.4  # Hz


@dataclass
class Ferraris:
    """The recording: t (s), gyro (N, 3) rad/s, accel (N, 3) m/s^2, sections {name: (i0, i1)}."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    sections: dict


def load(folder: os.PathLike | str) -> Ferraris:
    """
    Load ``ferraris.csv`` and ``ferraris_sections.json`` from ``folder``.

    :param folder: the ``imucal`` folder
    :raises ValueError: when a file is missing or malformed (one-line message)
    """
    folder = Path(folder)
    csv, js = folder / 'ferraris.csv', folder / 'ferraris_sections.json'
    if not csv.is_file() or not js.is_file():
        raise ValueError(f'{folder}: ferraris.csv and ferraris_sections.json are required')
    try:
        data = np.loadtxt(csv, delimiter=',', skiprows=1)
        sec = json.loads(js.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f'{folder}: cannot read the Ferraris recording: {exc}') from None
    if data.ndim != 2 or data.shape[1] < 7:
        raise ValueError(f'{csv}: expected 7 columns')
    t = data[:, 0] / RATE
    sections = {k: (int(v['start']), int(v['end'])) for k, v in sec.items()}
    return Ferraris(t, np.radians(data[:, 1:4]), data[:, 4:7].copy(), sections)
