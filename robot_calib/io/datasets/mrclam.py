# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loader of the UTIAS Multi-Robot Cooperative Localization and Mapping data set (MR.CLAM).

Leung, Halpern, Barfoot, Liu, *IJRR* 30(8), 2011. One robot's run is two text
files with ``#`` comment lines:

- ``RobotN_Odometry.dat``: time (s), forward velocity (m/s), angular velocity
  (rad/s) at about 70 Hz. These are the velocity **commands** sent to the
  iRobot Create (piecewise constant), not measured motion.
- ``RobotN_Groundtruth.dat``: time (s), x (m), y (m), heading (rad) from Vicon
  motion capture at about 60 Hz, with gaps (up to about 2 s) where the markers
  were lost.

Times are kept as recorded (Unix seconds); repeated or decreasing stamps are
dropped so every array is strictly increasing in time.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Union

import numpy as np


@dataclass
class MrclamRun:
    """One robot's run: commands (s, m/s, rad/s) and Vicon poses (s, m, m, rad)."""

    name: str
    t_cmd: np.ndarray
    v_cmd: np.ndarray
    w_cmd: np.ndarray
    t_gt: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray

    def gaps(self, max_step: float = 0.1) -> np.ndarray:
        """Return ``(k, 2)`` start and end times (s) of the ground truth's gaps over max_step."""
        dt = np.diff(self.t_gt)
        idx = np.flatnonzero(dt > max_step)
        return np.column_stack((self.t_gt[idx], self.t_gt[idx + 1]))


def _table(path: Union[str, Path], cols: int) -> np.ndarray:
    """Read a whitespace table with ``#`` comments; rows must have ``cols`` numbers."""
    a = np.loadtxt(path, comments='#', ndmin=2)
    if a.shape[1] != cols:
        raise ValueError(f'{path}: expected {cols} columns, got {a.shape[1]}')
    a = a[np.all(np.isfinite(a), axis=1)]
    order = np.argsort(a[:, 0], kind='stable')
    a = a[order]
    keep = np.concatenate(([True], np.diff(a[:, 0]) > 0)) if len(a) else np.zeros(0, bool)
    return a[keep]


def load(folder: Union[str, Path], robot: int = 1) -> MrclamRun:
    """
    Load ``Robot{robot}_Odometry.dat`` and ``Robot{robot}_Groundtruth.dat`` from ``folder``.

    :param folder: the folder holding the run's files
    :param robot: the robot number (1..5)
    """
    folder = Path(folder)
    odo = _table(folder / f'Robot{robot}_Odometry.dat', 3)
    gt = _table(folder / f'Robot{robot}_Groundtruth.dat', 4)
    return MrclamRun(f'Robot{robot}', odo[:, 0], odo[:, 1], odo[:, 2],
                     gt[:, 0], gt[:, 1], gt[:, 2], gt[:, 3])


def list_robots(folder: Union[str, Path]) -> list[int]:
    """Return the robot numbers that have both files in ``folder`` (empty when absent)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(n for n in range(1, 10)
                  if (folder / f'Robot{n}_Odometry.dat').is_file()
                  and (folder / f'Robot{n}_Groundtruth.dat').is_file())
