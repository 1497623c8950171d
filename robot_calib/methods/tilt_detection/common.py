# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What both tilt variants share: quaternion helpers on floats, the fall detector, the result types.

:class:`TiltBase` is the Estimator (:mod:`robot_calib.core.estimator`) both
variants derive from: the IMU mounting, gaps, the maximum tilt and the latched
fall alert (:class:`FallDetector`: the angle between the body z axis, i.e.
``base_link`` after the mounting rotation, and world up, with a threshold, a
minimum duration, hysteresis and a clear time). A variant supplies the
attitude filter (:meth:`TiltBase._attitude`).

Units: time s, rates rad/s, specific force m/s^2, angles rad. Quaternions are
``(w, x, y, z)``, sensor-to-earth.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
import math
from typing import Any, Optional, Sequence

import numpy as np

from robot_calib.core import types as T
from robot_calib.methods.tilt_detection.params import TiltParams


# --------------------------------------------------------------------------------------------
# Small quaternion helpers on Python floats (fast for one sample at a time)
# --------------------------------------------------------------------------------------------
def qmul(a: tuple, b: tuple) -> tuple:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def qrot(q: tuple, x: float, y: float, z: float) -> tuple:
    """Rotate (x, y, z) by unit quaternion q: R(q) v."""
    w, a, b, c = q
    # t = 2 * (q_vec x v); v' = v + w t + q_vec x t
    tx = 2.0 * (b * z - c * y)
    ty = 2.0 * (c * x - a * z)
    tz = 2.0 * (a * y - b * x)
    return (x + w * tx + b * tz - c * ty,
            y + w * ty + c * tx - a * tz,
            z + w * tz + a * ty - b * tx)


def qnorm(q: tuple) -> tuple:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def align_up(x: float, y: float, z: float) -> tuple:
    """Return the smallest rotation taking unit vector (x, y, z) to (0, 0, 1)."""
    if z > -0.999999:
        s = math.sqrt(2.0 * (1.0 + z))
        return (0.5 * s, y / s, -x / s, 0.0)
    return (0.0, 1.0, 0.0, 0.0)  # upside down: half turn about x


def quat_from_rpy_tuple(roll: float, pitch: float, yaw: float) -> tuple:
    """Return (w, x, y, z) of R = Rz(yaw) Ry(pitch) Rx(roll) (rad) as a tuple."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def tilt_of(q: tuple) -> float:
    """Return the tilt (rad, [0, pi]) of sensor-to-earth quaternion q: body z vs world up."""
    c = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])
    return math.acos(-1.0 if c < -1.0 else (1.0 if c > 1.0 else c))


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
# Results and the shared estimator
# --------------------------------------------------------------------------------------------
@dataclass
class TiltState:
    """
    The result of one sample.

    ``quat`` is base_link-to-earth (w, x, y, z; yaw not meaningful), ``tilt``
    the angle between base_link z and up (rad), ``roll``/``pitch`` (rad),
    ``alert`` the latched fall alert, ``changed`` True when the alert changed
    on this sample, ``bias`` the gyro bias estimate (rad/s, IMU frame),
    ``rest`` whether the IMU is at rest.
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
    restart_gap: float = 0.0
    """The gap (s) after which this sample restarted the attitude filter; 0 when it did not."""


@dataclass(frozen=True)
class TiltResult:
    """
    Everything estimated so far.

    ``state`` is the last sample's :class:`TiltState` (None before the first),
    ``max_tilt`` the largest decision angle seen (rad: the tilt, or for the
    seed the larger of |roll| and |pitch|), ``mounting`` the IMU frame in
    base_link (w, x, y, z), ``gyro_scale`` the estimated gyro scale errors
    (improved variant only).
    """

    state: Optional[TiltState]
    last_t: Optional[float]
    restarts: int
    max_tilt: float
    alert_episodes: int
    mounting: tuple
    gyro_scale: Optional[tuple] = None


