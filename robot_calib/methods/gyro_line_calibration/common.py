# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What both variants of ``gyro_line_calibration`` share: references, corrections, the result.

A :class:`Reference` is a wall line kept to correct the heading against; a
:class:`Correction` is one heading change; :class:`GyroLineResult` is what
:meth:`~robot_calib.core.estimator.Estimator.result` returns (seed and
improved variants alike).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping, Optional

import numpy as np

from robot_calib.core.lines import Line


@dataclass
class Reference:
    """A reference line with its covariance (angle, distance at its midpoint) and history."""

    id: int  # noqa: A003 - the reference's identifier
    line: Line
    t_created: float
    cov: np.ndarray
    pose: np.ndarray
    n_seen: int = 1
    t_last: float = 0.0
    confirmed: bool = False
    matches: int = 0
    conflicts: int = 0
    origin: Optional[Line] = None
    """The line as first seen (with :attr:`pose`, the estimated pose then)."""


@dataclass(frozen=True)
class Correction:
    """
    One heading correction.

    :ivar t: time (s).
    :ivar delta: heading change applied (rad).
    :ivar angle_error: reference angle minus line angle (rad, modulo pi) of the best match.
    :ivar reference_ids: references used.
    :ivar lines: the new lines used (world frame of the estimate).
    :ivar references: the reference lines used.
    :ivar pose: the estimated pose after the correction (x, y, yaw).
    :ivar kind: 'first', 'time', 'length' (seed) or 'filter' (improved).
    """

    t: float
    delta: float
    angle_error: float
    reference_ids: tuple
    lines: tuple
    references: tuple
    pose: np.ndarray
    kind: str = 'filter'
    position_delta: float = 0.0
    pose_before: Optional[np.ndarray] = None


@dataclass(frozen=True)
class PoseEstimate:
    """
    What one odometry sample produced: the corrected pose, its covariance and rate.

    :ivar initialized: True once the first odometry sample set the pose.
    :ivar pose: estimated pose (x m, y m, yaw rad in (-pi, pi]) in the odometry frame.
    :ivar pose_cov: covariance (3, 3) of x, y, yaw (m^2, m rad, rad^2).
    :ivar rate: corrected yaw speed (rad/s).
    :ivar odom_resets: odometry resets or jumps seen so far.
    """

    initialized: bool
    pose: np.ndarray
    pose_cov: np.ndarray
    rate: float
    odom_resets: int


def within_hold(last: Optional[float], t: float, hold: float) -> bool:
    """Return True when ``last`` (s, None: never) is at most ``hold`` (s) before ``t`` (s)."""
    return last is not None and t - last <= hold


@dataclass(frozen=True)
class GyroLineResult:
    """
    Everything estimated so far (both variants).

    :ivar initialized: True once the first odometry sample set the pose.
    :ivar pose: estimated pose (x m, y m, yaw rad in (-pi, pi]) in the odometry frame.
    :ivar heading: the corrected heading (rad, (-pi, pi]), ``pose[2]``.
    :ivar pose_cov: covariance (3, 3) of x, y, yaw (m^2, m rad, rad^2) as last propagated
        by odometry, scans and corrections.
    :ivar heading_sigma: 1-sigma heading uncertainty (rad), including the gyro samples
        integrated since the covariance was last propagated.
    :ivar gyro_bias: estimated gyro z bias (rad/s) (0 in the seed variant).
    :ivar rate: corrected yaw speed (rad/s): gyro minus bias, or the odometry one.
    :ivar edge_following: the seed phase (True: edge following, False: work).
    :ivar untrusted_until: lines are not used before this time (s) (see :meth:`trusted`).
    :ivar corrections: the latest corrections (bounded), oldest first.
    :ivar references: the reference lines kept (world frame of the estimate).
    :ivar tentative_references: tentative references not yet confirmed (improved variant).
    :ivar counts: event counters (corrections, rejections, untrusted data, ...).
    :ivar scan_rejected: why the last scan was rejected (None: it was accepted).
    :ivar lock_lost_episodes: times the walls began to contradict the heading.
    :ivar lock_lost_last: time (s) the walls last contradicted it (None: never).
    """

    initialized: bool
    pose: np.ndarray
    heading: float
    pose_cov: np.ndarray
    heading_sigma: float
    gyro_bias: float
    rate: float
    edge_following: bool
    untrusted_until: float
    corrections: tuple
    references: tuple
    tentative_references: int
    counts: Mapping[str, int]
    scan_rejected: Optional[str] = None
    lock_lost_episodes: int = 0
    lock_lost_last: Optional[float] = None

    def trusted(self, t: float) -> bool:
        """Return True when lines may be used at time ``t`` (s)."""
        return self.initialized and t >= self.untrusted_until

    @property
    def last_correction(self) -> Optional[Correction]:
        """Return the latest correction, or None."""
        return self.corrections[-1] if self.corrections else None


def frozen_counts(counts: dict) -> Mapping[str, int]:
    """Return a read-only copy of event counters."""
    return MappingProxyType(dict(counts))
