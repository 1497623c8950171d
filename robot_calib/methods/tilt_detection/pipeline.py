# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pipeline of ``tilt_detection``: IMU in; attitude, latched fall alert and diagnostics out.

Inputs: ``imu`` (sensor_msgs/Imu: raw gyro rad/s, specific force m/s^2) and
``/tf_static`` (a ``base_frame`` -> IMU frame transform gives the mounting
rotation; otherwise the ``mounting_rpy`` parameter).

Outputs:

- ``tilt/imu`` (sensor_msgs/Imu): the input rates and specific force (m/s^2,
  also from an IMU that reads g) with the orientation filled (gravity-aligned
  attitude; yaw is not meaningful and has a huge covariance). When a mounting
  rotation is set, vectors and orientation are expressed in ``base_frame``.
- ``tilt/fall_alert`` (std_msgs/Bool, reliable + transient local, depth 1):
  False at the first sample, then on every change.
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray): status
  ``tilt_detection`` every ``diagnostics_period`` s of data time and on every
  alert change: level ERROR while fallen, WARN after a filter restart or
  rejected samples in the period, OK otherwise; reason and margins as values.
- ``cmd_vel`` (geometry_msgs/TwistStamped, or Twist with ``stop_message``):
  zero velocity while fallen, only with ``stop_on_alert`` (off by default; the
  seed's "cut the drive"); not even advertised without it.

Bad input: non-finite values, repeated or backwards stamps (base class),
specific force above ``max_accel``, rates above ``max_gyro`` and an all-zero
accelerometer (the estimator's :func:`common.sample_problem`, so a batch run
rejects them too) are rejected and counted; a gap above ``max_dt`` restarts the
filter from the accelerometer with a warning (the alert state is kept), and
so does a clock that jumps (the base class turns a jump into such a gap).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.geometry import quat_to_matrix
from robot_calib.methods.tilt_detection.common import TiltResult, TiltState
from robot_calib.methods.tilt_detection.params import TiltParams
from robot_calib.methods.tilt_detection.variants import make_estimator
from robot_calib.pipelines import stack_export as SE
from robot_calib.pipelines.base import InputSpec, Output, OutputSpec, Pipeline

STATUS_NAME = 'tilt_detection'

EARLY_ALERT = 0.5
"""An alert this soon (s) after the first sample may be the IMU's mounting, not a fall."""

NO_ORIENTATION = np.diag([-1.0, 0.0, 0.0])
"""Orientation covariance of an IMU message without an orientation (REP-145: element 0 = -1)."""


class TiltPipeline(Pipeline):
    """Estimate the attitude, detect falls and publish a latched alert."""

    name = 'tilt_detection'
    params_type = TiltParams
    inputs = (InputSpec('imu', 'imu', 'imu'),
              InputSpec('tf_static', '/tf_static', 'tf_static', optional=True))
    outputs = (OutputSpec('imu', 'tilt/imu', 'imu'),
               OutputSpec('fall_alert', 'tilt/fall_alert', 'bool', qos='latched'),
               OutputSpec('diagnostics', '/diagnostics', 'diagnostics'),
               OutputSpec('cmd_vel', 'cmd_vel', 'cmd_vel'),
               OutputSpec('cmd_vel_stamped', 'cmd_vel', 'cmd_vel_stamped'))
    max_gap = 0.5
    live_params = ('fall_angle', 'fall_min_duration', 'clear_angle', 'clear_duration',
                   'diagnostics_period')

    def __init__(self, params: Optional[TiltParams] = None, log: Any = None):
        """Create the estimator from ``params`` (defaults when None)."""
        super().__init__(params, log)
        self.est = make_estimator(self.params)
        self.last: Optional[TiltState] = None
        self._first = True
        self._t_first: Optional[float] = None
        self.mounting_caveat = ''
        """Said when the alert came with the first samples and no IMU mounting is known."""
        self._mount_updates = 0
        self._last_diag: Optional[float] = None
        self._rejected_at_diag = 0
        self._restarts_at_diag = 0
        self._last_stop: Optional[float] = None
        self._reason = 'upright'
        rp = 0.02 ** 2 if self.params.mode == 'improved' else 0.05 ** 2
        self._cov = np.diag([rp, rp, 1e3])
        self._units_told = self.est.accel_units

    # -- configuration -----------------------------------------------------------------------
    def on_static_transform(self, transform: T.StaticTransform) -> None:
        """Forward a static transform to the estimator (base_frame -> IMU frame: the mounting)."""
        self.est.set_mounting(transform)
        self._log_mounting()

    def _log_mounting(self) -> None:
        """Log the mounting when a static transform has just set it."""
        r = self.est.result()
        if r.mounting_updates == self._mount_updates:
            return
        self._mount_updates = r.mounting_updates
        self.log('info', f'IMU mounting from /tf_static {self.params.base_frame} -> '
                 f'{r.imu_frame}: q = ({", ".join(f"{v:.4f}" for v in r.mounting)})')

    # -- samples ---------------------------------------------------------------------------
    def input_notes(self) -> Any:
        """Return the estimator's standing warnings about its input."""
        return self.est.input_notes

    def handle(self, key: str, sample: Any) -> list[Output]:
        """Process one IMU sample; return tilt/imu plus alert, diagnostics and stop outputs."""
        if key != 'imu':
            return []
        p = self.params
        s = self.est.update(sample)
        if s is None:  # (common.sample_problem: the estimator's own check, in batch runs too)
            return self.reject(key, self.est.rejection)
        if self.est.accel_units != self._units_told:
            self._tell_units()
        if self._first:
            self._log_mounting()
        if s.restart_gap is not None:
            self.log('warn', f'IMU gap of {s.restart_gap:.2f} s (> max_dt {p.max_dt} s): '
                     'attitude filter restarted from the accelerometer')
        self.last = s
        if self._t_first is None:
            self._t_first = sample.t
        stamp = T.stamp_of(sample.t, sample.stamp_ns)
        outs: list[Output] = [('imu', self._imu_out(sample, s, stamp))]
        if s.changed or self._first:
            if s.changed:
                self._on_change(s)
            outs.append(('fall_alert', T.BoolSample(sample.t, s.alert, stamp)))
        if s.changed or self._first or self._last_diag is None \
                or sample.t - self._last_diag >= p.diagnostics_period:
            outs.append(('diagnostics', self._diagnostics(s, stamp)))
            self._last_diag = sample.t
        if p.stop_on_alert and s.alert and (self._last_stop is None or s.changed
                                            or sample.t - self._last_stop >= 0.05):
            outs.append(self._stop(sample.t, stamp))
            self._last_stop = sample.t
        self._first = False
        return outs

    def _tell_units(self) -> None:
        """Log the accelerometer units once they are detected, and a missing gravity."""
        units = self._units_told = self.est.accel_units
        if units == 'detected_g':
            self.log('warn', f'IMU acceleration is in g (|a| median '
                     f'{self.est.accel_norm_median:.3f}): multiplied by 9.81 (set accel_units)')
        elif units == 'no_gravity':
            self.log('error', self._no_gravity())

    def _no_gravity(self) -> str:
        """Return what a missing gravity in the accelerometer means for the outputs."""
        return (f'the accelerometer reads no gravity (|a| median '
                f'{self.est.accel_norm_median:.3f}, neither 9.81 m/s^2 nor 1 g; gravity '
                'removed by the driver?): the tilt cannot be estimated, no fall alert is '
                'raised and the orientation is published as unknown')

    def _imu_out(self, sample: T.ImuSample, s: TiltState, stamp: int) -> T.ImuSample:
        """Return the sample with the attitude filled (in the base frame when mounted)."""
        if self._units_told == 'no_gravity':  # REP-145: covariance[0] = -1, no orientation
            return dataclasses.replace(sample, orientation=np.array([1.0, 0.0, 0.0, 0.0]),
                                       orientation_cov=NO_ORIENTATION, stamp_ns=stamp)
        if not s.mounted:
            accel_cov = sample.accel_cov
            k = self.est.accel_scale
            if k != 1.0 and accel_cov is not None:  # an IMU in g: m/s^2 out, and its variance
                accel_cov = np.asarray(accel_cov, dtype=float) * (k * k)
            return T.ImuSample(sample.t, sample.gyro, s.accel, sample.frame_id,
                               np.array(s.quat), self._cov, sample.gyro_cov, accel_cov, stamp)
        return T.ImuSample(sample.t, s.gyro, s.accel, s.frame_id, np.array(s.quat), self._cov,
                           None, None, stamp)

    def _on_change(self, s: TiltState) -> None:
        """Log an alert change and keep its reason for the diagnostics."""
        p = self.params
        if s.alert:
            self._reason = (f'fallen: tilt {math.degrees(s.tilt):.1f} deg above fall_angle '
                            f'{math.degrees(p.fall_angle):.1f} deg for '
                            f'>= {p.fall_min_duration:.3f} s')
            if s.t - self._t_first <= EARLY_ALERT and \
                    self.est.result().mounting_source == 'none':
                self.mounting_caveat = (
                    'the alert came with the first samples and no IMU mounting is known '
                    '(mounting_rpy or /tf_static): an IMU mounted rotated on an upright robot '
                    'reads the same; give its mounting if so')
                self._reason += '; ' + self.mounting_caveat
            self.log('warn', f'FALL ALERT at t = {s.t:.3f} s: {self._reason}')
        else:
            self._reason = (f'upright again: tilt below clear_angle '
                            f'{math.degrees(p.effective_clear_angle()):.1f} deg for '
                            f'{p.clear_duration:.2f} s')
            self.log('info', f'fall alert cleared at t = {s.t:.3f} s')

    def apply_params(self, params: TiltParams) -> None:
        """Take new alert thresholds and diagnostics period while running."""
        super().apply_params(params)
        self.est.set_alert_params(params)

    def active_outputs(self) -> tuple[OutputSpec, ...]:
        """Return the outputs to advertise: the stop command only with ``stop_on_alert``."""
        p = self.params
        stop = ('cmd_vel_stamped' if p.stop_message == 'TwistStamped' else 'cmd_vel') \
            if p.stop_on_alert else None
        return tuple(o for o in self.outputs if o.topic != 'cmd_vel' or o.key == stop)

    def _stop(self, t: float, stamp: int) -> Output:
        if self.params.stop_message == 'TwistStamped':
            return ('cmd_vel_stamped', T.StampedTwistSample(t, 0.0, 0.0, 0.0, stamp,
                                                            self.params.base_frame))
        return ('cmd_vel', T.TwistSample(t, 0.0, 0.0, 0.0, stamp))

    def _diagnostics(self, s: TiltState, stamp: int) -> T.DiagnosticSample:
        """Return the /diagnostics status for the last sample."""
        p = self.params
        r = self.est.result()
        rejected = self.counts['imu'].get('rejected', 0)
        new_rejects = rejected - self._rejected_at_diag
        new_restarts = r.restarts - self._restarts_at_diag
        self._rejected_at_diag = rejected
        self._restarts_at_diag = r.restarts
        if s.alert:
            level, message = 2, self._reason
        elif self._units_told == 'no_gravity':
            level, message = 2, self._no_gravity()
        elif new_restarts:
            level, message = 1, 'attitude filter restarted after an IMU gap'
        elif new_rejects:
            level, message = 1, f'{new_rejects} IMU sample(s) rejected'
        else:
            level, message = 0, 'upright'
        deg = math.degrees
        values = (
            ('alert', str(s.alert).lower()),
            ('reason', self._reason),
            ('mode', p.mode),
            ('tilt_deg', f'{deg(s.tilt):.2f}'),
            ('roll_deg', f'{deg(s.roll):.2f}'),
            ('pitch_deg', f'{deg(s.pitch):.2f}'),
            ('fall_angle_deg', f'{deg(p.fall_angle):.2f}'),
            ('clear_angle_deg', f'{deg(p.effective_clear_angle()):.2f}'),
            ('margin_to_fall_deg', f'{deg(p.fall_angle - s.tilt):.2f}'),
            ('margin_to_clear_deg', f'{deg(p.effective_clear_angle() - s.tilt):.2f}'),
            ('alert_episodes', str(len(r.alert_episodes))),
            ('gyro_bias_rad_s', ' '.join(f'{b:.5f}' for b in s.bias)),
            ('at_rest', str(s.rest).lower()),
            ('mounting', r.mounting_source),
            ('accel_units', r.accel_units),
            ('filter_restarts', str(r.restarts)),
            ('samples_rejected', str(rejected)),
        )
        return T.DiagnosticSample(s.t, (T.DiagnosticStatus(STATUS_NAME, level, message,
                                                           r.imu_frame or '', values),),
                                  stamp)

    # -- results ---------------------------------------------------------------------------
    @staticmethod
    def headline(summary: dict[str, Any]) -> dict[str, Any]:
        """Return the fall alerts, the largest tilt (deg) and the gyro bias per axis (rad/s)."""
        out = {'alerts': summary.get('alerts', 0), 'max_tilt_deg': summary.get('max_tilt_deg')}
        for axis, value in zip('xyz', summary.get('gyro_bias') or ()):
            out[f'gyro_bias_{axis}'] = value
        return out

    def method_summary(self) -> dict[str, Any]:
        """Return alert episodes, final state, restarts and the gyro bias for summary.json."""
        r: TiltResult = self.est.result()
        known = r.accel_units != 'no_gravity'  # else the angles are not estimates
        return {
            'mode': self.params.mode,
            'alerts': len(r.alert_episodes),
            'alert_episodes': [{'start': a, 'end': b} for a, b in r.alert_episodes],
            'alert_active': r.alert,
            'final_tilt_deg': math.degrees(r.tilt) if r.tilt is not None and known else None,
            'max_tilt_deg': math.degrees(r.max_tilt) if known else None,
            'gyro_bias': list(r.bias) if r.bias is not None else None,
            'gyro_scale': list(r.scale) if r.scale is not None else None,
            'filter_restarts': r.restarts,
            'mounting': r.mounting_source,
            'mounting_quat': list(r.mounting),
            **({'mounting_caveat': self.mounting_caveat} if self.mounting_caveat else {}),
            'accel_units': r.accel_units,
        }

    def stack_export(self) -> SE.StackFiles:
        """Return the IMU mounting the tilt node used (static transform, URDF joint)."""
        r: TiltResult = self.est.result()
        base = self.params.base_frame
        known = r.mounting_source in ('parameter', '/tf_static')
        source = f'/tf_static ({base} -> {r.imu_frame})' if r.mounting_source == '/tf_static' \
            else 'the mounting_rpy parameter'
        tf = self.static_mounting(r.imu_frame, base)
        return SE.imu_mounting_files(
            'imu_tilt', self.name, self.recording, base, r.imu_frame,
            quat_to_matrix(np.asarray(r.mounting, dtype=float)) if known else None, source,
            None if tf is None else tf.translation)


PIPELINE = TiltPipeline
