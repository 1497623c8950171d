# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pipeline of the ``odometry_fusion`` node: IMU + wheel odometry -> ``odometry/fused``.

Glue only: samples go to :mod:`robot_calib.methods.odometry_fusion.estimator`, estimates
come back as nav_msgs/Odometry samples stamped with the input that produced them, and a
diagnostic_msgs/DiagnosticArray on ``/diagnostics`` reports the NIS, the noise
adaptation, the bias estimates, rejections and re-initialisations once per
``diagnostics_period`` of sensor time.

Outputs are published on every accepted odometry (or joint-state) update; while
the odometry is silent for longer than ``sensor_timeout`` they are published on
every IMU sample instead (IMU dead reckoning, growing covariance).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.series import Thinned
from robot_calib.methods.odometry_fusion import estimator as F
from robot_calib.pipelines.base import InputSpec, Output, OutputSpec, Pipeline


class FusionPipeline(Pipeline):
    """IMU + wheel odometry fusion (seed 004; improved EKF by default)."""

    name = 'odometry_fusion'
    params_type = F.FusionParams
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
    )

    def __init__(self, params: Any = None, log: Any = None):
        """Create the pipeline and its filter."""
        super().__init__(params, log)
        self.filter = F.make_filter(self.params)
        self._tfs: list = []
        self._imu_frame = None
        self._next_diag = None
        self._events_seen = 0
        self._trajectory = Thinned()  # (t, x, y, yaw) for the plot
        self._ignored_cov = 0

    # -- inputs ----------------------------------------------------------------------------
    def on_static_transform(self, transform: T.StaticTransform) -> None:
        """Take the IMU mounting from /tf_static (base_frame -> IMU frame)."""
        if F.apply_static_transform(self.filter, transform, self._tfs, self.params,
                                    self._imu_frame):
            self.log('info', f'IMU extrinsic from /tf_static ({self.params.base_frame} -> '
                     f'{self._imu_frame or transform.child})')

    def handle(self, key: str, sample: Any) -> list[Output]:
        """Feed one accepted sample to the filter; return fused odometry and diagnostics."""
        f = self.filter
        outs: list[Output] = []
        if key == 'imu':
            if self._imu_frame is None:
                self._imu_frame = sample.frame_id.lstrip('/')
                if self._tfs and f.front.rot_source != 'tf':
                    F.apply_static_transform(f, self._tfs.pop(), self._tfs, self.params,
                                             self._imu_frame)
            if self._cov_next <= sample.t:  # IMU covariances: checked once a second
                self._check_cov(sample.gyro_cov)
                self._cov_next = sample.t + 1.0
            reason = f.imu(sample)
            if reason is not None and reason != 'initialising':
                self.reject(key, reason)
            elif reason is None and f.last_odom_t is not None and \
                    sample.t - f.last_odom_t > self.params.sensor_timeout:
                outs += self._estimate(sample)
        elif key in ('odom', 'joint_states'):
            if not self._wheel_source_ok(key, sample.t):
                self.reject(key, 'other_wheel_source_used')
                return self._diagnostics(sample)
            if key == 'odom':
                self._check_cov(sample.twist_cov)
            reason = f.odom(sample) if key == 'odom' else f.wheels(sample)
            if reason is not None:
                self.reject(key, reason)
            else:
                outs += self._estimate(sample)
        elif key == 'lidar_odom':
            f.lidar(sample)
        outs += self._diagnostics(sample)
        self._flush_events()
        return outs

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

    _wheel_key = None
    _js_first = None
    _cov_next = -math.inf

    def _check_cov(self, cov: Any) -> None:
        """Count message covariances that are zero, negative or absurd (they are not used)."""
        if cov is None:
            return
        d = (float(cov[0][0]), float(cov[1][1]), float(cov[2][2]))
        if all(v != v for v in d):  # NaN: not provided
            return
        if not all(0.0 < v <= 1e3 for v in d):  # zero, negative, NaN or absurd
            self._ignored_cov += 1

    def _estimate(self, sample: Any) -> list[Output]:
        o = self.filter.output()
        if o is None:
            return []
        p = self.params
        tw, pc = o.twist_cov, o.pose_cov
        if isinstance(self.filter, F.SeedFusion):  # unknown entries -> -1 (ROS convention)
            tw = np.where(np.isfinite(tw), tw, -1.0)
            pc = np.where(np.isfinite(pc), pc, -1.0)
        w = o.w if math.isfinite(o.w) else 0.0
        out = T.OdomSample(sample.t, o.x, o.y, o.yaw, o.v, 0.0, w, p.odom_frame, p.base_frame,
                           pc, tw, stamp_ns=sample.stamp_ns)
        self._trajectory.append((sample.t, o.x, o.y, o.yaw))
        return [('odom', out)]

    def _flush_events(self) -> None:
        ev = self.filter.events
        while self._events_seen < len(ev):
            self.log('warn', ev[self._events_seen][1])
            self._events_seen += 1
        if len(ev) > 900:
            self._events_seen = 0
            ev.clear()

    # -- diagnostics -----------------------------------------------------------------------
    def _diagnostics(self, sample: Any) -> list[Output]:
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
        f = self.filter
        values = [('mode', self.params.mode),
                  ('imu_extrinsic', f.front.rot_source),
                  ('accel_units', f.front.units_source)]
        level, msg = 0, 'ok'
        if isinstance(f, F.ImprovedFusion):
            band = f.nis_band_now
            frac = f.nis_in_band / f.nis_checked if f.nis_checked else float('nan')
            wfrac = f.nis_window_in_band / f.nis_window_checked if f.nis_window_checked \
                else float('nan')
            values += [('nis_last', f'{f.nis_hist[-1]:.3f}' if f.nis_hist else 'nan'),
                       ('nis_avg', f'{f.nis_avg:.3f}'),
                       ('nis_band_low', f'{band[0]:.3f}'), ('nis_band_high', f'{band[1]:.3f}'),
                       ('nis_in_band_fraction', f'{frac:.3f}'),
                       ('nis_window_in_band_fraction', f'{wfrac:.3f}')]
            values += [(k, f'{v:.6g}') for k, v in f.state_summary().items()]
            values.append(('imu_stale', str(f.imu_stale)))
            if math.isfinite(f.nis_avg) and not band[0] <= f.nis_avg <= band[1]:
                level, msg = 1, 'NIS outside its 95% band'
            if f.imu_stale:
                level, msg = 1, 'IMU stale: wheel odometry only'
        for k, v in sorted(f.counts.items()):
            values.append((k, str(v)))
        for key, c in sorted(self.counts.items()):
            if c.get('rejected'):
                values.append((f'{key}_rejected', str(c['rejected'])))
        acc, valid = f.lidar_check()
        if math.isfinite(acc):
            values += [('lidar_accuracy', f'{acc:.4f}'), ('lidar_accuracy_valid', str(valid))]
            if not valid:
                level, msg = max(level, 1), 'lidar distance check failed (accuracy < 0.95)'
        if f.counts.get('reinitialisations'):
            msg = msg if level else f'ok ({f.counts["reinitialisations"]} re-initialisations)'
        if f.events:
            values.append(('last_warning', f.events[-1][1]))
        return T.DiagnosticStatus('odometry_fusion: filter', level, msg, 'odometry_fusion',
                                  tuple(values))

    # -- summary ---------------------------------------------------------------------------
    def method_summary(self) -> dict[str, Any]:
        """Return estimates, adaptation state, NIS consistency, warnings and counters."""
        f = self.filter
        out: dict[str, Any] = {
            'mode': self.params.mode,
            'imu_extrinsic': f.front.rot_source,
            'accel_units': f.front.units_source,
            'filter_counts': dict(f.counts),
            'message_covariances_ignored': self._ignored_cov,
            'warnings': [f'{t:.3f}: {m}' for t, m in f.events[-50:]],
            'path_length': f.path_length,
        }
        if isinstance(f, F.ImprovedFusion):
            out['estimates'] = f.state_summary()
            out['nis'] = {
                'updates': f.nis_hist.count,
                'mean': f.nis_sum / f.nis_hist.count if f.nis_hist.count else None,
                'window': self.params.nis_window,
                'in_band_fraction': f.nis_in_band / f.nis_checked if f.nis_checked else None,
                'window_in_band_fraction': f.nis_window_in_band / f.nis_window_checked
                if f.nis_window_checked else None,
            }
        else:
            out['estimates'] = f.state_summary()
        acc, valid = f.lidar_check()
        out['lidar_accuracy'] = {'accuracy': acc, 'valid': valid}
        if self._trajectory:
            t, x, y, yaw = self._trajectory[-1]
            out['final_pose'] = {'t': t, 'x': x, 'y': y, 'yaw': yaw}
        return out

    def plot(self, out_dir: str) -> list[str]:
        """Draw the fused trajectory and the NIS history (PNG)."""
        if not self._trajectory:
            return []
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        from pathlib import Path
        tr = np.array(list(self._trajectory))
        names = []
        fig, ax = plt.subplots(figsize=(6, 6))
        ax.plot(tr[:, 1], tr[:, 2], lw=1)
        ax.set_aspect('equal')
        ax.set_xlabel('x (m)')
        ax.set_ylabel('y (m)')
        ax.set_title(f'odometry_fusion ({self.params.mode}) trajectory')
        fig.savefig(Path(out_dir) / 'odometry_fusion_trajectory.png', dpi=100)
        plt.close(fig)
        names.append('odometry_fusion_trajectory.png')
        f = self.filter
        if isinstance(f, F.ImprovedFusion) and f.nis_hist:
            fig, ax = plt.subplots(figsize=(7, 3))
            ax.semilogy(np.arange(0, f.nis_hist.count, f.nis_hist.stride)[:len(f.nis_hist.items)],
                        f.nis_hist.items, lw=0.5)
            ax.set_xlabel('odometry update')
            ax.set_ylabel('NIS')
            fig.savefig(Path(out_dir) / 'odometry_fusion_nis.png', dpi=100)
            plt.close(fig)
            names.append('odometry_fusion_nis.png')
        return names


PIPELINE = FusionPipeline
