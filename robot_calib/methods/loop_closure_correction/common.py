# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What both loop-closure variants share: keyframes, candidates, reports, the result, scoring.

A :class:`ClosureReport` is what ``update(scan)`` returns for a closure
attempt (accepted or refused) or a suspected kidnap; a
:class:`LoopClosureResult` is what ``result()`` returns.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
import math
from typing import Mapping, Optional, Sequence, TYPE_CHECKING

import numpy as np
from robot_calib.core.geometry import se2_apply
from robot_calib.core.scan_match import MatchResult
from robot_calib.core.types import ScanSample

if TYPE_CHECKING:  # the KD-tree is built in core.scan_match
    from scipy.spatial import cKDTree


@dataclass
class Keyframe:
    """A keyframe: id ``kid``, time (s), corrected and raw pose (m, m, rad), points (m)."""

    kid: int
    t: float
    pose: np.ndarray
    points: np.ndarray
    path: float
    segment: int
    cell: tuple
    raw: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rate: float = 0.0


@dataclass
class Candidate:
    """One registered keyframe: its match, candidate pose of the current frame, and score."""

    keyframe: int
    similarity: float
    match: MatchResult
    pose: np.ndarray
    score: float
    inliers: int
    outliers: int


@dataclass(frozen=True)
class ClosureReport:
    """
    One closure attempt, accepted or refused, or a suspected kidnap.

    Times in s, poses and the correction (x m, y m, yaw rad), latency and CPU
    time in ms, search radius in m; ``keyframes_tried``, ``scores`` and
    ``similarities`` are per registered (or, when none was similar enough, per
    checked) keyframe.
    """

    t: float
    accepted: bool
    reason: str
    keyframes_tried: tuple
    scores: tuple
    similarities: tuple
    chosen: int = -1
    correction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pose_before: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pose_after: np.ndarray = field(default_factory=lambda: np.zeros(3))
    latency_ms: float = 0.0
    cpu_ms: float = 0.0
    radius: float = 0.0
    min_eigenvalue: float = float('nan')
    inlier_ratio: float = float('nan')

    def as_dict(self) -> dict:
        """Return a JSON-ready dict (m, rad, ms)."""
        return {'t': self.t, 'accepted': self.accepted, 'reason': self.reason,
                'keyframes_tried': list(self.keyframes_tried),
                'scores': [round(float(s), 4) for s in self.scores],
                'similarities': [round(float(s), 4) for s in self.similarities],
                'chosen': self.chosen,
                'correction': {'x': float(self.correction[0]), 'y': float(self.correction[1]),
                               'yaw': float(self.correction[2])},
                'pose_before': [float(v) for v in self.pose_before],
                'pose_after': [float(v) for v in self.pose_after],
                'latency_ms': round(self.latency_ms, 3), 'cpu_ms': round(self.cpu_ms, 3),
                'radius': round(self.radius, 3),
                'min_eigenvalue': self.min_eigenvalue, 'inlier_ratio': self.inlier_ratio}


@dataclass(frozen=True)
class LoopClosureResult:
    """
    Everything a loop-closure variant has estimated so far (``result()``).

    ``pose`` is the corrected pose and ``raw_pose`` the dead reckoning (x m,
    y m, yaw rad) in the odometry frame of the first sample; ``sigma_xy`` (m)
    and ``sigma_yaw`` (rad) their uncertainty; ``yaw_rate`` the latest
    bias-corrected yaw rate (rad/s); ``heading_source`` the source in use
    (``imu`` or ``odom``); ``gyro_bias`` the learned residual bias (rad/s);
    ``path`` the distance driven (m); ``segments`` the maps made (1 + kidnaps).
    ``counts`` reads 0 for what never happened. ``keyframes`` is the number
    stored in the map, ``keyframe_memory_bytes`` what they hold (B).
    ``closures`` lists every report, oldest first.
    ``scans_refused_few_beams`` counts the scans refused before use: fewer than
    ``min_valid_beams`` valid beams (the input rejection a pipeline reports).
    """

    mode: str
    pose: np.ndarray
    raw_pose: np.ndarray
    sigma_xy: float
    sigma_yaw: float
    yaw_rate: float
    heading_source: str
    gyro_bias: float
    path: float
    segments: int
    counts: Mapping[str, int]
    keyframes: int
    keyframe_memory_bytes: int
    closures: tuple
    scans_refused_few_beams: int

    def summary(self) -> dict:
        """Return counts, closures and latency statistics (JSON-ready; ms, rad/s, B)."""
        done = [r for r in self.closures if r.reason != 'kidnap_suspected']
        lat = [r.latency_ms for r in done]
        cpu = [r.cpu_ms for r in done]
        acc = [r for r in self.closures if r.accepted]
        return {
            'counts': dict(self.counts),
            'keyframes': self.keyframes,
            'keyframe_memory_bytes': self.keyframe_memory_bytes,
            'closures_accepted': len(acc),
            'closures_refused': len(self.closures) - len(acc),
            'latency_ms_median': float(np.median(lat)) if lat else None,
            'latency_ms_p95': float(np.percentile(lat, 95)) if lat else None,
            'cpu_ms_median': float(np.median(cpu)) if cpu else None,
            'cpu_ms_p95': float(np.percentile(cpu, 95)) if cpu else None,
            'gyro_bias': self.gyro_bias,
            'heading_source': self.heading_source,
            'segments': self.segments,
        }


