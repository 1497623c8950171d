# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loader and metric for BROAD (Berlin Robust Orientation Estimation Assessment Dataset).

Laidig, Caruso, Cereatti, Seel, *Data* 6(7):72, 2021 (CC BY 4.0). Each trial
here is an ``.npz`` with ``t`` (s), ``fs`` (Hz), ``gyr`` (rad/s, the gyro bias is
left in on purpose), ``acc`` (m/s^2), ``gt_quat`` (optical ground truth of the
IMU frame w.r.t. ENU, ``[w x y z]``, NaN where the markers were lost) and
``movement`` (the samples the benchmark scores) and, where the file has it,
``pos`` (optical position of the marker body, m, NaN where lost).

The metric is the dataset's 6D inclination error:
``q_err = q_est * inv(q_gt)`` (both sensor-to-earth), inclination error
``2 acos(sqrt(w^2 + z^2))``, RMSE over the ``movement`` samples, NaN skipped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np


@dataclass
class BroadTrial:
    """One BROAD trial: name, times (s), rates (rad/s), specific force (m/s^2), truth."""

    name: str
    t: np.ndarray
    fs: float
    gyr: np.ndarray
    acc: np.ndarray
    gt_quat: np.ndarray
    movement: np.ndarray
    pos: Optional[np.ndarray] = None

    def true_tilt(self) -> np.ndarray:
        """Return the true tilt (rad) of the IMU z axis from up; NaN where the truth is lost."""
        x = self.gt_quat[:, 1]
        y = self.gt_quat[:, 2]
        return np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y), -1.0, 1.0))


def load_trial(path: Union[str, Path]) -> BroadTrial:
    """Load one ``.npz`` trial."""
    path = Path(path)
    with np.load(path) as d:
        fs = float(d['fs'])
        gyr = np.asarray(d['gyr'], dtype=float)
        t = np.asarray(d['t'], dtype=float) if 't' in d.files else np.arange(len(gyr)) / fs
        pos = np.asarray(d['pos'], dtype=float) if 'pos' in d.files else None
        return BroadTrial(path.stem, t, fs, gyr, np.asarray(d['acc'], dtype=float),
                          np.asarray(d['gt_quat'], dtype=float),
                          np.asarray(d['movement'], dtype=bool), pos)


def list_trials(folder: Union[str, Path]) -> list[Path]:
    """Return the trial files of a BROAD folder, sorted by name."""
    return sorted(Path(folder).glob('*.npz'))


def inclination_error(q_est: np.ndarray, q_gt: np.ndarray) -> np.ndarray:
    """Return the inclination error (rad) per sample of two (N, 4) sensor-to-earth quaternions."""
    w1, x1, y1, z1 = np.asarray(q_est, dtype=float).T
    w2, x2, y2, z2 = np.asarray(q_gt, dtype=float).T
    x2, y2, z2 = -x2, -y2, -z2
    w = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    z = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    return 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))


def inclination_rmse(q_est: np.ndarray, trial: BroadTrial) -> float:
    """Return the BROAD 6D inclination RMSE (rad) over the ``movement`` samples, NaN skipped."""
    e = inclination_error(q_est, trial.gt_quat)
    m = trial.movement & np.isfinite(e)
    if not m.any():
        return float('nan')
    return float(np.sqrt(np.mean(e[m] ** 2)))
