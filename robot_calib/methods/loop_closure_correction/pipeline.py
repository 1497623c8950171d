# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pipeline of ``loop_closure_correction``: imu, odom, scan in; corrected odometry out.

Thin glue around the variant ``params.mode`` selects
(:mod:`robot_calib.methods.loop_closure_correction.variants`): samples go to
its ``update``, ``/tf_static`` mountings to its ``set_mounting`` (the
estimator rotates the gyro and moves and de-skews the scans into base_link
itself). Every odometry input produces one ``loop_closure/odom``
(nav_msgs/Odometry, same stamp, the corrected pose of ``result()`` with its
covariance, in ``map_frame``: REP-105's map, since a closure makes it jump);
with ``publish_tf`` also the correction ``map_frame -> odometry frame`` on
``/tf``, so that map -> odom -> base_link gives the corrected pose. Every
closure attempt (accepted, refused, or a suspected kidnap) that ``update``
returns produces one ``/diagnostics`` array.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from robot_calib.core import types as T
from robot_calib.core.series import Thinned
from robot_calib.methods.loop_closure_correction import report
from robot_calib.methods.loop_closure_correction.params import LoopClosureParams
from robot_calib.methods.loop_closure_correction.variants import make_estimator
from robot_calib.pipelines.base import InputSpec, OutputSpec, Pipeline

NAME = report.NAME


class LoopClosurePipeline(Pipeline):
    """Loop-closure heading and pose correction (seed 001) as a pipeline."""

    name = NAME
    params_type = LoopClosureParams
    inputs = (
        InputSpec('imu', 'imu', 'imu', optional=True),
        InputSpec('odom', 'odom', 'odom'),
        InputSpec('scan', 'scan', 'scan'),
        InputSpec('tf_static', '/tf_static', 'tf_static', optional=True),
    )
    outputs = (
        OutputSpec('odom', 'loop_closure/odom', 'odom'),
        OutputSpec('diagnostics', '/diagnostics', 'diagnostics'),
        OutputSpec('tf', '/tf', 'tf', qos='tf'),
    )

    def __init__(self, params: Any = None, log=None):
        """Create the estimator of ``params.mode``."""
        super().__init__(params, log)
        self.estimator = make_estimator(self.params)
        self._refused_scans = 0
        self._track = Thinned()  # (t, x, y, yaw, raw x, raw y) for the plot

    def input_notes(self) -> Any:
        """Return the estimator's standing warnings about its inputs."""
        return self.estimator.input_notes

    def on_static_transform(self, transform: T.StaticTransform) -> None:
        """Hand a mounting to the estimator."""
        self.estimator.set_mounting(transform)

    def handle(self, key: str, sample: Any) -> list:
        """Process one imu, odom or scan sample."""
        if key == 'imu':
            self.estimator.update(sample)
            return []
        if key == 'odom':
            self.estimator.update(sample)
            corrected = self._corrected_odom(sample)
            return [('odom', corrected)] + self.correction_tf(corrected, sample)
        if key == 'scan':
            closure = self.estimator.update(sample)
            refused = self.estimator.scans_refused_few_beams
            if refused > self._refused_scans:
                self._refused_scans = refused
                return self.reject('scan', 'few_valid_beams')
            if closure is None:
                return []
            stamp_ns = T.stamp_of(sample.t, sample.stamp_ns)
            return [('diagnostics',
                     report.diagnostic(closure, self.estimator.result(), stamp_ns))]
        return []

    def _corrected_odom(self, sample: T.OdomSample) -> T.OdomSample:
        """Return the odometry message of the corrected pose at the time of ``sample``."""
        est = self.estimator  # its live state: result() would copy the reports and counts
        pose = est.pose
        sxy2 = 0.5 * est.sigma_xy ** 2
        cov = np.diag([sxy2, sxy2, est.sigma_yaw ** 2])
        wz = est.rate if est.using_imu else sample.wz
        raw = est.raw
        if not self._track or sample.t - self._track[-1][0] >= 0.2:
            self._track.append((sample.t, float(pose[0]), float(pose[1]), float(pose[2]),
                                float(raw[0]), float(raw[1])))
        return T.OdomSample(t=sample.t, x=float(pose[0]), y=float(pose[1]),
                            yaw=float(pose[2]), vx=sample.vx, vy=sample.vy, wz=float(wz),
                            frame_id=self.params.map_frame,
                            child_frame_id=sample.child_frame_id,
                            pose_cov=cov, twist_cov=sample.twist_cov,
                            stamp_ns=T.stamp_of(sample.t, sample.stamp_ns))

    @staticmethod
    def headline(summary: dict[str, Any]) -> dict[str, Any]:
        """Return the gyro bias (rad/s), the closures accepted and the heading correction (rad)."""
        return {k: summary[k] for k in ('gyro_bias', 'closures_accepted',
                                        'total_heading_correction')
                if isinstance(summary.get(k), (int, float))}

    def method_summary(self) -> dict:
        """Return closures (tried keyframes, scores, correction, time), counts and latency."""
        return report.summary(self.estimator.result())

    def plot(self, out_dir: str) -> list:
        """Draw the raw and corrected trajectories with the closures (loop_closure.png)."""
        return report.plot(self._track, self.estimator.result(), out_dir)


PIPELINE = LoopClosurePipeline