def frozen_counts(counts: Mapping[str, int]) -> Counter:
    """Return a copy of ``counts`` that reads 0 for a missing name (and never inserts it)."""
    return Counter(counts)


def voxel_thin(points: np.ndarray, voxel: float) -> np.ndarray:
    """Keep the first point of every ``voxel``-sized cell (m); order is preserved."""
    if voxel <= 0 or len(points) == 0:
        return points
    keys = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def surely_within(scan: ScanSample, ranges: np.ndarray, sensor: Optional[Sequence[float]],
                  speed: float, rate: float, max_range: float) -> bool:
    """
    Return True when every point of ``scan`` is finite and within ``max_range`` (m) of base_link.

    The points are those :func:`robot_calib.core.frames.scan_points` makes of
    the valid beams (``ranges``, m) with the mounting ``sensor`` (x m, y m,
    yaw rad; None: none) and the de-skew at ``speed`` (m/s) and ``rate``
    (rad/s). A rotation keeps a point's distance, so a point lies within
    ``range + |sensor offset| + |speed| * (time since the stamp)``; False
    when that bound, with a margin for rounding, does not prove it.
    """
    if len(ranges) == 0:
        return True
    offset = math.hypot(sensor[0], sensor[1]) if sensor is not None else 0.0
    reach = 0.0
    ti = scan.time_increment
    if ti != 0.0 and math.isfinite(ti):
        reach = abs(speed) * abs(ti) * np.size(scan.ranges)  # beam i is at i * ti s
    bound = float(np.max(ranges)) + offset + reach
    finite = all(math.isfinite(v) for v in (offset, reach, speed, rate)) and (
        sensor is None or math.isfinite(sensor[2]))
    return finite and bound + 1e-6 * (1.0 + bound) < max_range


def score_candidate(kf_points: np.ndarray, relative: np.ndarray, tree: cKDTree,
                    inlier_distance: float, outlier_weight: float) -> tuple[float, int, int]:
    """
    Score a candidate as seed 001 does: inliers raise it, outliers lower it.

    :param kf_points: keyframe points (N, 2) (m) in the keyframe frame.
    :param relative: keyframe frame seen from the current frame (m, m, rad).
    :param tree: KD-tree of the current scan's points.
    :param inlier_distance: nearest-point distance of an inlier (m).
    :param outlier_weight: weight of one outlier against one inlier.
    :return: (score in [-w, 1], inliers, outliers); score = (inl - w * out) / N.
    """
    if len(kf_points) == 0:
        return -outlier_weight, 0, 0
    moved = se2_apply(relative, kf_points)
    dist, _ = tree.query(moved, distance_upper_bound=inlier_distance)
    inl = int(np.isfinite(dist).sum())
    out = len(kf_points) - inl
    # seed 001: the quantized value grows with inliers and falls with outliers
    return (inl - outlier_weight * out) / len(kf_points), inl, out


def base_refusal(best: Candidate, min_score: float) -> str:
    """Return why ``best`` is refused by the rules both variants apply, or '' (seed 001)."""
    if best.match.reason:
        return 'match_failed_' + best.match.reason
    if best.score < min_score:
        return 'low_score'
    return ''
