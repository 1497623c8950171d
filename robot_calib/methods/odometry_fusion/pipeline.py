# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pipeline of the ``odometry_fusion`` node: IMU + wheel odometry -> ``odometry/fused``.

Glue only: samples go to the filter (:mod:`robot_calib.methods.odometry_fusion.seed`
or :mod:`~robot_calib.methods.odometry_fusion.improved`, by ``mode``) through its
``update``; the estimates it returns come back as nav_msgs/Odometry samples
stamped with the input that produced them, and a diagnostic_msgs/DiagnosticArray
on ``/diagnostics`` reports its result (:mod:`.report`: NIS, noise adaptation,
bias estimates, rejections and re-initialisations) once per
``diagnostics_period`` of sensor time. Static transforms go to its
``set_mounting`` (the IMU mounting); its warnings are logged. With
``publish_tf`` every fused pose is also the transform ``odom_frame ->
base_frame`` on ``/tf`` (REP-105's odom frame), with the same stamp.

Outputs are published on every accepted odometry (or joint-state) update; while
the odometry is silent for longer than ``sensor_timeout`` the filter returns
them on every IMU sample instead (IMU dead reckoning, growing covariance).
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from robot_calib.core import frames, types as T
from robot_calib.core.series import Thinned
from robot_calib.methods.odometry_fusion import report
from robot_calib.methods.odometry_fusion.common import FusionOutput, LidarOdomSample, Rejected
from robot_calib.methods.odometry_fusion.params import FusionParams
from robot_calib.methods.odometry_fusion.variants import make_estimator
from robot_calib.pipelines import stack_export as SE
from robot_calib.pipelines.base import InputSpec, Output, OutputSpec, Pipeline


class FusionPipeline(Pipeline):
    """IMU + wheel odometry fusion (seed 004; improved EKF by default)."""

    name = 'odometry_fusion'
    params_type = FusionParams
    inputs = (
        InputSpec('imu', 'imu', 'imu'),
        InputSpec('odom', 'odom', 'odom', optional=True),
        InputSpec('joint_states', 'joint_states', 'joint_states', optional=True),
        InputSpec('lidar_odom', 'lidar/odom', 'odom', optional=True),
        InputSpec('tf_static', '/tf_static', 'tf_static', optional=True),
    )
    outputs = (
        OutputSpec('odom', 'odometry/fused', 'odom'),
        OutputSpec('diagnostics', '/diagnostics', 'diagnostics'),
        OutputSpec('tf', '/tf', 'tf', qos='tf'),
    )

    def __init__(self, params: Any = None, log: Any = None):
        """Create the pipeline and its filter (the filter's warnings go to ``log``)."""
        super().__init__(params, log)
        self.estimator = make_estimator(self.params, self.log)
        self._next_diag: Optional[float] = None
        self._trajectory = Thinned()  # (t, x, y, yaw) for the plot
        self._ignored_cov = 0
        self._wheel_key: Optional[str] = None
        self._js_first: Optional[float] = None
        self._cov_next = -math.inf

    # -- inputs ----------------------------------------------------------------------------
    def input_notes(self) -> Any:
        """Return the filter's standing warnings about its inputs."""
        return self.estimator.input_notes

    def on_static_transform(self, transform: T.StaticTransform) -> None:
        """Give a static transform to the filter (the IMU mounting: base_frame -> IMU frame)."""
        self.estimator.set_mounting(transform)

    def handle(self, key: str, sample: Any) -> list[Output]:
        """Feed one accepted sample to the filter; return fused odometry and diagnostics."""
        outs: list[Output] = []
        if key == 'imu':
            if self._cov_next <= sample.t:  # IMU covariances: checked once a second
                self._check_cov(sample.gyro_cov)
                self._cov_next = sample.t + 1.0
            outs += self._update(key, sample)
        elif key in ('odom', 'joint_states'):
            if not self._wheel_source_ok(key, sample.t):
                self.reject(key, 'other_wheel_source_used')
                return self._diagnostics(sample)
            if key == 'odom':
                self._check_cov(sample.twist_cov)
            outs += self._update(key, sample)
        elif key == 'lidar_odom':
            self.estimator.update(LidarOdomSample(sample))
        outs += self._diagnostics(sample)
        return outs

    def _update(self, key: str, sample: Any) -> list[Output]:
        """Update the filter with ``sample``; count a rejection or publish the estimate."""
        out = self.estimator.update(sample)
        if isinstance(out, Rejected):
            return self.reject(key, out.reason)
        if isinstance(out, FusionOutput):
            return self._publish(sample, out)
        return []

    def _wheel_source_ok(self, key: str, t: float) -> bool:
        """Use one wheel source only: odometry, or joint states when no odometry comes."""
        want = self.params.wheel_source
        if want != 'auto':
            return key == want
        if self._wheel_key is None:
            if key == 'joint_states':
                if self._js_first is None:
                    self._js_first = t
                if t - self._js_first < 1.0:
                    return False  # wait up to 1 s for odometry
            self._wheel_key = key
            self.log('info', f'wheel input: {key}')
        return key == self._wheel_key

    def _check_cov(self, cov: Any) -> None:
        """Count message covariances that are zero, negative or absurd (they are not used)."""
        if cov is None:
            return
        d = (float(cov[0][0]), float(cov[1][1]), float(cov[2][2]))
        if all(v != v for v in d):  # NaN: not provided
            return
        if not all(0.0 < v <= 1e3 for v in d):  # zero, negative, NaN or absurd
            self._ignored_cov += 1

    def _publish(self, sample: Any, o: FusionOutput) -> list[Output]:
        """Return the estimate ``o`` as odometry stamped with the input ``sample``."""
        p = self.params
        tw, pc = o.twist_cov, o.pose_cov
        if p.mode == 'seed':  # unknown entries -> -1 (ROS convention)
            tw = np.where(np.isfinite(tw), tw, -1.0)
            pc = np.where(np.isfinite(pc), pc, -1.0)
        w = o.w if math.isfinite(o.w) else 0.0
        out = T.OdomSample(sample.t, o.x, o.y, o.yaw, o.v, o.v_lateral, w, p.odom_frame,
                           p.base_frame, pc, tw, stamp_ns=sample.stamp_ns)
        self._trajectory.append((sample.t, o.x, o.y, o.yaw))
        if not p.publish_tf:
            return [('odom', out)]
        return [('odom', out), ('tf', [frames.pose_transform(
            p.odom_frame, p.base_frame, (o.x, o.y, o.yaw), sample.t, sample.stamp_ns)])]

    # -- reports ---------------------------------------------------------------------------
    def _diagnostics(self, sample: Any) -> list[Output]:
        """Return the diagnostics when one ``diagnostics_period`` of sensor time has passed."""
        if self._next_diag is None:
            self._next_diag = sample.t + self.params.diagnostics_period
            return []
        if sample.t < self._next_diag:
            return []
        self._next_diag = sample.t + self.params.diagnostics_period
        return [('diagnostics', T.DiagnosticSample(sample.t, (self.status(),),
                                                   stamp_ns=sample.stamp_ns))]

    def status(self) -> T.DiagnosticStatus:
        """Return the current diagnostic status: level, message and key-values."""
        return report.diagnostic_status(self.estimator.result(for_status=True), self.params,
                                        self.counts)

    @staticmethod
    def headline(summary: dict[str, Any]) -> dict[str, Any]:
        """Return the learned sensor errors (gyro bias, yaw-rate scale, ...) with their stds."""
        return {k: v for k, v in (summary.get('estimates') or {}).items()
                if isinstance(v, (int, float)) and not isinstance(v, bool)}

    def method_summary(self) -> dict[str, Any]:
        """Return estimates, adaptation state, NIS consistency, warnings and counters."""
        out = report.summary(self.estimator.result(), self.params, self._ignored_cov)
        if self._trajectory:
            t, x, y, yaw = self._trajectory[-1]
            out['final_pose'] = {'t': t, 'x': x, 'y': y, 'yaw': yaw}
        return out

    def stack_export(self) -> SE.StackFiles:
        """Return the IMU mounting used (static transform, URDF joint) and the gyro bias (YAML)."""
        res = self.estimator.result()
        base = self.params.base_frame
        frame = getattr(self.estimator, 'imu_frame', None)
        sources = {'tf': f'/tf_static ({base} -> {frame})', 'param': 'the imu_rpy parameter'}
        rot = res.imu_rotation if res.imu_extrinsic in sources else None
        tf = self.static_mounting(frame, base)
        out = SE.imu_mounting_files('imu_fusion', self.name, self.recording, base, frame, rot,
                                    sources.get(res.imu_extrinsic, ''),
                                    None if tf is None else tf.translation)
        if res.imu_extrinsic == 'gravity':
            out.withheld[-1:] = [f'{self.name}: no IMU mounting file: only the up axis was '
                                 'found (from gravity); give imu_rpy or /tf_static']
        est = res.estimates
        return out.add(SE.gyro_bias_file(
            'imu_fusion_gyro_bias.yaml', self.name, self.recording, base, 'z',
            float(est.get('gyro_bias', math.nan)), float(est.get('gyro_bias_std', math.nan)),
            self.params.gyro_bias_init))

    def plot(self, out_dir: str) -> list[str]:
        """Draw the fused trajectory and the NIS history (PNG)."""
        return report.plot(self.estimator.result(), self.params, list(self._trajectory),
                           out_dir)


PIPELINE = FusionPipeline
