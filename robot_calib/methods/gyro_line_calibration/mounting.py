# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The IMU and laser mountings of ``gyro_line_calibration``, from parameters or the tree."""

from __future__ import annotations

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.frames import (find_mounting, planar_pose, rotation_matrix, SENSOR_WORDS,
                                     upside_down)
from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix


class SensorMountings:
    """
    Mixin: ``_imu_rot`` (3x3) and ``laser_pose`` (x m, y m, yaw rad) in ``base_frame``.

    The host sets ``params``, ``_mountings`` (a :class:`~robot_calib.core.frames.StaticTree`),
    ``_imu_frame``, ``_laser_frame`` and ``input_notes``.
    """

    def _param_mountings(self) -> None:
        """Take the IMU rotation and the laser pose from the parameters."""
        p = self.params
        r, pi_, y = (list(p.imu_rpy) + [0.0, 0.0, 0.0])[:3]
        self._imu_rot = quat_to_matrix(quat_from_rpy(r, pi_, y))
        lp = (list(p.laser_pose) + [0.0, 0.0, 0.0])[:3]
        self.laser_pose = np.array(lp, dtype=float)
        self._laser_upside_down = False

    def set_mounting(self, transform: T.StaticTransform) -> None:
        """
        Take a static transform; the IMU's and the laser's mountings in base_frame follow.

        Each sensor's frame (from its first sample) is looked up by the rule of
        :func:`robot_calib.core.frames.find_mounting`; with no mounting known the
        ``imu_rpy`` and ``laser_pose`` parameters are used, and said.
        """
        self._mountings.add(transform)
        self._apply_mountings()

    def _apply_mountings(self) -> None:
        """Set the IMU rotation and the laser pose of the frames seen from the tree."""
        self._param_mountings()
        tree, base = self._mountings, self.params.base_frame
        if self._imu_frame is None or self._laser_frame is None:
            # before a sensor's own frame is known: the tree's frames named like it
            for frame in tree.leaves():
                name = frame.lower()
                imu = 'imu' in name
                if not (imu or any(k in name for k in SENSOR_WORDS['lidar'])):
                    continue
                mounting = tree.mounting(frame, base)
                if mounting is None:
                    continue
                if imu and self._imu_frame is None:
                    self._imu_rot = rotation_matrix(mounting)
                elif not imu and self._laser_frame is None:
                    self.laser_pose = np.array(planar_pose(mounting))
                    self._laser_upside_down = upside_down(mounting)
        if self._imu_frame is not None:
            found = find_mounting(tree, self._imu_frame, base, 'imu', 'the imu_rpy parameter '
                                  f'used ({list(self.params.imu_rpy)} rad)')
            self.input_notes.say('imu', found.note)
            if found.transform is not None:
                self._imu_rot = rotation_matrix(found.transform)
        if self._laser_frame is not None:
            found = find_mounting(tree, self._laser_frame, base, 'lidar', 'the laser_pose '
                                  f'parameter used ({list(self.params.laser_pose)} m, m, rad)')
            self.input_notes.say('lidar', found.note)
            if found.transform is not None:
                self.laser_pose = np.array(planar_pose(found.transform))
                self._laser_upside_down = upside_down(found.transform)
