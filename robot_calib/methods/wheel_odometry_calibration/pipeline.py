# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pipeline of ``wheel_odometry_calibration``: wheel data + scans in, estimates out.

Inputs: ``odom`` (nav_msgs/Odometry) or ``joint_states`` (sensor_msgs/JointState;
preferred once the named joints appear), ``scan`` (sensor_msgs/LaserScan) and
``/tf_static`` (a ``base_frame`` -> scan frame transform gives the nominal
lidar pose). Output: ``wheel_calibration/status`` (diagnostic_msgs/
DiagnosticArray) every ``update_period`` seconds of data time and at the end,
one status named ``wheel_odometry_calibration`` whose key-values are the
result keys of the contract (``drive_type``, the estimates and their ``_std``
twins, ``segments_used``, ``verdict``) plus progress counters; level OK when
converged, WARN while the drive still lacks something. The artifact
``wheel_calibration.yaml`` is the contract's flat YAML result.
"""

from __future__ import annotations

import math
from typing import Any, Optional

from robot_calib.core import types as T
from robot_calib.core.geometry import yaw_from_quat
from robot_calib.methods.wheel_odometry_calibration.estimator import (CalibResult,
                                                                      WheelCalibParams,
                                                                      WheelCalibrator)
from robot_calib.pipelines.base import InputSpec, Output, OutputSpec, Pipeline

STATUS_NAME = 'wheel_odometry_calibration'


class WheelCalibrationPipeline(Pipeline):
    """Calibrate wheel odometry (and the lidar pose) against scan matching."""

    name = 'wheel_odometry_calibration'
    params_type = WheelCalibParams
    inputs = (InputSpec('odom', 'odom', 'odom', optional=True),
              InputSpec('joint_states', 'joint_states', 'joint_states', optional=True),
              InputSpec('scan', 'scan', 'scan'),
              InputSpec('tf_static', '/tf_static', 'tf_static', optional=True))
    outputs = (OutputSpec('status', 'wheel_calibration/status', 'diagnostics'),)
    max_gap = 1.0
    artifact_names = ('wheel_calibration.yaml',)

    def __init__(self, params: Optional[WheelCalibParams] = None, log: Any = None,
                 matcher: Any = None, prepare: Any = None):
        """Create the calibrator; ``matcher``/``prepare`` replace the registration (tests)."""
        super().__init__(params, log)
        self.calib = WheelCalibrator(self.params, matcher=matcher, prepare=prepare)
        self.result: Optional[CalibResult] = None
        self._last_update: Optional[float] = None
        self._latest_t = math.nan
        self._latest_stamp = -1
        self._sensor_frame: Optional[str] = None
        self._n_solved = 0
        self._told_problem = ''

    def on_static_transform(self, transform: T.StaticTransform) -> None:
        """Use a base_frame -> scan frame transform as the nominal lidar pose."""
        if self._sensor_frame is not None:
            self._apply_tf(self._sensor_frame)

    def _apply_tf(self, frame: str) -> None:
        tf = self.static_transforms.get((self.params.base_frame, frame))
        if tf is None or self.calib.segments:
            return
        yaw = yaw_from_quat(tf.rotation)
        self.calib.set_sensor_pose(float(tf.translation[0]), float(tf.translation[1]), yaw)
        self.log('info', f'lidar pose from /tf_static: x {tf.translation[0]:.3f} m, '
                 f'y {tf.translation[1]:.3f} m, yaw {yaw:.4f} rad')

    def handle(self, key: str, sample: Any) -> list[Output]:
        """Feed wheel data and scans; publish the status every update_period (data time)."""
        if key == 'joint_states':
            decided = self.calib.drive_source
            used = self.calib.add_joint_state(sample)
            if self.calib.drive_source != decided:
                self.log('info', f'drive type {self.calib.drive} told by the '
                         f'{self.calib.drive_source} ({", ".join(self.calib.drive_joints)})')
            if self.calib.drive_problem and self.calib.drive_problem != self._told_problem:
                self._told_problem = self.calib.drive_problem
                self.log('warn', self.calib.drive_problem)
            if not used:
                return self.reject(key, 'missing_joints')
        elif key == 'odom':
            if not self.calib.add_odom(sample):
                return self.reject(key, 'joint_states_preferred')
        elif key == 'scan':
            if self._sensor_frame is None:
                self._sensor_frame = sample.frame_id
                self._apply_tf(sample.frame_id)
            self.calib.add_scan(sample)
        self._latest_t, self._latest_stamp = sample.t, T.stamp_of(sample.t, sample.stamp_ns)
        if self._last_update is None:
            self._last_update = sample.t
        if sample.t - self._last_update >= self.params.update_period:
            self._last_update = sample.t
            # re-solve when the data grew by 10 % (or 10 segments): O(log n) solves per drive
            n = len(self.calib.segments) + self.calib.counts['stages']
            if self.result is None or n >= max(self._n_solved * 1.1, self._n_solved + 10):
                self._n_solved = n
                self.result = self.calib.solve()
            return [('status', self._status(final=False))]
        return []

    def finish(self) -> list[Output]:
        """Solve once more with all data; publish the final status."""
        self.result = self.calib.solve(final=True)
        if not math.isfinite(self._latest_t):
            return []
        return [('status', self._status(final=True))]

    def _status(self, final: bool) -> T.DiagnosticSample:
        res = self.result
        values = []
        if res is not None:
            for k, v in res.to_dict().items():
                values.append((k, f'{v:.9g}' if isinstance(v, float) else str(v)))
        c = self.calib.counts
        values += [('segments', str(len(self.calib.segments))),
                   ('scans', str(c['scans'])), ('match_failed', str(c['match_failed'])),
                   ('seed_stages', str(c['stages'])), ('final', str(final).lower())]
        if self.calib.seed is not None:
            values.append(('seed_counter', str(self.calib.seed.counter)))
        if res is None:
            level, msg = 1, 'collecting the calibration drive'
        elif res.converged:
            level, msg = 0, 'converged'
        else:
            level, msg = 1, res.verdict
        status = T.DiagnosticStatus(STATUS_NAME, level, msg, '', tuple(values))
        return T.DiagnosticSample(self._latest_t, (status,), self._latest_stamp)

    def method_summary(self) -> dict[str, Any]:
        """Return the result, the drive content and the front end's counters."""
        res = self.result or self.calib.solve()
        out = {'result': res.to_dict(), 'counts': dict(self.calib.counts),
               'drive_type_source': self.calib.drive_source}
        for k in ('content', 'outliers', 'sigma', 'seed_stages_needed'):
            if k in res.details:
                out[k] = res.details[k]
        return out

    def artifacts(self) -> dict[str, str]:
        """Return ``{'wheel_calibration.yaml': text}`` (the contract's flat YAML)."""
        res = self.result or self.calib.solve(final=True)
        return {'wheel_calibration.yaml': res.to_yaml()}


PIPELINE = WheelCalibrationPipeline
