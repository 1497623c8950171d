# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The variant base of ``tilt_detection``: the streaming frame both estimators build on.

:class:`TiltEstimatorBase` implements the :class:`robot_calib.core.estimator.Estimator`
protocol once (sample checks, IMU units, mounting, restarts, fall detection);
a variant supplies the attitude filter. The shared types are in :mod:`.common`.

Units: time s, rates rad/s, specific force m/s^2, angles rad.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar, Optional

import numpy as np

from robot_calib.core.constants import GRAVITY
from robot_calib.core.frames import find_mounting, rotation_matrix, StaticTree
from robot_calib.core.geometry import quat_tuple_from_rpy, same_rotation
from robot_calib.core.imu_units import accel_units_of, UNITS_SAMPLES
from robot_calib.core.notes import InputNotes
from robot_calib.core.types import ImuSample, StaticTransform
from robot_calib.methods.tilt_detection.common import (FallDetector, NOMINAL_PERIOD,
                                                       sample_problem, TiltResult, TiltState)
from robot_calib.methods.tilt_detection.params import TiltParams
from robot_calib.methods.tilt_detection.quaternion import IDENTITY, qnorm


class TiltEstimatorBase(abc.ABC):
    """
    Streaming tilt estimation and fall detection (the Estimator protocol); variants subclass.

    A sample :func:`sample_problem` names, or whose stamp repeats or goes back
    (by up to ``max_dt``), is rejected: :meth:`update` returns None and
    :attr:`rejection` says why (what the live pipeline rejects, so a batch run
    over raw data does too). Gaps longer than ``max_dt``, and steps back by
    more (a clock that jumped), restart the attitude filter from the
    accelerometer (the alert and the gyro bias are kept). With ``accel_units: auto`` the first
    sample's |a| tells the units (about 9.81: m/s^2, about 1: g); otherwise the
    median of the first ``UNITS_SAMPLES``, and when neither (a driver that took
    gravity out) ``accel_units`` is ``'no_gravity'``: the accelerometer cannot
    tell up, so no fall alert is raised (the caller says so). No alert is raised
    while the units are undecided.
    """

    mode: ClassVar[str] = ''
    """The value of ``TiltParams.mode`` that selects the variant."""

    def __init__(self, params: Optional[TiltParams] = None, ts: float = NOMINAL_PERIOD):
        """Create the estimator with ``params`` and a nominal sampling period ``ts`` (s)."""
        self.params = params if params is not None else TiltParams()
        p = self.params
        self.ts = ts
        self._transforms = StaticTree()
        self._imu_frame: Optional[str] = None
        self.input_notes = InputNotes()
        """Standing warnings about the input (an IMU frame not in the tree)."""
        self._mount_source = 'parameter' if any(p.mounting_rpy) else 'none'
        self._mount_updates = 0
        self._set_mount(quat_tuple_from_rpy(*p.mounting_rpy))
        self.reset()

    # -- the Estimator protocol ------------------------------------------------------------
    def set_mounting(self, transform: StaticTransform) -> None:
        """
        Take a static transform; ``base_frame`` -> IMU frame (through any chain) is the mounting.

        Kept only with ``use_tf_static``; it applies once samples come in its
        child frame (at once when they already do).
        """
        p = self.params
        if not p.use_tf_static:
            return
        self._transforms.add(transform)
        if self._imu_frame is not None:
            mounting = self._find_mounting(self._imu_frame)
            if mounting is not None:
                self._apply_transform(mounting)

    def _find_mounting(self, frame: str) -> Optional[StaticTransform]:
        """Return the mounting of IMU frame ``frame`` by the one rule of every node, or None."""
        p = self.params
        fallback = (f'the mounting_rpy parameter used ({list(p.mounting_rpy)} rad)'
                    if any(p.mounting_rpy) else
                    f'the IMU taken as level in {p.base_frame} (set mounting_rpy)')
        found = find_mounting(self._transforms, frame, p.base_frame, 'imu', fallback)
        self.input_notes.say('imu', found.note)
        return found.transform

    def set_alert_params(self, params: TiltParams) -> None:
        """
        Take new alert thresholds (``fall_angle``, ``fall_min_duration``, ``clear_*``) live.

        The attitude, the alert state and its timers are kept; the next sample
        is judged against the new thresholds.
        """
        self.params = params
        d = self._detector
        d.fall_angle, d.min_duration = params.fall_angle, params.fall_min_duration
        d.clear_angle, d.clear_duration = params.effective_clear_angle(), params.clear_duration

    def reset(self) -> None:
        """Forget the attitude, the alert and its history; keep parameters and mountings."""
        p = self.params
        self._detector = FallDetector(p.fall_angle, p.fall_min_duration,
                                      p.effective_clear_angle(), p.clear_duration)
        self._episodes: list[tuple[float, Optional[float]]] = []
        self._last_t: Optional[float] = None
        self._last: Optional[TiltState] = None
        self._samples = 0
        self._restarts = 0
        self._rejected: dict[str, int] = {}
        self.rejection = ''
        """Why the last sample :meth:`update` turned down was rejected."""
        self._max_tilt = 0.0
        scale = {'mps2': 1.0, 'g': GRAVITY}.get(p.accel_units)
        self._accel_scale: Optional[float] = scale
        self._alerts_on = scale is not None
        self.accel_units = p.accel_units if scale is not None else 'pending'
        """'mps2' or 'g' (given), 'detected_mps2', 'detected_g', 'no_gravity' or 'pending'."""
        self.accel_norm_median: Optional[float] = None
        self._norms: list[float] = []
        self._new_filter()

    def update(self, sample: ImuSample) -> Optional[TiltState]:
        """
        Process one IMU sample: time (s), gyro (rad/s) and specific force (m/s^2 or g).

        Return the state after it, or None when it is rejected (see :attr:`rejection`).
        """
        g = sample.gyro
        a = sample.accel
        gx, gy, gz = float(g[0]), float(g[1]), float(g[2])
        ax, ay, az = float(a[0]), float(a[1]), float(a[2])
        t = sample.t
        problem = sample_problem(t, gx, gy, gz, ax, ay, az, self.params)
        last_t = self._last_t
        if problem is None and last_t is not None and t <= last_t \
                and t >= last_t - self.params.max_dt:
            problem = 'duplicate_stamp' if t == last_t else 'out_of_order'
        if problem is not None:
            self.rejection = problem
            self._rejected[problem] = self._rejected.get(problem, 0) + 1
            return None
        scale = self._accel_scale
        if scale != 1.0:
            if scale is None:
                scale = self._detect_units(ax, ay, az)
            ax, ay, az = ax * scale, ay * scale, az * scale
        if self._imu_frame is None:
            self._imu_frame = sample.frame_id
            transform = self._find_mounting(sample.frame_id) if self.params.use_tf_static \
                else None
            if transform is not None:
                self._apply_transform(transform)
        dt = self.ts if last_t is None else t - last_t
        gap = None
        if dt > self.params.max_dt or dt < 0.0:
            gap = dt
            self._restart()
            dt = self.ts
        self._last_t = t
        q, tilt, roll, pitch, bias, rest, decision = self._estimate(gx, gy, gz, ax, ay, az, dt)
        if decision > self._max_tilt:
            self._max_tilt = decision
        changed = self._detector.update(t, decision) if self._alerts_on else None
        if changed is True:
            self._episodes.append((t, None))
        elif changed is False and self._episodes:
            self._episodes[-1] = (self._episodes[-1][0], t)
        state = TiltState(t, q, tilt, self._detector.alert, changed is not None, roll, pitch,
                          bias, rest, gap, *self._in_base_frame(sample, scale))
        self._last = state
        self._samples += 1
        return state

    def result(self) -> TiltResult:
        """Return the estimates so far (see :class:`TiltResult`)."""
        s = self._last
        return TiltResult(
            mode=self.mode, samples=self._samples,
            t=s.t if s else None, quat=s.quat if s else None, tilt=s.tilt if s else None,
            roll=s.roll if s else None, pitch=s.pitch if s else None,
            bias=s.bias if s else None, rest=s.rest if s else False,
            alert=self._detector.alert, alert_episodes=tuple(self._episodes),
            max_tilt=self._max_tilt, restarts=self._restarts, scale=self._gyro_scale(),
            rest_snaps=self._rest_snaps(), mounting=self._mount,
            mounting_source=self._mount_source, mounting_updates=self._mount_updates,
            imu_frame=self._imu_frame, accel_units=self.accel_units,
            rejected=dict(self._rejected))

    @property
    def accel_scale(self) -> float:
        """Return the factor (m/s^2 per unit read) applied to the specific force: 9.81 for g."""
        return self._accel_scale if self._accel_scale is not None else 1.0

    # -- what a variant supplies -----------------------------------------------------------
    @abc.abstractmethod
    def _new_filter(self) -> None:
        """Create the attitude filter from scratch."""

    @abc.abstractmethod
    def _restart_filter(self) -> None:
        """Restart the attitude filter from the next sample (after a gap)."""

    @abc.abstractmethod
    def _estimate(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
                  dt: float) -> tuple:
        """
        Run the filter on one sample (IMU frame; rad/s, m/s^2, s since the previous one).

        Return (quat base_link-to-earth with w >= 0, tilt rad, roll rad, pitch
        rad, gyro bias rad/s, at rest, fall decision value rad).
        """

    def _gyro_scale(self) -> Optional[tuple]:
        """Return the gyro scale-factor errors (relative), None when not estimated."""
        return None

    def _rest_snaps(self) -> int:
        """Return how often the filter restarted from the mean reading at rest."""
        return 0

    # -- internals -------------------------------------------------------------------------
    def _detect_units(self, ax: float, ay: float, az: float) -> float:
        """Judge the units from the first samples; return the scale to m/s^2 meanwhile."""
        norm = math.sqrt(ax * ax + ay * ay + az * az)
        units = accel_units_of(norm) if not self._norms else ''
        self._norms.append(norm)
        if not units and len(self._norms) >= UNITS_SAMPLES:
            norm = float(np.median(self._norms))
            units = accel_units_of(norm) or 'no_gravity'
        if not units:
            return 1.0
        self.accel_norm_median = norm
        self.accel_units = 'detected_' + units if units != 'no_gravity' else units
        self._accel_scale = GRAVITY if units == 'g' else 1.0
        self._alerts_on = units != 'no_gravity'
        if len(self._norms) > 1:
            self._restart_filter()  # what it saw before the units were known is dropped
        self._norms = []
        return self._accel_scale

    def _restart(self) -> None:
        """Restart the attitude filter after a gap (the alert state is kept)."""
        self._restart_filter()
        self._detector.interrupt()
        self._last_t = None
        self._restarts += 1

    def _set_mount(self, q: tuple) -> None:
        """Set the mounting rotation (IMU frame in base_link, unit (w, x, y, z))."""
        self._mount = q
        self._mount_conj = (q[0], -q[1], -q[2], -q[3])
        self._mounted = q != IDENTITY
        self._mount_matrix = None
        if self._mounted:
            transform = StaticTransform(self.params.base_frame, self._imu_frame or '',
                                        np.zeros(3), np.array(q))
            self._mount_matrix = rotation_matrix(transform)

    def _apply_transform(self, transform: StaticTransform) -> None:
        """
        Take the rotation of a static transform base_frame -> IMU frame as the mounting.

        A rotation the same as the one from /tf_static in use (compared as
        rotations: :func:`robot_calib.core.geometry.same_rotation`) changes nothing.
        """
        q = tuple(float(v) for v in transform.rotation)
        if self._mount_source == '/tf_static' and same_rotation(q, self._mount):
            return
        self._set_mount(qnorm(q))
        self._mount_source = '/tf_static'
        self._mount_updates += 1

    def _in_base_frame(self, sample: ImuSample, scale: float) -> tuple:
        """
        Return (gyro, accel, frame, mounted): the sample's vectors in the base frame.

        ``scale`` (m/s^2 per unit read) turns the specific force into m/s^2.
        """
        accel = sample.accel
        if scale != 1.0:
            accel = np.asarray(accel, dtype=float) * scale
        if not self._mounted:
            return sample.gyro, accel, sample.frame_id, False
        m = self._mount_matrix
        return (m @ np.asarray(sample.gyro, dtype=float),
                m @ np.asarray(accel, dtype=float), self.params.base_frame, True)
