# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Validation of input samples at the pipeline boundary: finite, physically plausible, sane rate.

:func:`sample_problem` names what is wrong with one sample (``'non_finite'``,
``'implausible'``, or ``'duplicate_joint'`` for a JointState naming one joint
twice: which entry is the joint's cannot be told, so the message is not
used), or returns None. The limits below are far outside what
any real sensor on a ground robot reports, so they never reject real data;
they stop corrupt or hostile values (a flipped bit, a wrong unit by orders of
magnitude, a garbage driver) before any method integrates them.

:class:`RateGuard` rejects samples that come impossibly fast for their kind
(a burst of copies at microsecond stamps), as a token bucket over the sample
stamps: a stream may run at up to :data:`MAX_RATE` on average and bunch up to
:data:`RATE_BURST` seconds' worth of samples (drivers that stamp at reception
deliver USB or network packets of several samples at once).

:func:`restamp_unset` gives samples whose driver left the header stamp unset
(0) their receive time.

Both use scalar math only on the IMU and odometry hot path.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

import numpy as np

from robot_calib.core import types as T

MAX_ANGULAR_RATE = 100.0
"""Largest plausible angular rate (rad/s, 5730 deg/s): the widest MEMS gyro range is 4000 deg/s."""
MAX_SPECIFIC_FORCE = 2000.0
"""Largest plausible specific force (m/s^2, about 200 g): the widest MEMS accelerometer range."""
QUATERNION_NORM = (0.5, 1.5)
"""Plausible norm range of a reported orientation quaternion (1 when normalised)."""
MAX_POSITION = 1e8
"""Largest plausible odometry coordinate (m); UTM northings reach 1e7 m."""
MAX_SPEED = 200.0
"""Largest plausible linear speed of a ground robot (m/s, 720 km/h)."""
MAX_SCAN_RANGE = 1e4
"""Largest plausible ``range_max`` of a 2D scan (m); long-range lidars reach about 2 km."""
MAX_SCAN_FOV = 2.0 * math.pi * 1.05
"""Largest plausible field of view of one scan, ``|angle_increment| * (beams - 1)`` (rad)."""
MAX_SCAN_DURATION = 10.0
"""Largest plausible time over one scan's beams, ``|time_increment| * (beams - 1)`` (s)."""
MAX_JOINT_POSITION = 1e9
"""Largest plausible joint position (rad, or m for a prismatic joint)."""
MAX_JOINT_VELOCITY = 1e4
"""Largest plausible joint velocity (rad/s, about 95,000 rpm)."""

MAX_RATE = {'imu': 5000.0, 'odom': 2000.0, 'joint_states': 5000.0, 'scan': 500.0,
            'cmd_vel': 2000.0, 'fix': 1000.0}
"""
Largest plausible average sample rate per input kind (Hz).

IMUs on robots publish at 50 Hz to 2 kHz (a few at 4 kHz); wheel odometry and
joint states at the controller rate, up to 1-2 kHz; 2D lidars scan at 5 to 50 Hz
(a few hundred Hz at most for scans derived from depth cameras); GNSS at up
to 100 Hz. Kinds absent here are not rate-checked.
"""
RATE_BURST = 0.01
"""Seconds' worth of samples (at :data:`MAX_RATE`) a stream may deliver at once (s)."""
_MIN_BURST = 5.0
"""Samples any stream may deliver at once, however slow its kind."""