class TiltBase(abc.ABC):
    """
    Streaming tilt estimation and fall detection (an Estimator); variants supply the filter.

    The caller validates samples (finite, in range, increasing stamps); gaps
    longer than ``max_dt`` restart the attitude filter from the accelerometer.
    """

    def __init__(self, params: Optional[TiltParams] = None, ts: float = 0.005):
        """Create the estimator with ``params`` and a nominal sampling period ``ts`` (s)."""
        self.params = params if params is not None else TiltParams()
        p = self.params
        self.mount = quat_from_rpy_tuple(*p.mounting_rpy)   # IMU frame in base_link
        self.detector = FallDetector(p.fall_angle, p.fall_min_duration,
                                     p.effective_clear_angle(), p.clear_duration)
        self.ts = ts
        self.last_t: Optional[float] = None
        self.restarts = 0
        self.max_tilt = 0.0
        self.last: Optional[TiltState] = None

    # -- the variant's part ----------------------------------------------------------------
    @abc.abstractmethod
    def _attitude(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
                  dt: float) -> tuple:
        """Return (base_link-to-earth quaternion, bias, at rest) after one sample."""

    @abc.abstractmethod
    def _decision(self, q: tuple, tilt: float) -> tuple:
        """Return (roll, pitch, the angle the fall decision uses) for attitude ``q``."""

    @abc.abstractmethod
    def _reset_filter(self) -> None:
        """Forget the attitude filter's state."""

    def _gyro_scale(self) -> Optional[tuple]:
        return None

    # -- the Estimator API -----------------------------------------------------------------
    def set_mounting(self, transform: T.StaticTransform) -> None:
        """Take the IMU mounting rotation from a static transform base_link -> IMU frame."""
        self.mount = qnorm(tuple(float(v) for v in transform.rotation))

    def reset(self) -> None:
        """Restart the attitude filter from the next sample (the alert state is kept)."""
        self._reset_filter()
        self.detector.interrupt()
        self.last_t = None
        self.restarts += 1

    def update(self, sample: T.ImuSample) -> TiltState:
        """Process one IMU sample (gyro rad/s, specific force m/s^2, IMU frame)."""
        return self.step(sample.t, sample.gyro, sample.accel)

    def step(self, t: float, gyro: Any, accel: Any) -> TiltState:
        """Process one IMU sample: time (s), gyro (rad/s) and specific force (m/s^2)."""
        gx, gy, gz = float(gyro[0]), float(gyro[1]), float(gyro[2])
        ax, ay, az = float(accel[0]), float(accel[1]), float(accel[2])
        dt = self.ts if self.last_t is None else t - self.last_t
        gap = 0.0
        if dt > self.params.max_dt:
            self.reset()
            gap, dt = dt, self.ts
        self.last_t = t
        q, bias, rest = self._attitude(gx, gy, gz, ax, ay, az, dt)
        if q[0] < 0.0:
            q = (-q[0], -q[1], -q[2], -q[3])
        tilt = tilt_of(q)
        roll, pitch, decision = self._decision(q, tilt)
        if decision > self.max_tilt:
            self.max_tilt = decision
        changed = self.detector.update(t, decision)
        self.last = TiltState(t, q, tilt, self.detector.alert, changed is not None, roll, pitch,
                              bias, rest, gap)
        return self.last

    def result(self) -> TiltResult:
        """Return the last state, restarts, maximum tilt, alert episodes and mounting."""
        return TiltResult(self.last, self.last_t, self.restarts, self.max_tilt,
                          self.detector.episodes, tuple(self.mount), self._gyro_scale())


def stack_states(states: Sequence[TiltState]) -> dict[str, np.ndarray]:
    """
    Return the per-sample states of a run as arrays.

    ``quat`` (N, 4) base_link-to-earth (w, x, y, z), ``tilt`` (N,) rad, ``alert``
    (N,) bool, ``bias`` (N, 3) rad/s.
    """
    n = len(states)
    return {'quat': np.array([s.quat for s in states], dtype=float).reshape(n, 4),
            'tilt': np.array([s.tilt for s in states], dtype=float),
            'alert': np.array([s.alert for s in states], dtype=bool),
            'bias': np.array([s.bias for s in states], dtype=float).reshape(n, 3)}
