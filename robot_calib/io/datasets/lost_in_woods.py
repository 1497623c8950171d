# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loader of UTIAS 'Lost in the Woods' (Barfoot, state estimation course data, 2009).

``dataset2.mat`` (MATLAB, read with :func:`scipy.io.loadmat`): ``t`` (s, 10 Hz),
``v`` (m/s) and ``om`` (rad/s) the **measured** wheel odometry of the robot,
``x_true``, ``y_true``, ``th_true`` (m, m, rad) its Vicon ground truth and
``true_valid`` (1 where the truth is valid), ``v_var``, ``om_var`` the odometry
variances ((m/s)^2, (rad/s)^2). The laser data (``r``, ``b``, ``l``, ``d``) is
not loaded.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Union

import numpy as np


@dataclass
class WoodsRun:
    """The run: times (s), measured odometry (m/s, rad/s), Vicon poses (m, m, rad), validity."""

    t: np.ndarray
    v: np.ndarray
    om: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    valid: np.ndarray
    v_var: float = float('nan')
    om_var: float = float('nan')


def load(path: Union[str, Path]) -> WoodsRun:
    """
    Load ``dataset2.mat``; invalid truth samples read NaN in x, y and yaw.

    :param path: the ``.mat`` file
    """
    from scipy.io import loadmat
    m = loadmat(str(path))

    def col(key: str) -> np.ndarray:
        if key not in m:
            raise ValueError(f'{path}: no variable {key!r}')
        return np.asarray(m[key], float).ravel()

    t, v, om = col('t'), col('v'), col('om')
    x, y, yaw = col('x_true'), col('y_true'), col('th_true')
    valid = col('true_valid').astype(bool) if 'true_valid' in m else np.ones(t.size, bool)
    n = t.size
    if not all(a.size == n for a in (v, om, x, y, yaw, valid)):
        raise ValueError(f'{path}: the time series differ in length')
    valid &= np.isfinite(x) & np.isfinite(y) & np.isfinite(yaw)
    x, y, yaw = (np.where(valid, a, np.nan) for a in (x, y, yaw))

    def scalar(key: str) -> float:
        return float(np.asarray(m[key], float).ravel()[0]) if key in m else float('nan')

    return WoodsRun(t, v, om, x, y, yaw, valid, scalar('v_var'), scalar('om_var'))
