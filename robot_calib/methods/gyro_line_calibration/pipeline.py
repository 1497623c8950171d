# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pipeline of the ``gyro_line_calibration`` node: imu + odom + scan -> ``gyro_line/odom``.

Glue only: samples go to the estimator variant that ``mode`` selects
(:class:`~robot_calib.methods.gyro_line_calibration.seed.SeedGyroLine` or
:class:`~robot_calib.methods.gyro_line_calibration.improved.ImprovedGyroLine`);
everything published is read from what ``update`` returns and from ``result()``.
On every accepted odometry sample the pose with the corrected heading is
published on ``gyro_line/odom`` (nav_msgs/Odometry, same stamp and child frame
as the input odometry, in ``map_frame``: REP-105's map, since a correction makes
it jump; pose covariance of x, y, yaw from the filter), and with
``publish_tf`` the correction ``map_frame -> odometry frame`` on ``/tf``. A
diagnostic_msgs/DiagnosticArray on ``/diagnostics`` reports the corrections
(count, last one in degrees), the references, the heading uncertainty and the
gyro bias estimate, and every rejection and untrusted-data count, once per
``diagnostics_period`` of sensor time and at every correction.

The seed mode's phase comes from the ``seed.phase`` parameter, from
``seed.phase_switch_time``, or from the optional ``gyro_line/edge_following``
topic (std_msgs/Bool: true = edge following).
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any, Optional

import numpy as np

from robot_calib.core import figures, types as T
from robot_calib.core.series import Thinned
from robot_calib.methods.gyro_line_calibration.common import GyroLineResult, within_hold
from robot_calib.methods.gyro_line_calibration.params import GyroLineParams
from robot_calib.methods.gyro_line_calibration.variants import make_estimator
from robot_calib.pipelines.base import InputSpec, Output, OutputSpec, Pipeline


