# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The IMU front end of both fusion filters: acceleration units and mounting rotation.

The mounting (IMU -> ``base_link`` rotation) comes from the ``imu_rpy``
parameter, from ``/tf_static`` (:class:`robot_calib.core.frames.StaticTree` through the static
transforms, each turned into a rotation by :mod:`robot_calib.core.frames`) or,
failing both, from the gravity direction at start (then only the up axis is
known and the accelerometer is not used). The units (m/s^2 or g) are a
parameter or told from the median magnitude of the first 10 samples by the
rule of :mod:`robot_calib.core.imu_units` (the one tilt detection uses).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from robot_calib.core import types as T
from robot_calib.core.constants import GRAVITY
from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix
from robot_calib.core.imu_units import accel_units_of, UNITS_SAMPLES
from robot_calib.methods.odometry_fusion.params import FusionParams

G = GRAVITY
"""Standard gravity (m/s^2)."""


class ImuFrontEnd:
    """IMU units detection and mounting rotation shared by both filters."""

    def __init__(self, params: FusionParams):
        """Start with the units and the mounting given by ``params`` (else pending)."""
        self.p = params
        self.rot: Optional[np.ndarray] = None
        self.rot_source = 'none'
        self.forward_known = False
        self.accel_scale: Optional[float] = {'mps2': 1.0, 'g': G}.get(params.accel_units)
        self.units_source = params.accel_units if self.accel_scale else 'pending'
        self._norms: list[float] = []
        self._acc_sum = np.zeros(3)
        self._n_up = 0
        self.warnings: list[str] = []
        self.full_vectors = False
        """Whether :meth:`convert` also keeps the whole gyro and force in base_link."""
        self.gyro = (0.0, 0.0, 0.0)
        """The last gyro reading in base_link (rad/s), with ``full_vectors``."""
        self.force = (0.0, 0.0, 0.0)
        """The last specific force in base_link (m/s^2), with ``full_vectors``."""
        rpy = list(params.imu_rpy) + [0.0] * 3
        if params.imu_extrinsic == 'param' or (params.imu_extrinsic == 'auto'
                                               and any(abs(v) > 0 for v in rpy[:3])):
            self.set_rotation(quat_to_matrix(quat_from_rpy(*rpy[:3])), 'param')

    def set_rotation(self, rot: np.ndarray, source: str) -> None:
        """Use ``rot`` (3x3, IMU -> base) from ``source``."""
        self.rot = np.asarray(rot, dtype=float)
        self._r0 = [float(v) for v in self.rot[0]]
        self._r1 = [float(v) for v in self.rot[1]]
        self._r2 = [float(v) for v in self.rot[2]]
        self.rot_source = source
        self.forward_known = source in ('param', 'tf')

    def convert(self, s: T.ImuSample, g: tuple, acc: tuple
                ) -> Optional[tuple[float, float, bool]]:
        """
        Return (gyro z rad/s, forward specific force m/s^2, accel usable) in base_link.

        None while the units or the gravity axis are still being determined.
        """
        if self.accel_scale is None:
            self._norms.append(math.sqrt(acc[0] ** 2 + acc[1] ** 2 + acc[2] ** 2))
            if len(self._norms) >= UNITS_SAMPLES:
                med = float(np.median(self._norms))
                units = accel_units_of(med)
                if units == 'g':
                    self.accel_scale, self.units_source = G, 'detected_g'
                    self.warnings.append(f'IMU acceleration is in g (|a| median {med:.3f}): '
                                         'converting to m/s^2')
                elif units == 'mps2':
                    self.accel_scale, self.units_source = 1.0, 'detected_mps2'
                else:
                    self.accel_scale, self.units_source = 1.0, 'unknown'
                    self.warnings.append(f'IMU |a| median {med:.3f} is neither 1 g nor 9.81 '
                                         'm/s^2: acceleration ignored')
        if self.rot is None and self.p.imu_extrinsic in ('auto', 'gravity', 'tf'):
            if self.p.imu_extrinsic == 'tf':
                return None
            self._acc_sum += np.asarray(acc, dtype=float)
            self._n_up += 1
            if self._n_up < 10 or self.accel_scale is None:
                return None
            mean = self._acc_sum / self._n_up
            if np.linalg.norm(mean) * self.accel_scale < 0.5 * G:
                self.warnings.append('no gravity in the IMU acceleration: taking the IMU z '
                                     'axis as up (set imu_rpy or publish /tf_static)')
                self.set_rotation(np.eye(3), 'gravity')
            else:
                self.set_rotation(rotation_to_up(mean / np.linalg.norm(mean)), 'gravity')
        if self.rot is None or self.accel_scale is None:
            return None
        r2, r0 = self._r2, self._r0
        gz = r2[0] * g[0] + r2[1] * g[1] + r2[2] * g[2]
        use_acc = self.forward_known and self.units_source != 'unknown'
        ax = (r0[0] * acc[0] + r0[1] * acc[1] + r0[2] * acc[2]) * self.accel_scale \
            if use_acc else 0.0
        if use_acc and self.full_vectors:
            r1, k = self._r1, self.accel_scale
            self.gyro = (r0[0] * g[0] + r0[1] * g[1] + r0[2] * g[2],
                         r1[0] * g[0] + r1[1] * g[1] + r1[2] * g[2], gz)
            self.force = (ax, (r1[0] * acc[0] + r1[1] * acc[1] + r1[2] * acc[2]) * k,
                          (r2[0] * acc[0] + r2[1] * acc[1] + r2[2] * acc[2]) * k)
        return gz, ax, use_acc


def rotation_to_up(up: np.ndarray) -> np.ndarray:
    """Return a rotation (IMU -> level frame) mapping the unit vector ``up`` onto +z."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(up, z)
    c = float(up @ z)
    s = float(np.linalg.norm(v))
    if s < 1e-9:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * ((1 - c) / (s * s))
