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
converged, WARN while the drive still lacks something. The same status goes
to ``/diagnostics`` (where monitors and rqt_robot_monitor look). The artifact
``wheel_calibration.yaml`` is the contract's flat YAML result.
"""

from __future__ import annotations

import math
from typing import Any, Optional

from robot_calib.core import types as T
from robot_calib.methods.wheel_odometry_calibration.common import WheelCalibResult
from robot_calib.methods.wheel_odometry_calibration.params import WheelCalibParams
from robot_calib.methods.wheel_odometry_calibration.variants import make_estimator
from robot_calib.pipelines import stack_export as SE
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
    outputs = (OutputSpec('status', 'wheel_calibration/status', 'diagnostics'),
               OutputSpec('diagnostics', '/diagnostics', 'diagnostics'))
    max_gap = 1.0
    artifact_names = ('wheel_calibration.yaml',)
    refusable = ('odom',)

    def __init__(self, params: Optional[WheelCalibParams] = None, log: Any = None,
                 matcher: Any = None, prepare: Any = None):
        """Create the estimator of ``mode``; ``matcher``/``prepare`` replace the registration."""
        super().__init__(params, log)
        self.estimator = make_estimator(self.params, matcher=matcher, prepare=prepare)
        self.result: Optional[WheelCalibResult] = None
        self._latest_t = math.nan
        self._latest_stamp = -1

    def input_notes(self) -> Any:
        """Return the estimator's standing warnings about its inputs."""
        return self.estimator.input_notes

    def on_static_transform(self, transform: T.StaticTransform) -> None:
        """Forward a static transform (base_frame -> scan frame: the nominal lidar pose)."""
        self.estimator.set_mounting(transform)

    def refusal(self, key: str) -> str:
        """Turn odometry away unread while joint states drive the wheel odometry."""
        return self.estimator.odometry_refusal() if key == 'odom' else ''

    def handle(self, key: str, sample: Any) -> list[Output]:
        """Feed wheel data and scans; publish the status the estimator returns."""
        out = self.estimator.update(sample)
        if out is not None:
            for level, message in out.notes:
                self.log(level, message)
            if out.rejected:
                return self.reject(key, out.rejected)
        self._latest_t, self._latest_stamp = sample.t, T.stamp_of(sample.t, sample.stamp_ns)
        if out is not None and out.status is not None:
            self.result = out.status
            return self._both(self._status(out.status))
        return []

    def finish(self) -> list[Output]:
        """Solve once more with all data; publish the final status."""
        self.result = self.estimator.result()
        if not math.isfinite(self._latest_t):
            return []
        caveat = self.odometry_caveat()
        if caveat:
            self.log('warn', caveat)
        return self._both(self._status(self.result))

    def wheel_source(self) -> str:
        """Return where the wheel turns came from: 'joint_states', 'odometry' or 'none'."""
        front = self.estimator.front
        if front.uses_joints:
            return 'joint_states'
        return 'odometry' if front.counts['wheel_samples'] else 'none'

    def odometry_caveat(self) -> str:
        """
        Return what the result is relative to when wheel turns came from odometry, else ''.

        Odometry is turned back into wheel turns with the nominal geometry of
        the parameters, so the estimates scale with it: they are the robot's
        only if its odometry was computed with those same values.
        """
        front = self.estimator.front
        if self.wheel_source() != 'odometry':
            return ''
        n = self.params.nominal()
        used = ', '.join(f'{k} {n[k]:g}' for k in
                         (('left_wheel_radius', 'right_wheel_radius', 'track_width')
                          if front.drive == 'differential' else
                          ('wheel_radius', 'wheel_base', 'steering_offset', 'steering_scale')))
        checked = '' if front.drive_source != 'configured' else \
            f'; the drive type ({front.drive}) is as configured, which odometry cannot check'
        return ('wheel turns from odometry (no joint states): the estimates are relative to '
                f"the nominal geometry given ({used}); they are the robot's only if its "
                f'odometry uses those same values{checked}')

    @staticmethod
    def _both(status: T.DiagnosticSample) -> list[Output]:
        """Publish a status on the method's own topic and on ``/diagnostics``."""
        return [('status', status), ('diagnostics', status)]

    def _status(self, res: WheelCalibResult) -> T.DiagnosticSample:
        values = [(k, f'{v:.9g}' if isinstance(v, float) else str(v))
                  for k, v in res.to_dict().items()]
        c = res.counts
        values += [('segments', str(res.segments)),
                   ('scans', str(c['scans'])), ('match_failed', str(c['match_failed'])),
                   ('seed_stages', str(c['stages'])), ('final', str(res.final).lower())]
        if res.seed_counter is not None:
            values.append(('seed_counter', str(res.seed_counter)))
        level, msg = (0, 'converged') if res.converged else (1, res.verdict)
        status = T.DiagnosticStatus(STATUS_NAME, level, msg, '', tuple(values))
        return T.DiagnosticSample(self._latest_t, (status,), self._latest_stamp)

    @staticmethod
    def headline(summary: dict[str, Any]) -> dict[str, Any]:
        """Return the calibrated values with their standard deviations, and the verdict."""
        result = summary.get('result', {})
        out = {k: v for k, v in result.items()
               if isinstance(v, (int, float)) and not isinstance(v, bool)}
        out['verdict'] = result.get('verdict')
        return out

    def method_summary(self) -> dict[str, Any]:
        """Return the result, the drive content and the front end's counters."""
        res = self.result or self.estimator.result()
        out = {'result': res.to_dict(), 'counts': dict(res.counts),
               'drive_type_source': res.drive_source,
               'wheel_source': self.wheel_source()}
        if out['wheel_source'] == 'odometry':
            out['wheel_source_caveat'] = self.odometry_caveat()
        for k in ('content', 'outliers', 'sigma', 'seed_stages_needed'):
            if k in res.details:
                out[k] = res.details[k]
        return out

    def artifacts(self) -> dict[str, str]:
        """Return ``{'wheel_calibration.yaml': text}`` (the contract's flat YAML)."""
        res = self.result or self.estimator.result()
        caveat = self.odometry_caveat()
        return {'wheel_calibration.yaml': (f'# NOTE: {caveat}.\n' if caveat else '') +
                res.to_yaml()}

    def stack_export(self) -> SE.StackFiles:
        """
        Return the controller block and the lidar pose for the robot's stack (converged only).

        ros2_control's diff_drive_controller or tricycle_controller parameters,
        the steering calibration as a transmission, the lidar pose as a static
        transform and a URDF joint (:func:`stack_export.wheel_files`).
        """
        res = self.result or self.estimator.result()
        p = self.params
        frame = getattr(self.estimator, 'lidar_frame', None)
        tf = self.static_mounting(frame, p.base_frame)
        joints = {'left': p.left_wheel_joint, 'right': p.right_wheel_joint,
                  'steering': p.steering_joint, 'traction': p.traction_joint} \
            if self.wheel_source() == 'joint_states' else {}
        return SE.wheel_files(res.to_dict(), self.name, self.recording, base_frame=p.base_frame,
                              lidar_frame=frame,
                              lidar_mounting=None if tf is None else (tf.translation,
                                                                      tf.rotation),
                              caveat=self.odometry_caveat(), joints=joints)


PIPELINE = WheelCalibrationPipeline