class GyroLinePipeline(Pipeline):
    """Gyro heading calibration from wall lines (seed 000; automatic mode by default)."""

    name = 'gyro_line_calibration'
    params_type = GyroLineParams
    inputs = (
        InputSpec('imu', 'imu', 'imu', optional=True),
        InputSpec('odom', 'odom', 'odom'),
        InputSpec('scan', 'scan', 'scan'),
        InputSpec('edge_following', 'gyro_line/edge_following', 'bool', optional=True),
        InputSpec('tf_static', '/tf_static', 'tf_static', optional=True),
    )
    outputs = (
        OutputSpec('odom', 'gyro_line/odom', 'odom'),
        OutputSpec('diagnostics', '/diagnostics', 'diagnostics'),
        OutputSpec('tf', '/tf', 'tf', qos='tf'),
    )

    def __init__(self, params: Any = None, log: Any = None):
        """Create the pipeline and its estimator."""
        super().__init__(params, log)
        self.core = make_estimator(self.params)
        self._next_diag = None
        self._odom_resets = 0
        self._lock_lost_episodes = 0
        self._trace = Thinned()  # (t, x, y, yaw) for the plot

    def input_notes(self) -> Any:
        """Return the estimator's standing warnings about its inputs."""
        return self.core.input_notes

    def on_static_transform(self, transform: T.StaticTransform) -> None:
        """Forward a /tf_static mounting (IMU or laser) to the estimator."""
        self.core.set_mounting(transform)

    def handle(self, key: str, sample: Any) -> list[Output]:
        """Feed one accepted sample to the estimator; return the corrected pose and diagnostics."""
        made = self.core.update(sample)
        if key == 'scan':
            reason = self.core.scan_rejected
            if reason is not None:
                self.reject('scan', reason)
            lost = self.core.lock_lost_episodes > self._lock_lost_episodes
            if lost:
                self._lock_lost_episodes = self.core.lock_lost_episodes
                self.log('warn', f't={sample.t:.1f} s: the walls contradict the heading (lines '
                         'on references disagree with them): a turn left it outside every gate; '
                         'a gyro scale or bias beyond scale_sigma0 / bias_sigma0?')
            if made:
                c = made[-1]
                self.log('debug', f'heading corrected by {math.degrees(c.delta):+.3f} deg '
                         f'({c.kind}, references {list(c.reference_ids)})')
            return self._diagnostics(sample, force=True) if made or lost else []
        if key != 'odom':
            return []
        if made.odom_resets > self._odom_resets:
            self._odom_resets = made.odom_resets
            self.log('warn', 'odometry reset or jump: pose kept, lines distrusted for a while')
        if not made.initialized:
            return []
        pose = made.pose
        if not self._trace or sample.t - self._trace[-1][0] >= 0.1:
            self._trace.append((sample.t, float(pose[0]), float(pose[1]), float(pose[2])))
        out = T.OdomSample(sample.t, float(pose[0]), float(pose[1]), float(pose[2]),
                           sample.vx, sample.vy, made.rate, self.params.map_frame,
                           sample.child_frame_id, made.pose_cov, sample.twist_cov, sample.z,
                           sample.roll, sample.pitch, sample.stamp_ns)
        return [('odom', out)] + self.correction_tf(out, sample) + self._diagnostics(sample)

    # -- diagnostics -----------------------------------------------------------------------
    def _diagnostics(self, sample: Any, force: bool = False,
                     res: Optional[GyroLineResult] = None) -> list[Output]:
        if not force and self._next_diag is not None and sample.t < self._next_diag:
            return []
        self._next_diag = sample.t + self.params.diagnostics_period
        return [('diagnostics', T.DiagnosticSample(sample.t, (self.status(sample.t, res),),
                                                   sample.stamp_ns))]

    def status(self, t: float, res: Optional[GyroLineResult] = None) -> T.DiagnosticStatus:
        """Return the diagnostic status at time ``t`` (s) (of ``res``, else the latest result)."""
        res = res if res is not None else self.core.result()
        last = res.last_correction
        trusted = res.trusted(t)
        contradicted = within_hold(res.lock_lost_last, t, self.params.improved.lock_hold)
        rejected = {f'rejected_{k}.{r[9:]}': v for k, c in self.counts.items()
                    for r, v in c.items() if r.startswith('rejected_')}
        values = [
            ('mode', self.params.mode),
            ('phase', 'edge_following' if res.edge_following else 'work'),
            ('corrections', str(res.counts.get('corrections', 0))),
            ('last_correction_deg', f'{math.degrees(last.delta):.4f}' if last else 'none'),
            ('last_correction_time', f'{last.t:.3f}' if last else 'none'),
            ('references', str(len(res.references))),
            ('tentative_references', str(res.tentative_references)),
            ('heading_sigma_deg', f'{math.degrees(res.heading_sigma):.4f}'),
            ('gyro_bias_deg_per_h', f'{math.degrees(res.gyro_bias) * 3600.0:.3f}'),
            ('trusted', str(trusted)),
            ('walls_contradict_heading', str(contradicted)),
            ('walls_contradicted_times', str(res.lock_lost_episodes)),
        ]
        values += [(k, str(v)) for k, v in sorted(rejected.items())]
        values += [(f'events.{k}', str(v)) for k, v in sorted(res.counts.items())
                   if k not in ('lines',)]
        level, msg = 0, 'ok'
        if contradicted:
            level, msg = 1, ('heading lost the walls: lines on references disagree with them '
                             '(gyro scale or bias beyond its prior?)')
        elif not trusted:
            level, msg = 1, 'lines not used: untrusted data (carried, odometry reset or gap)'
        elif not res.corrections:
            msg = 'no correction yet'
        return T.DiagnosticStatus('gyro_line_calibration: heading', level, msg,
                                  'gyro_line_calibration', tuple(values))

    # -- results ---------------------------------------------------------------------------
    @staticmethod
    def headline(summary: dict[str, Any]) -> dict[str, Any]:
        """Return the gyro bias (rad/s), the corrections and the heading uncertainty (rad)."""
        return {k: summary[k] for k in ('gyro_bias', 'corrections', 'heading_sigma')
                if isinstance(summary.get(k), (int, float))}

    def method_summary(self) -> dict[str, Any]:
        """
        Return corrections, references, bias estimate and event counts.

        ``walls_verdict`` is ``contradicted`` when the walls ever disagreed with
        the heading (it lost them: every later correction may follow references
        made in a rotated frame), ``no_correction`` when no wall corrected it,
        ``not_checked`` in seed mode, else ``consistent``.
        """
        res, core = self.core.result(), self.core
        return {
            'mode': self.params.mode,
            'corrections': res.counts.get('corrections', 0),
            'correction_total_deg': math.degrees(core.correction_total),
            'corrections_kept': len(res.corrections),
            'correction_abs_max_deg': math.degrees(core.correction_abs_max),
            'corrections_list': [
                {'t': c.t, 'delta_deg': math.degrees(c.delta), 'kind': c.kind,
                 'angle_error_deg': math.degrees(c.angle_error),
                 'references': list(c.reference_ids)}
                for c in itertools.islice(res.corrections, 500)],
            'references': len(res.references),
            'gyro_bias': res.gyro_bias,
            'heading_sigma': res.heading_sigma,
            'final_pose': [float(v) for v in res.pose] if res.initialized else None,
            'events': dict(res.counts),
            'walls_verdict': self._walls_verdict(res),
            'walls_contradicted_times': res.lock_lost_episodes,
            'walls_contradicted_last_t': res.lock_lost_last,
        }

    def _walls_verdict(self, res: GyroLineResult) -> str:
        if self.params.mode != 'improved':
            return 'not_checked'
        if res.lock_lost_episodes:
            return 'contradicted'
        return 'consistent' if res.counts.get('corrections', 0) else 'no_correction'

    def plot(self, out_dir: str) -> list[str]:
        """Draw the corrected trajectory and the heading corrections over time."""
        if not self._trace:
            return []
        if not figures.available():
            return []
        tr = np.array(list(self._trace))
        fig, ax = figures.new_figure(11, 4.5, cols=2)
        ax[0].plot(tr[:, 1], tr[:, 2], lw=0.7)
        res = self.core.result()
        for line in res.references:
            ax[0].plot([line.p1[0], line.p2[0]], [line.p1[1], line.p2[1]], 'k-', lw=1.5)
        ax[0].set_aspect('equal')
        ax[0].set_title('corrected trajectory and reference lines (m)')
        if self.core.correction_trace:
            c = np.array(list(self.core.correction_trace))
            ax[1].plot(c[:, 0], np.degrees(c[:, 1]), '.-', ms=2)
        ax[1].set_xlabel('t (s)')
        ax[1].set_ylabel('cumulative heading correction (deg)')
        return [figures.save(fig, Path(out_dir) / 'gyro_line_calibration.png')]


PIPELINE = GyroLinePipeline
