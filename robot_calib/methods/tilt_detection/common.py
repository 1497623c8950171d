# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What both ``tilt_detection`` variants share: sample check, fall detector, outputs, result.

The streaming frame the variants subclass, :class:`TiltEstimatorBase`, is in
:mod:`.variant_base`; this module holds what it and the pipeline use: the one
sample check (:func:`sample_problem`), the latched fall alert
(:class:`FallDetector`), the per-sample output :class:`TiltState`, the frozen
:class:`TiltResult` and the batch helpers.

Units: time s, rates rad/s, specific force m/s^2, angles rad. Quaternions are
``(w, x, y, z)``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import math
from typing import Any, Optional

import numpy as np

from robot_calib.methods.tilt_detection.params import TiltParams

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