def _imu_problem(s: T.ImuSample) -> Optional[str]:
    try:
        g0, g1, g2 = s.gyro.tolist()
        a0, a1, a2 = s.accel.tolist()
    except (AttributeError, ValueError):  # not a numpy vector of 3
        g, a = np.asarray(s.gyro, dtype=float).ravel(), np.asarray(s.accel, dtype=float).ravel()
        if g.size != 3 or a.size != 3:
            return 'implausible'
        (g0, g1, g2), (a0, a1, a2) = g.tolist(), a.tolist()
    w, f = MAX_ANGULAR_RATE, MAX_SPECIFIC_FORCE
    # NaN fails every comparison: one test covers finite and plausible values
    if not (-w <= g0 <= w and -w <= g1 <= w and -w <= g2 <= w and -f <= a0 <= f
            and -f <= a1 <= f and -f <= a2 <= f):
        isf = math.isfinite
        finite = isf(g0) and isf(g1) and isf(g2) and isf(a0) and isf(a1) and isf(a2)
        return 'implausible' if finite else 'non_finite'
    q = s.orientation
    if q is not None:
        n = math.hypot(float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        lo, hi = QUATERNION_NORM
        if not lo <= n <= hi:
            return 'implausible' if math.isfinite(n) else 'non_finite'
    return None


def _odom_problem(s: T.OdomSample) -> Optional[str]:
    x, y, z, yaw, vx, vy, wz = s.x, s.y, s.z, s.yaw, s.vx, s.vy, s.wz
    p, v, w = MAX_POSITION, MAX_SPEED, MAX_ANGULAR_RATE
    n = s.orientation_norm
    lo, hi = QUATERNION_NORM
    if abs(x) <= p and abs(y) <= p and abs(z) <= p and abs(vx) <= v and abs(vy) <= v \
            and abs(wz) <= w and abs(yaw) < math.inf and (lo <= n <= hi or n == 0.0):
        return None  # (a driver that fills only the twist leaves the quaternion all zero)
    isf = math.isfinite
    finite = isf(x) and isf(y) and isf(z) and isf(yaw) and isf(vx) and isf(vy) and isf(wz) \
        and isf(n)
    return 'implausible' if finite else 'non_finite'


def _twist_problem(s: T.TwistSample) -> Optional[str]:
    vals = (s.vx, s.vy, s.wz)
    if not all(math.isfinite(v) for v in vals):
        return 'non_finite'
    if max(abs(s.vx), abs(s.vy)) > MAX_SPEED or abs(s.wz) > MAX_ANGULAR_RATE:
        return 'implausible'
    return None


def _scan_problem(s: T.ScanSample) -> Optional[str]:
    # NaN/inf beams are normal (no return, REP-117); the geometry must be finite and sane.
    geometry = (s.angle_min, s.angle_increment, s.range_min, s.range_max, s.time_increment)
    if not all(math.isfinite(v) for v in geometry):
        return 'non_finite'
    span = max(s.ranges.size - 1, 0)
    if span and s.angle_increment == 0.0:
        return 'implausible'  # every beam in one direction: no geometry at all
    if abs(s.angle_min) > MAX_SCAN_FOV or abs(s.angle_increment) * span > MAX_SCAN_FOV \
            or abs(s.time_increment) * span > MAX_SCAN_DURATION:
        return 'implausible'
    # (a range_max of 0 is a driver leaving it unset: the methods then use their own limit)
    if not 0.0 <= s.range_max <= MAX_SCAN_RANGE or abs(s.range_min) > MAX_SCAN_RANGE:
        return 'implausible'
    return None


def _floats(values: Any) -> list:
    """Return a numpy vector (or any sequence) as a list of Python floats."""
    return values.tolist() if isinstance(values, np.ndarray) else [float(v) for v in values]


def _joint_problem(s: T.JointStateSample) -> Optional[str]:
    pos, vel = _floats(s.position), _floats(s.velocity)
    if len(pos) != len(s.names) or len(vel) != len(s.names):
        return 'implausible'
    if len(set(s.names)) != len(s.names):
        return 'duplicate_joint'  # which of the two values is the joint's cannot be told
    big_p, big_v = MAX_JOINT_POSITION, MAX_JOINT_VELOCITY
    for p, v in zip(pos, vel):
        if -big_p <= p <= big_p and (-big_v <= v <= big_v or v != v):
            continue
        if p != p and -big_v <= v <= big_v:
            continue  # a joint may report only position or only velocity (NaN elsewhere)
        if (p != p and v != v) or abs(p) == math.inf or abs(v) == math.inf:
            return 'non_finite'
        return 'implausible'
    return None


_CHECKS = {T.ImuSample: _imu_problem, T.OdomSample: _odom_problem,
           T.TwistSample: _twist_problem, T.ScanSample: _scan_problem,
           T.JointStateSample: _joint_problem}


UNCHECKED: Any = object()
"""A verdict not taken yet (see :meth:`Pipeline.process_checked`): the sample is checked there."""


def sample_problem(sample: Any) -> Optional[str]:
    """
    Return why ``sample`` must not be used, or None when it is fine.

    ``'non_finite'``: a NaN or inf where a number must be finite (the stamp, a
    rate, a pose...); ``'implausible'``: a value outside the physical limits of
    this module (rates, forces, speeds, positions, quaternion norms, scan
    geometry), or a malformed sample (vector lengths); ``'duplicate_joint'``: a
    JointState that names one joint twice.
    """
    if not math.isfinite(sample.t):
        return 'non_finite'
    check = _CHECKS.get(type(sample))
    return None if check is None else check(sample)


class RateGuard:
    """
    Reject samples of one input that arrive impossibly fast for their kind (token bucket).

    The bucket holds up to ``max(MAX_RATE * RATE_BURST, 5)`` samples and refills
    at ``MAX_RATE`` per second of sample time; a sample that finds it empty is
    implausible. Stamps must be checked for order before (see the pipeline).
    """

    __slots__ = ('rate', 'capacity', 'tokens', 'last_t')

    def __init__(self, kind: str):
        """Create the guard of an input of ``kind`` (unbounded when the kind has no limit)."""
        self.rate = MAX_RATE.get(kind, math.inf)
        self.capacity = max(self.rate * RATE_BURST, _MIN_BURST)
        self.tokens = self.capacity
        self.last_t: Optional[float] = None

    def allow(self, t: float) -> bool:
        """Return True when a sample stamped ``t`` (s, after the previous one) is plausible."""
        last = self.last_t
        self.last_t = t
        if last is not None:
            tokens = self.tokens + (t - last) * self.rate
            self.tokens = tokens if tokens < self.capacity else self.capacity
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


WALL_CLOCK_NS = 86_400 * 10**9
"""A receive time later than one day after 1970 (ns) is a wall clock, not simulated time."""


def restamp_unset(samples: list, time_ns: int) -> Optional[list]:
    """
    Return ``samples`` stamped at their receive time ``time_ns`` when their stamps are unset.

    A driver that never fills ``header.stamp`` leaves it 0: every message then has
    the same stamp and all but the first would be rejected as duplicates. Such
    samples take the receive time (the bag's log time, or the node's clock)
    instead, when that is a wall clock (after :data:`WALL_CLOCK_NS`; in
    simulated time a first stamp of 0 is the start, not unset). None when the
    first sample's stamp is set (the usual case: one attribute read) or kept.
    Static transforms keep theirs.
    """
    if not samples or getattr(samples[0], 'stamp_ns', -1) != 0 or time_ns < WALL_CLOCK_NS or \
            isinstance(samples[0], T.StaticTransform):
        return None
    t = time_ns * 1e-9
    return [dataclasses.replace(s, t=t, stamp_ns=time_ns) if s.stamp_ns == 0 else s
            for s in samples]
