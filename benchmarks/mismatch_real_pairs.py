# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Simulated-and-real pairs built from the real recordings in ../shared/data, for the benchmarks.

The builders know nothing of what effect a pair holds: the simulated side is
derived from a ground truth with nominal parameters, the real side is the
recording as it is.

- :func:`broad_pair`: a BROAD trial: the ideal IMU of the optical truth
  (orientation and position) vs the real IMU.
- :func:`null_pairs`: pairs that hold nothing: a real IMU split into its even
  and odd samples, and an ideal IMU against itself plus white noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from robot_calib.io.datasets import broad
from robot_calib.mismatch import protocols as P
from robot_calib.mismatch.channels import Topic

SHARED = Path(__file__).resolve().parents[2] / 'shared' / 'data'


def broad_trials() -> list:
    """Return the BROAD trial files (empty when the data is absent)."""
    folder = SHARED / 'broad'
    return broad.list_trials(folder) if folder.is_dir() else []


def broad_pair(path) -> tuple:
    """Return (trial, sim, real) of one BROAD trial file."""
    trial = broad.load_trial(path)
    sim, real = P.broad_pair(trial)
    return trial, sim, real


def _split(rec: dict, start: int) -> dict:
    return {k: Topic(tp.name, tp.msgtype, tp.t[start::2],
                     {f: x[start::2] for f, x in tp.fields.items()}) for k, tp in rec.items()}


def null_pairs(path, seed: int = 0) -> dict:
    """
    Return pairs of one BROAD trial that differ by nothing but noise.

    ``even_odd``: the real IMU's even samples as "sim", its odd samples as
    "real"; ``ideal_noise``: the ideal IMU against itself plus white noise of
    a low-cost IMU (0.005 rad/s, 0.05 m/s^2).
    """
    trial, sim, real = broad_pair(path)
    rng = np.random.default_rng(seed)
    tp = sim['/imu']
    noisy = {f: x + rng.standard_normal(x.size) * (0.005 if f.startswith('angular') else 0.05)
             for f, x in tp.fields.items()}
    plain = {'/imu': Topic(tp.name, tp.msgtype, tp.t, dict(tp.fields))}
    return {'even_odd': (_split(real, 0), _split(real, 1)),
            'ideal_noise': (plain, {'/imu': Topic(tp.name, tp.msgtype, tp.t, noisy)})}
