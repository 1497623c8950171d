# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pipeline of ``loop_closure_correction``: imu, odom, scan in; corrected odometry out.

Thin glue around
:class:`robot_calib.methods.loop_closure_correction.estimator.LoopClosureCorrector`:
the gyro (rotated into base_link by the ``/tf_static`` mounting when present)
drives the heading, the wheel odometry the distance, and the scans (moved
into base_link the same way) the keyframes and loop closures. Every odometry
input produces one ``loop_closure/odom`` (nav_msgs/Odometry, same stamp, the
corrected pose with its covariance); every closure attempt (accepted,
refused, or a suspected kidnap) produces one ``/diagnostics`` array.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from robot_calib.core import types as T
from robot_calib.core.geometry import quat_to_matrix, se2_apply, yaw_from_quat
from robot_calib.core.series import Thinned
from robot_calib.methods.loop_closure_correction.estimator import (ClosureReport, deskew,
                                                                   LoopClosureCorrector,
                                                                   LoopClosureParams)
from robot_calib.pipelines.base import InputSpec, OutputSpec, Pipeline

NAME = 'loop_closure_correction'


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
    )

    def __init__(self, params: Any = None, log=None):
        """Create the corrector."""
        super().__init__(params, log)
        self.core = LoopClosureCorrector(self.params)
        self._n_reports = 0
        self._speed = 0.0
        self._track = Thinned()  # (t, x, y, yaw, raw x, raw y) for the plot

    # -- helpers --------------------------------------------------------------------------
    def _mount(self, frame: str):
        """Return the static transform whose child is ``frame``, or None."""
        for (_, child), tf in self.static_transforms.items():
            if child == frame:
                return tf
        return None

    def _scan_points(self, scan: T.ScanSample) -> np.ndarray:
        """Return the valid beams in base_link (m), deskewed when beams have times."""
        idx, r, ang = scan.beams()
        pts = np.column_stack((r * np.cos(ang), r * np.sin(ang)))
        tf = self._mount(scan.frame_id)
        if tf is not None and len(pts):
            pose = (float(tf.translation[0]), float(tf.translation[1]),
                    yaw_from_quat(tf.rotation))
            pts = se2_apply(pose, pts)
        if scan.time_increment != 0 and len(pts):
            pts = deskew(pts, scan.beam_times(idx), self._speed, self.core.rate)
        return pts

    def _diagnostic(self, report: ClosureReport, stamp_ns: int) -> tuple[str, T.DiagnosticSample]:
        if report.accepted:
            level, msg = 0, 'loop closure accepted'
        elif report.reason == 'kidnap_suspected':
            level, msg = 2, 'kidnap suspected: scan disagrees with odometry, map restarted'
        else:
            level, msg = 1, f'loop closure refused: {report.reason}'
        c = report.correction
        values = (
            ('reason', report.reason),
            ('keyframes_tried', ','.join(str(k) for k in report.keyframes_tried)),
            ('scores', ','.join(f'{s:.3f}' for s in report.scores)),
            ('similarities', ','.join(f'{s:.3f}' for s in report.similarities)),
            ('chosen_keyframe', str(report.chosen)),
            ('correction_x', f'{c[0]:.4f}'), ('correction_y', f'{c[1]:.4f}'),
            ('correction_yaw', f'{c[2]:.5f}'),
            ('latency_ms', f'{report.latency_ms:.2f}'),
            ('search_radius', f'{report.radius:.2f}'),
            ('min_eigenvalue', f'{report.min_eigenvalue:.4f}'),
            ('inlier_ratio', f'{report.inlier_ratio:.3f}'),
            ('gyro_bias', f'{self.core.gyro_bias:.6f}'),
            ('closures_accepted', str(self.core.counts.get('closures_accepted', 0))),
        )
        status = T.DiagnosticStatus(name=f'{NAME}: loop closure', level=level, message=msg,
                                    hardware_id=NAME, values=values)
        return 'diagnostics', T.DiagnosticSample(t=report.t, statuses=(status,),
                                                 stamp_ns=stamp_ns)

    def _new_reports(self, stamp_ns: int) -> list:
        outs = []
        while self._n_reports < len(self.core.reports):
            outs.append(self._diagnostic(self.core.reports[self._n_reports], stamp_ns))
            self._n_reports += 1
        return outs

    # -- pipeline hooks -----------------------------------------------------------------------
    def handle(self, key: str, sample: Any) -> list:
        """Process one imu, odom or scan sample."""
        if key == 'imu':
            gyro = np.asarray(sample.gyro, dtype=float)
            tf = self._mount(sample.frame_id)
            if tf is not None:
                gyro = quat_to_matrix(tf.rotation) @ gyro
            self.core.update_imu(sample.t, float(gyro[2]))
            return []
        if key == 'odom':
            pose = self.core.update_odom(sample.t, sample.x, sample.y, sample.yaw)
            self._speed = float(sample.vx)
            sxy2 = 0.5 * self.core.sigma_xy ** 2
            cov = np.diag([sxy2, sxy2, self.core.sigma_yaw ** 2])
            wz = sample.wz
            if self.core.using_imu:
                wz = self.core.rate
            out = T.OdomSample(t=sample.t, x=float(pose[0]), y=float(pose[1]),
                               yaw=float(pose[2]), vx=sample.vx, vy=sample.vy, wz=float(wz),
                               frame_id=sample.frame_id, child_frame_id=sample.child_frame_id,
                               pose_cov=cov, twist_cov=sample.twist_cov,
                               stamp_ns=T.stamp_of(sample.t, sample.stamp_ns))
            raw = self.core.raw
            if not self._track or sample.t - self._track[-1][0] >= 0.2:
                self._track.append((sample.t, float(pose[0]), float(pose[1]), float(pose[2]),
                                    float(raw[0]), float(raw[1])))
            return [('odom', out)]
        if key == 'scan':
            pts = self._scan_points(sample)
            if len(pts) < self.params.min_valid_beams:
                return self.reject('scan', 'few_valid_beams')
            self.core.update_scan(sample.t, pts)
            return self._new_reports(T.stamp_of(sample.t, sample.stamp_ns))
        return []

    def method_summary(self) -> dict:
        """Return closures (tried keyframes, scores, correction, time), counts and latency."""
        s = self.core.summary()
        reports = self.core.reports
        s['closures'] = [r.as_dict() for r in reports[:500]]
        s['closures_listed'] = min(len(reports), 500)
        s['corrections'] = [
            {'t': r.t, 'x': float(r.correction[0]), 'y': float(r.correction[1]),
             'yaw': float(r.correction[2])} for r in reports if r.accepted][:500]
        s['final_pose'] = [float(v) for v in self.core.pose]
        s['total_heading_correction'] = float(sum(abs(r.correction[2]) for r in reports
                                                  if r.accepted))
        return s

    def plot(self, out_dir: str) -> list:
        """Draw the raw and corrected trajectories with the closures (loop_closure.png)."""
        if not self._track:
            return []
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        tr = np.array(list(self._track))
        fig, ax = plt.subplots(figsize=(7, 6))
        ax.plot(tr[:, 4], tr[:, 5], color='0.6', lw=1, label='dead reckoning (raw)')
        ax.plot(tr[:, 1], tr[:, 2], color='C0', lw=1.2, label='corrected')
        acc = [r for r in self.core.reports if r.accepted]
        ref = [r for r in self.core.reports if not r.accepted]
        if acc:
            a = np.array([r.pose_after for r in acc])
            ax.plot(a[:, 0], a[:, 1], 'o', color='C2', ms=4, label=f'accepted ({len(acc)})')
        if ref:
            b = np.array([r.pose_before for r in ref])
            ax.plot(b[:, 0], b[:, 1], 'x', color='C3', ms=4, label=f'refused ({len(ref)})')
        ax.set_aspect('equal')
        ax.set_xlabel('x (m)')
        ax.set_ylabel('y (m)')
        ax.set_title('loop_closure_correction')
        ax.legend(fontsize=8)
        name = 'loop_closure.png'
        fig.savefig(f'{out_dir}/{name}', dpi=90)
        plt.close(fig)
        return [name]


def heading_rmse(t_est: np.ndarray, yaw_est: np.ndarray, t_true: np.ndarray,
                 yaw_true: np.ndarray) -> float:
    """Return the RMS heading error (rad) of estimates against truth interpolated at ``t_est``."""
    unwrapped = np.unwrap(yaw_true)
    ref = np.interp(t_est, t_true, unwrapped)
    err = np.angle(np.exp(1j * (np.asarray(yaw_est) - ref)))
    return float(math.sqrt(np.mean(err ** 2))) if len(err) else float('nan')


PIPELINE = LoopClosurePipeline
