# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Simulated counterparts of real IMU recordings, for sim-vs-real comparison.

- :func:`imu_from_orientation`: the ideal IMU of an orientation trajectory:
  body rates from consecutive quaternions (rotation vector of
  ``q_k^-1 q_k+1`` over dt, at the mid-time, interpolated back), specific
  force from gravity only (``R^T (0, 0, g)``; no positions, so no motion
  acceleration). NaN where the orientation is lost.
- :func:`broad_pair`: BROAD trial -> (sim, real) recordings of ``/imu``.
- :func:`ferraris_pair`: the Ferraris protocol -> (sim, real): static poses
  read zero rate and +-g on the pose's axis; each rotation is a rotation of
  exactly -360 deg (the recording turns clockwise) about its axis, with the
  rate profile's shape taken from the real rate magnitude (rest level
  removed) because the protocol does not prescribe one; between sections
  nothing is compared.
"""

from __future__ import annotations

import numpy as np

from robot_calib.core.constants import GRAVITY
from robot_calib.mismatch.channels import IMU_FIELDS, IMU_TYPE, Topic
from robot_calib.mismatch.ideal import quat_products


def imu_from_orientation(t: np.ndarray, q: np.ndarray, g: float = GRAVITY,
                         half: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """
    Return (gyro (N, 3) rad/s, specific force (N, 3) m/s^2) of sensor-to-world quaternions.

    :param t: times (s)
    :param q: (N, 4) quaternions [w x y z] of the sensor frame w.r.t. ENU
    :param g: gravity (m/s^2)
    :param half: the rate is the rotation between samples k - half and k + half
        over their time difference (a central difference that keeps optical
        noise from dominating the simulated gyro)
    """
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    qc = q * np.array([1.0, -1.0, -1.0, -1.0])
    h = max(1, int(half))
    dq = quat_products(qc[:-2 * h], q[2 * h:])
    dq *= np.sign(dq[:, :1] + 1e-300)
    vn = np.linalg.norm(dq[:, 1:], axis=1)
    ang = 2.0 * np.arctan2(vn, dq[:, 0])
    with np.errstate(invalid='ignore', divide='ignore'):
        axis = dq[:, 1:] / np.where(vn > 0, vn, 1.0)[:, None]
    rv = axis * ang[:, None]
    dt = t[2 * h:] - t[:-2 * h]
    w_mid = rv / dt[:, None]
    tm = 0.5 * (t[:-2 * h] + t[2 * h:])
    gyro = np.full((t.size, 3), np.nan)
    ok = np.all(np.isfinite(w_mid), axis=1)
    if ok.sum() > 2:
        for k in range(3):
            gyro[:, k] = np.interp(t, tm[ok], w_mid[ok, k])
        # NaN where the truth is lost on either side
        lost = ~np.all(np.isfinite(q), axis=1)
        near = np.convolve(lost.astype(float), np.ones(2 * h + 1), mode='same') > 0
        gyro[near] = np.nan
    w, x, y, z = q.T
    # third row of R (sensor->world) gives the world z axis in sensor coordinates
    acc = g * np.column_stack((2 * (x * z - w * y), 2 * (y * z + w * x),
                               1 - 2 * (x * x + y * y)))
    return gyro, acc


def _rec(t: np.ndarray, gyro: np.ndarray, acc: np.ndarray, kernels: dict = None) -> dict:
    fields = {f: (gyro if i < 3 else acc)[:, i % 3].astype(float)
              for i, f in enumerate(IMU_FIELDS)}
    per_field = {}
    for f in IMU_FIELDS:
        k = (kernels or {}).get('gyro' if f.startswith('angular') else 'accel')
        if k is not None:
            per_field[f] = k
    return {'/imu': Topic('/imu', IMU_TYPE, np.asarray(t, float), fields, per_field)}


def broad_pair(trial, pos: np.ndarray = None) -> tuple[dict, dict]:
    """
    Return (sim, real) recordings of a BROAD trial.

    The simulated IMU is the ideal one of the optical truth
    (:func:`robot_calib.mismatch.ideal.ideal_imu`: rates from the
    orientations, specific force from the positions when given, each with
    the smoothing kernel it went through); the real one is the trial's IMU.
    """
    from robot_calib.mismatch.ideal import ideal_imu
    ideal = ideal_imu(trial.t, trial.gt_quat, trial.pos if pos is None else pos)
    return (_rec(trial.t, ideal['gyro'], ideal['accel'], ideal['kernels']),
            _rec(trial.t, trial.gyr, trial.acc))


POSE_AXIS = {'x_p': (0, 1.0), 'x_a': (0, -1.0), 'y_p': (1, 1.0), 'y_a': (1, -1.0),
             'z_p': (2, 1.0), 'z_a': (2, -1.0)}
ROT_AXIS = {'x_rot': 0, 'y_rot': 1, 'z_rot': 2}


def ferraris_pair(rec, turn: float = -2.0 * np.pi) -> tuple[dict, dict]:
    """
    Return (sim, real) recordings of the Ferraris protocol (see module doc).

    :param rec: a :class:`robot_calib.io.datasets.ferraris.Ferraris` recording
    :param turn: the protocol's rotation angle per rotation section (rad)
    """
    idx = []
    sim_g, sim_a = [], []
    rest = np.concatenate([np.arange(a, b) for k, (a, b) in rec.sections.items()
                           if k in POSE_AXIS])
    b_rest = np.median(rec.gyro[rest], axis=0)
    for name, (a, b) in sorted(rec.sections.items(), key=lambda kv: kv[1][0]):
        n = b - a
        g = np.zeros((n, 3))
        acc = np.full((n, 3), np.nan)
        if name in POSE_AXIS:
            ax, sgn = POSE_AXIS[name]
            acc = np.zeros((n, 3))
            acc[:, ax] = sgn * GRAVITY
        elif name in ROT_AXIS:
            ax = ROT_AXIS[name]
            mag = np.linalg.norm(rec.gyro[a:b] - b_rest, axis=1)
            dt = np.gradient(rec.t[a:b])
            g[:, ax] = mag * (turn / float(np.sum(mag * dt)))
        else:
            continue
        idx.append(np.arange(a, b))
        sim_g.append(g)
        sim_a.append(acc)
    ii = np.concatenate(idx)
    t = rec.t[ii]
    return _rec(t, np.vstack(sim_g), np.vstack(sim_a)), _rec(t, rec.gyro[ii], rec.accel[ii])
