# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What both ``tilt_detection`` variants share: fall detector, outputs, result, streaming frame.

:class:`TiltEstimatorBase` implements the :class:`robot_calib.core.estimator.Estimator`
protocol once: IMU mounting (``mounting_rpy`` or a static transform
``base_frame -> IMU frame``, through :mod:`robot_calib.core.frames`), sample
spacing and gap restarts, the latched fall alert (:class:`FallDetector`) and
its episodes, the per-sample output :class:`TiltState` and the frozen
:class:`TiltResult`. A variant (:mod:`.seed`, :mod:`.improved`) supplies the
attitude filter through ``_estimate`` and ``_restart_filter``.

Units: time s, rates rad/s, specific force m/s^2, angles rad. Quaternions are
``(w, x, y, z)``.
"""

from __future__ import annotations

import abc
import dataclasses
from dataclasses import dataclass, field
import math
from typing import Any, ClassVar, Optional

import numpy as np

from robot_calib.core.constants import GRAVITY
from robot_calib.core.frames import find_mounting, rotation_matrix, StaticTree
from robot_calib.core.geometry import quat_tuple_from_rpy, same_rotation
from robot_calib.core.imu_units import accel_units_of, UNITS_SAMPLES
from robot_calib.core.notes import InputNotes
from robot_calib.core.types import ImuSample, StaticTransform
from robot_calib.methods.tilt_detection.params import TiltParams
from robot_calib.methods.tilt_detection.quaternion import IDENTITY, qnorm

NOMINAL_PERIOD = 0.005
"""Sampling period assumed before the first sample interval is known (s)."""

ZERO_ACCEL2 = 1e-12
"""A squared specific force below this ((m/s^2)^2 or g^2) is an all-zero accelerometer."""


def sample_problem(t: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
                   params: TiltParams) -> Optional[str]:
    """
    Return why an IMU sample is rejected, or None: the one check of every path.

    Time ``t`` (s), rates (rad/s) and specific force (as read, before any unit
    scale). Reasons: ``non_finite``, ``accel_out_of_range`` (norm above
    ``max_accel``), ``accel_zero`` (an all-zero accelerometer: no direction of
    gravity), ``gyro_out_of_range`` (norm above ``max_gyro``).
    """
    a2 = ax * ax + ay * ay + az * az
    g2 = gx * gx + gy * gy + gz * gz
    if not math.isfinite(a2 + g2 + t) and not all(
            math.isfinite(v) for v in (t, gx, gy, gz, ax, ay, az)):
        return 'non_finite'
    if a2 > params.max_accel * params.max_accel:
        return 'accel_out_of_range'
    if a2 < ZERO_ACCEL2:
        return 'accel_zero'
    if g2 > params.max_gyro * params.max_gyro:
        return 'gyro_out_of_range'
    return None


# --------------------------------------------------------------------------------------------
# Fall detector
# --------------------------------------------------------------------------------------------
class FallDetector:
    """
    Latched fall alert with threshold, minimum duration, hysteresis and clear time.

    Raised when the tilt (rad) stays above ``fall_angle`` for ``min_duration``
    seconds; cleared when it stays below ``clear_angle`` for ``clear_duration``.
    """

    def __init__(self, fall_angle: float, min_duration: float, clear_angle: float,
                 clear_duration: float):
        """Create the detector (angles rad, durations s)."""
        self.fall_angle = fall_angle
        self.min_duration = min_duration
        self.clear_angle = clear_angle
        self.clear_duration = clear_duration
        self.alert = False
        self._above_since: Optional[float] = None
        self._below_since: Optional[float] = None
        self.episodes = 0
        self.last_change_t: Optional[float] = None

    def update(self, t: float, tilt: float) -> Optional[bool]:
        """Feed the tilt (rad) at time ``t`` (s); return the new alert state when it changes."""
        if not self.alert:
            if tilt > self.fall_angle:
                if self._above_since is None:
                    self._above_since = t
                if t - self._above_since >= self.min_duration - 1e-9:
                    self.alert = True
                    self._below_since = None
                    self.episodes += 1
                    self.last_change_t = t
                    return True
            else:
                self._above_since = None
            return None
        if tilt < self.clear_angle:
            if self._below_since is None:
                self._below_since = t
            if t - self._below_since >= self.clear_duration - 1e-9:
                self.alert = False
                self._above_since = None
                self.last_change_t = t
                return False
        else:
            self._below_since = None
        return None

    def interrupt(self) -> None:
        """Forget partial timing (after a gap or a filter restart); the alert itself stays."""
        self._above_since = None
        self._below_since = None


# --------------------------------------------------------------------------------------------
# Outputs
# --------------------------------------------------------------------------------------------
@dataclass
class TiltState:
    """
    What :meth:`TiltEstimatorBase.update` returns for one sample.

    ``quat`` is base_link-to-earth (w, x, y, z; yaw not meaningful), ``tilt``
    the angle between base_link z and up (rad), ``roll``/``pitch`` (rad),
    ``alert`` the latched fall alert, ``changed`` True when the alert changed
    on this sample, ``bias`` the gyro bias estimate (rad/s, IMU frame),
    ``rest`` True while the IMU counts as still. ``restart_gap`` is the gap
    (s) that restarted the filter on this sample (None otherwise).
    ``gyro`` (rad/s) and ``accel`` (m/s^2, an IMU in g scaled) are the
    sample's vectors in ``frame_id``: the base frame when ``mounted`` (a
    mounting rotation that is not the identity), else the IMU frame.
    """

    t: float
    quat: tuple
    tilt: float
    alert: bool
    changed: bool = False
    roll: float = 0.0
    pitch: float = 0.0
    bias: tuple = (0.0, 0.0, 0.0)
    rest: bool = False
    restart_gap: Optional[float] = None
    gyro: Any = None
    accel: Any = None
    frame_id: str = ''
    mounted: bool = False


@dataclass(frozen=True)
class TiltResult:
    """
    Everything a ``tilt_detection`` estimator has estimated so far.

    ``t``, ``quat``, ``tilt``, ``roll``, ``pitch``, ``bias`` and ``rest`` are
    those of the last sample (None before the first one); ``alert`` is the
    latched fall alert, ``alert_episodes`` its (start s, end s or None while
    raised) pairs, ``max_tilt`` the largest fall decision value seen (rad: the
    tilt, or for the seed max(|roll|, |pitch|)), ``restarts`` the filter
    restarts after gaps. ``scale`` are the gyro scale-factor errors (relative;
    None for the seed), ``rest_snaps`` the restarts of the acceleration filter
    at rest (improved only). ``mounting`` is the IMU frame in base_link (w, x,
    y, z), ``mounting_source`` 'none', 'parameter' or '/tf_static',
    ``mounting_updates`` how often a static transform set it, ``imu_frame``
    the frame of the samples (None before the first one), ``accel_units`` the
    accelerometer's units as given or detected (``no_gravity``: no tilt known),
    ``rejected`` the samples turned down by reason (:func:`sample_problem`,
    ``duplicate_stamp``, ``out_of_order``).
    """

    mode: str
    samples: int
    t: Optional[float]
    quat: Optional[tuple]
    tilt: Optional[float]
    roll: Optional[float]
    pitch: Optional[float]
    bias: Optional[tuple]
    rest: bool
    alert: bool
    alert_episodes: tuple
    max_tilt: float
    restarts: int
    scale: Optional[tuple]
    rest_snaps: int
    mounting: tuple
    mounting_source: str
    mounting_updates: int
    imu_frame: Optional[str]
    accel_units: str = 'mps2'
    rejected: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# Batch helpers
# --------------------------------------------------------------------------------------------
def nominal_period(t: Any) -> float:
    """Return the median sample interval (s) of sample times ``t`` (s), 0.005 s for < 2."""
    t = np.asarray(t, dtype=float)
    return float(np.median(np.diff(t))) if t.size > 1 else NOMINAL_PERIOD


# --------------------------------------------------------------------------------------------
# The streaming frame both variants share
# --------------------------------------------------------------------------------------------
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


def outputs_as_arrays(outputs: list[Optional[TiltState]]) -> dict[str, np.ndarray]:
    """
    Return per-sample outputs as arrays, one row per entry of ``outputs``.

    ``quat`` (N, 4) base_link-to-earth (w, x, y, z), ``tilt`` (N,) rad,
    ``alert`` (N,) bool, ``bias`` (N, 3) rad/s, ``rest`` (N,) bool. A None entry
    (a rejected sample) gives NaN in ``quat``, ``tilt`` and ``bias``, ``rest``
    False and the alert as it stood.
    """
    n = len(outputs)
    if any(o is None for o in outputs):
        nan = math.nan
        gap = TiltState(nan, (nan, nan, nan, nan), nan, False, bias=(nan, nan, nan))
        filled, alert = [], False
        for o in outputs:
            if o is None:
                o = dataclasses.replace(gap, alert=alert)
            alert = o.alert
            filled.append(o)
        outputs = filled
    return {'quat': np.array([o.quat for o in outputs]).reshape(n, 4),
            'tilt': np.array([o.tilt for o in outputs], dtype=float),
            'alert': np.array([o.alert for o in outputs], dtype=bool),
            'rest': np.array([o.rest for o in outputs], dtype=bool),
            'bias': np.array([o.bias for o in outputs], dtype=float).reshape(n, 3)}
