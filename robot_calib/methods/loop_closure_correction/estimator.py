# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Gyro heading (and pose) correction by loop closure with ICP against keyframes (seed 001).

A cheap robot integrates its gyro for heading and its wheels for distance;
the heading drifts (bias, bias drift). Instead of a global pose-graph
optimisation after each loop closure (see
:mod:`robot_calib.methods.loop_closure_correction.pose_graph` for that baseline), the seed
corrects the current pose directly from ICP against stored keyframes, in milliseconds.

Pipeline of one update (:class:`LoopClosureCorrector`):

1. **Dead reckoning**: heading from the gyro (``heading_source``: ``imu``,
   ``odom`` or ``auto``), distance from the wheel odometry increments; the
   published pose is ``correction (+) raw``. Its uncertainty grows with the
   distance and rotation travelled and with time (gyro bias drift).
2. **Keyframes** every ``keyframes.distance`` m or ``keyframes.angle`` rad:
   the corrected pose and the scan points (voxel-thinned, float32). Memory is
   bounded by a spatial grid (``cell_size``): at most ``max_per_cell``
   keyframes per cell (the oldest kept: they carry the least drift) and at
   most ``max_keyframes`` overall, so hours of driving in one building cost
   the building's area, not the time driven (about 3 kB per keyframe).
3. **Loop detection** at each new keyframe: keyframes within a radius of the
   current estimate (``base_radius + radius_gain * sigma_xy``, capped) that
   were made at least ``min_loop_travel`` m of driving ago; each is confirmed
   by scan similarity (the fraction of its points that land near the current
   scan at the predicted pose, best over a small yaw grid); the ``candidates``
   (Y) most similar are registered.
4. **Registration** (:mod:`robot_calib.core.scan_match`): the keyframe's points
   against the current scan: kiss-icp coarse + point-to-line refinement
   (improved) or kiss-icp alone (seed). Candidate pose of the current frame:
   ``keyframe_pose (+) inverse(relative)``. Seed mode takes the heading from the
   centroids of the matched points (seed 001): the bearing of the keyframe
   points' centroid seen from the current position, minus its bearing in the
   current frame.
5. **Scoring and choice** (seed 001): transform the keyframe's points by the
   candidate, count inliers (nearest current point within
   ``inlier_distance``) and outliers, ``score = (inliers - outlier_weight *
   outliers) / points``; take the best. Improved mode refuses when the best is
   below ``min_score``; when another candidate proposes a different pose
   (beyond ``hypothesis_tolerance``) with a score within ``score_margin``; when
   the match is degenerate (Hessian, e.g. a corridor); or when the correction
   is implausible given the pose uncertainty (``max_correction_sigma``).
6. **Correction**: heading and position at once; later poses stay consistent
   because the correction is a transform applied to all later dead reckoning.
   Improved mode also spreads the correction linearly over the keyframes made
   since the last fix (so they agree with the corrected map), and learns the
   residual gyro bias with a scalar Kalman filter from the heading change
   that registering each new scan against the last keyframe measures
   (``motion.estimate_gyro_bias``), so the heading drifts less between closures.

Bad input is refused and counted (:attr:`LoopClosureCorrector.counts`): scans
with too few valid beams, degenerate matches, ambiguous or low-score matches,
and a kidnapped or carried robot (the scan stops agreeing with the last
keyframe at the dead-reckoning prediction ``kidnap_checks`` times in a row,
checked at each keyframe and every ``kidnap_check_interval`` s when standing):
then the map is dropped and a new one started, so no later closure is made
against a place the robot can no longer locate itself in.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
import math
import time
from typing import Iterable, Optional

import numpy as np
from robot_calib.core.geometry import (rot2, se2_apply, se2_between, se2_compose,
                                       se2_inverse, wrap_angle)
from robot_calib.core.params import param
from robot_calib.core.scan_match import (MatchResult, PreparedScan, register,
                                         ScanMatchParams)
from scipy.spatial import cKDTree


@dataclass
class KeyframeParams:
    """When keyframes are made and how their memory is bounded."""

    distance: float = param(0.5, 'm', 'distance travelled that makes a new keyframe',
                            minimum=0.01)
    angle: float = param(0.35, 'rad', 'rotation that makes a new keyframe', minimum=0.01)
    voxel: float = param(0.1, 'm', 'voxel size for thinning keyframe points', minimum=0.0)
    max_range: float = param(20.0, 'm', 'beams farther than this are not stored or matched',
                             minimum=0.1)
    cell_size: float = param(2.0, 'm', 'cell size of the spatial keyframe index', minimum=0.1)
    max_per_cell: int = param(6, '', 'keyframes kept per cell (the oldest are kept)',
                              minimum=1)
    max_keyframes: int = param(5000, '', 'keyframes kept at most (memory bound)', minimum=2)


@dataclass
class DetectionParams:
    """Loop detection: which keyframes become candidates."""

    candidates: int = param(3, '', 'Y: keyframes registered per closure attempt', minimum=1)
    base_radius: float = param(1.5, 'm', 'search radius around the current estimate',
                               minimum=0.0)
    radius_gain: float = param(3.0, '', 'radius grows by this many position sigmas',
                               minimum=0.0)
    max_radius: float = param(8.0, 'm', 'largest search radius', minimum=0.0)
    min_loop_travel: float = param(8.0, 'm', 'a keyframe is a loop candidate only when made '
                                   'at least this much driving ago', minimum=0.0)
    max_prefilter: int = param(8, '', 'nearest keyframes checked for similarity', minimum=1)
    similarity_gate: float = param(0.3, 'm', 'distance counting a point as overlapping in the '
                                   'similarity check', minimum=0.0)
    min_similarity: float = param(0.35, '', 'fewest overlapping point fraction for a '
                                  'candidate', minimum=0.0, maximum=1.0)
    similarity_yaw_steps: int = param(7, '', 'yaw hypotheses of the similarity check (over '
                                      '+- 3 heading sigmas)', minimum=1)


@dataclass
class ScoringParams:
    """Scoring of the candidates and refusal rules."""

    inlier_distance: float = param(0.1, 'm', 'a keyframe point is an inlier when the nearest '
                                   'current point is closer (seed: first preset distance)',
                                   minimum=0.0)
    outlier_weight: float = param(1.0, '', 'weight of an outlier in the score (seed: score '
                                  'falls with outliers)', minimum=0.0)
    min_score: float = param(0.2, '', 'lowest accepted score, (inliers - w outliers) / points',
                             minimum=-1.0, maximum=1.0)
    score_margin: float = param(0.1, '', 'a competing hypothesis within this score of the '
                                'best makes the closure ambiguous (improved)', minimum=0.0)
    hypothesis_tolerance: float = param(0.3, 'm', 'candidate poses closer than this (and 0.1 '
                                        'rad) are the same hypothesis', minimum=0.0)
    max_correction_sigma: float = param(4.0, '', 'largest correction in predicted sigmas '
                                        '(improved; larger is a wrong match or a kidnap)',
                                        minimum=0.0)
    min_correction_floor: float = param(0.3, 'm', 'corrections below this are always '
                                        'plausible (0.1 of it in rad for yaw)', minimum=0.0)


@dataclass
class MotionParams:
    """Dead reckoning, its uncertainty model, and the kidnap check."""

    odom_noise: float = param(0.02, 'm/m', 'position sigma growth per metre driven',
                              minimum=0.0)
    heading_noise: float = param(0.02, 'rad/rad', 'heading sigma growth per radian turned',
                                 minimum=0.0)
    heading_drift_rate: float = param(0.002, 'rad/s', 'heading sigma growth per second '
                                      '(residual gyro bias)', minimum=0.0)
    estimate_gyro_bias: bool = param(True, '', 'learn the residual gyro bias from the scan '
                                     'registrations against the last keyframe (improved)')
    bias_random_walk: float = param(2e-5, 'rad/s/sqrt(s)', 'assumed gyro bias random walk of '
                                    'the bias filter', minimum=0.0)
    initial_bias_sigma: float = param(0.005, 'rad/s', 'prior sigma of the residual gyro bias',
                                      minimum=0.0)
    scan_yaw_sigma: float = param(0.002, 'rad', 'heading noise floor of one scan registration',
                                  minimum=1e-6)
    max_gyro_bias: float = param(0.05, 'rad/s', 'largest gyro bias accepted', minimum=0.0)
    bias_max_rate: float = param(0.1, 'rad/s', 'the bias is learned only from scans taken '
                                 'while turning slower than this (residual scan skew)',
                                 minimum=0.0)
    kidnap_check_interval: float = param(1.0, 's', "how often a standing robot's scan is "
                                         'checked against the last keyframe', minimum=0.0)
    kidnap_min_inlier_ratio: float = param(0.15, '', 'below this inlier ratio against the '
                                           'last keyframe the scan disagrees with odometry',
                                           minimum=0.0, maximum=1.0)
    kidnap_max_offset: float = param(0.5, 'm', 'registration offset from the odometry '
                                     'prediction beyond which the scan disagrees (plus 30 % '
                                     'of the distance since the keyframe)', minimum=0.0)
    kidnap_max_yaw_offset: float = param(0.5, 'rad', 'heading offset from the prediction '
                                         'beyond which the scan disagrees (plus 30 % of the '
                                         'rotation since the keyframe)', minimum=0.0)
    kidnap_checks: int = param(3, '', 'consecutive failed checks that declare a kidnap',
                               minimum=1)
    kidnap_doubt_time: float = param(3.0, 's', 'a weak match to the last keyframe that lasts '
                                     'this long also declares a kidnap', minimum=0.0)


@dataclass
class LoopScanMatchParams(ScanMatchParams):
    """
    The registration settings loop closure uses: the shared ones, lighter by default.

    A loop-closure candidate starts from a prediction already refined by the
    similarity check's yaw search, so the kiss-icp coarse stage is skipped by
    default (``coarse: none``; set it to ``kiss_icp`` for large drifts) and the
    refinement's gate anneals over fewer iterations.
    """

    coarse: str = param('none', '', 'coarse alignment before the refinement: kiss_icp or '
                        'none', choices=('kiss_icp', 'none'))
    refine_anneal_iterations: int = param(4, '', 'iterations over which the gate shrinks '
                                          'from the wide to the narrow value', minimum=1)
    convergence_rotation: float = param(5e-5, 'rad', 'rotation update that ends the '
                                        'refinement', minimum=0.0)
    convergence_translation: float = param(2e-4, 'm', 'translation update that ends the '
                                           'refinement', minimum=0.0)


@dataclass
class LoopClosureParams:
    """Parameters of the loop-closure heading correction (seed 001)."""

    mode: str = param('improved', '', 'improved (refusals, point-to-line, bias learning) or '
                      'seed (kiss-icp, centroid heading, best score)',
                      choices=('improved', 'seed'))
    heading_source: str = param('auto', '', 'heading from the imu gyro, the odom yaw, or auto '
                                '(imu when it arrives)', choices=('auto', 'imu', 'odom'))
    distribute_correction: bool = param(True, '', 'spread each correction over the keyframes '
                                        'made since the last fix (improved)')
    min_valid_beams: int = param(30, '', 'scans with fewer valid beams are rejected', minimum=3)
    keyframes: KeyframeParams = field(default_factory=KeyframeParams)
    detection: DetectionParams = field(default_factory=DetectionParams)
    scoring: ScoringParams = field(default_factory=ScoringParams)
    motion: MotionParams = field(default_factory=MotionParams)
    scan_match: LoopScanMatchParams = field(default_factory=LoopScanMatchParams)


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


@dataclass
class ClosureReport:
    """One closure attempt, accepted or refused (what /diagnostics and the summary report)."""

    t: float
    accepted: bool
    reason: str
    keyframes_tried: list
    scores: list
    similarities: list
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


def voxel_thin(points: np.ndarray, voxel: float) -> np.ndarray:
    """Keep the first point of every ``voxel``-sized cell (m); order is preserved."""
    if voxel <= 0 or len(points) == 0:
        return points
    keys = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def deskew(points: np.ndarray, dt: np.ndarray, v: float, w: float) -> np.ndarray:
    """
    Move points measured ``dt`` (s) after the stamp into the robot frame at the stamp.

    A rotating lidar measures beam i at ``stamp + i * time_increment``; with
    a constant forward speed ``v`` (m/s) and yaw rate ``w`` (rad/s) over the
    scan, a point measured in base_link at ``stamp + dt`` is, in base_link at
    the stamp, ``R(w dt) p + (v dt, 0)``.

    :param points: (N, 2) points in base_link (m) when measured.
    :param dt: (N,) time of each point after the stamp (s).
    :param v: forward speed (m/s).
    :param w: yaw rate (rad/s).
    :return: (N, 2) deskewed points (m).
    """
    th = w * dt
    c, s = np.cos(th), np.sin(th)
    x, y = points[:, 0], points[:, 1]
    return np.column_stack((c * x - s * y + v * dt, s * x + c * y))


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


def centroid_heading(kf_pose: np.ndarray, kf_points: np.ndarray, cur_position: np.ndarray,
                     cur_points: np.ndarray) -> float:
    """
    Return the seed's heading estimate of the current frame from point centroids (rad).

    seed 001: p0 = mean(p_i) (keyframe points), q0 = mean(q_i) (current
    points). The keyframe centroid in the world is ``kf_pose (+) p0``; seen from
    the current position it has bearing ``b_w``; in the current frame it has
    bearing ``b_c = atan2(q0)``; heading = ``b_w - b_c``. The two point sets
    must be corresponding points (here: the matched inliers).

    :param kf_pose: keyframe pose (m, m, rad).
    :param kf_points: (N, 2) keyframe points (m), keyframe frame.
    :param cur_position: (x, y) of the current frame (m).
    :param cur_points: (N, 2) corresponding current points (m), current frame.
    """
    p0 = kf_points.mean(axis=0)
    q0 = cur_points.mean(axis=0)
    c_world = se2_apply(kf_pose, p0[None, :])[0]
    b_w = math.atan2(c_world[1] - cur_position[1], c_world[0] - cur_position[0])
    b_c = math.atan2(q0[1], q0[0])
    return wrap_angle(b_w - b_c)


class LoopClosureCorrector:
    """
    Streaming loop-closure heading and pose correction (seed 001).

    Feed :meth:`update_imu`, :meth:`update_odom` and :meth:`update_scan` in time
    order; :attr:`pose` is the corrected pose (m, m, rad) in the odometry frame
    of the first sample. :attr:`reports` lists every closure attempt.

    :param params: the parameters (defaults when None).
    """

    def __init__(self, params: Optional[LoopClosureParams] = None):
        """Start with an empty map at the origin."""
        self.params = params if params is not None else LoopClosureParams()
        p = self.params
        self.seed_mode = p.mode == 'seed'
        self.match_params = p.scan_match
        if self.seed_mode:
            # The seed runs ICP (kiss-icp's point-to-point) without our refinement.
            self.match_params = ScanMatchParams(**{**p.scan_match.__dict__, 'refine': False,
                                                   'coarse': 'kiss_icp'})
        self.raw = np.zeros(3)
        self.correction = np.zeros(3)
        self.gyro_bias = 0.0
        self.bias_var = self.params.motion.initial_bias_sigma ** 2
        self._bias_t: Optional[float] = None
        self.sigma_xy = 0.0
        self.sigma_yaw = 0.0
        self.path = 0.0
        self.keyframes: dict[int, Keyframe] = {}
        self.grid: dict[tuple, list] = defaultdict(list)
        self.reports: list[ClosureReport] = []
        self.counts: dict[str, int] = defaultdict(int)
        self.segment = 0
        self.using_imu = False
        self.rate = 0.0
        """Latest bias-corrected yaw rate (rad/s)."""
        self._next_id = 0
        self._last_imu: Optional[tuple[float, float]] = None
        self._last_odom = None
        self._last_kf_pose: Optional[np.ndarray] = None
        self._last_kf_id: Optional[int] = None
        self._last_fix_t: Optional[float] = None
        self._last_fix_kf = -1
        self._last_check_t = -math.inf
        self._failed_checks = 0
        self._doubt_since: Optional[float] = None
        self._t = 0.0
        self._t0: Optional[float] = None

    # -- state ----------------------------------------------------------------------------
    @property
    def pose(self) -> np.ndarray:
        """Return the corrected pose: x, y, yaw (m, m, rad)."""
        return se2_compose(self.correction, self.raw)

    @property
    def raw_pose(self) -> np.ndarray:
        """Return the uncorrected dead-reckoning pose (m, m, rad)."""
        return self.raw.copy()

    # -- dead reckoning ---------------------------------------------------------------------
    def update_imu(self, t: float, gyro_z: float) -> None:
        """
        Integrate the gyro yaw rate (rad/s, in base_link) up to time ``t`` (s).

        The heading comes from the gyro once the first IMU sample arrives (unless
        ``heading_source`` is ``odom``); the learned bias is subtracted.
        """
        if self.params.heading_source == 'odom' or not math.isfinite(gyro_z):
            return
        self.using_imu = True
        self.rate = gyro_z - self.gyro_bias
        if self._last_imu is not None:
            t0, w0 = self._last_imu
            dt = t - t0
            if 0 < dt < 1.0:
                # trapezoidal integration of the bias-corrected rate
                self.raw[2] = wrap_angle(self.raw[2] + 0.5 * (w0 + gyro_z) * dt
                                         - self.gyro_bias * dt)
                self.sigma_yaw += self.params.motion.heading_drift_rate * dt
        self._last_imu = (t, gyro_z)

    def update_odom(self, t: float, x: float, y: float, yaw: float) -> np.ndarray:
        """
        Advance the dead reckoning with one odometry pose (m, m, rad) at ``t`` (s).

        :return: the corrected pose (m, m, rad).
        """
        m = self.params.motion
        self._t = t
        if self._t0 is None:
            self._t0 = t
        cur = np.array([x, y, yaw], dtype=float)
        if self._last_odom is not None:
            t_prev, prev = self._last_odom
            d = se2_between(prev, cur)
            ds = math.hypot(d[0], d[1])
            if self.using_imu:
                heading = self.raw[2]
            else:
                heading = self.raw[2] + 0.5 * d[2]
                self.raw[2] = wrap_angle(self.raw[2] + d[2])
                if t > t_prev:
                    self.sigma_yaw += m.heading_drift_rate * (t - t_prev)
                    self.rate = d[2] / (t - t_prev)
            # body-frame increment rotated by the (gyro) heading
            self.raw[:2] += rot2(heading) @ d[:2]
            self.path += ds
            self.sigma_yaw += m.heading_noise * abs(d[2])
            self.sigma_xy += m.odom_noise * ds + self.sigma_yaw * ds
        self._last_odom = (t, cur)
        return self.pose

    # -- scans ------------------------------------------------------------------------------
    def update_scan(self, t: float, points: np.ndarray) -> Optional[ClosureReport]:
        """
        Process one scan (points (N, 2) in base_link, m) at ``t`` (s).

        Makes a keyframe when due, attempts a loop closure first, and checks
        for a kidnap. Returns the closure report when an attempt was made.
        """
        p = self.params
        pts = np.asarray(points, dtype=float)
        pts = pts[np.all(np.isfinite(pts), axis=1)] if pts.ndim == 2 else np.zeros((0, 2))
        if len(pts):
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= p.keyframes.max_range]
        if len(pts) < p.min_valid_beams:
            self.counts['scans_rejected_few_beams'] += 1
            return None
        self.counts['scans_used'] += 1
        self._t = max(self._t, t)
        pose = self.pose
        due = self._last_kf_pose is None
        if not due:
            d = se2_between(self._last_kf_pose, pose)
            due = (math.hypot(d[0], d[1]) >= p.keyframes.distance
                   or abs(d[2]) >= p.keyframes.angle)
        if self._last_kf_id is not None and (
                due or t - self._last_check_t >= p.motion.kidnap_check_interval):
            self._last_check_t = t
            if self._local_check(t, pts) != 'ok':
                return None          # kidnapped, or in doubt: no keyframe, no closure
        if not due:
            return None
        report = self._attempt_closure(t, pts)
        self._add_keyframe(t, pts)
        return report

    def _local_check(self, t: float, pts: np.ndarray) -> str:
        """
        Register the scan against the last keyframe at the dead-reckoning prediction.

        Learns the gyro bias from the heading difference (improved mode).
        Returns 'ok'; 'doubt' when the match is weak (under twice the kidnap
        inlier ratio) and lands over half the offset limits away from the
        prediction, or failed: then no
        keyframe is made from this scan and the next scan is checked again; or
        'kidnap' (after restarting the map) when the scan has disagreed with
        odometry ``kidnap_checks`` times in a row, or stayed in doubt for
        ``kidnap_doubt_time``: the robot was kidnapped or carried.
        """
        m = self.params.motion
        kf = self.keyframes.get(self._last_kf_id)
        if kf is None:
            return 'ok'
        guess = se2_between(self.raw, kf.raw)             # keyframe frame in current frame
        res = register(kf.points.astype(float), pts, guess, self.match_params)
        off = res.pose - guess
        lim_xy = m.kidnap_max_offset + 0.3 * math.hypot(guess[0], guess[1])
        lim_yaw = m.kidnap_max_yaw_offset + 0.3 * abs(guess[2])
        d_xy, d_yaw = math.hypot(off[0], off[1]), abs(wrap_angle(off[2]))
        kp = self.params.keyframes
        # Within a keyframe step of the keyframe the view must still match it well.
        near = math.hypot(guess[0], guess[1]) < kp.distance and abs(guess[2]) < kp.angle
        far = d_xy > 0.5 * lim_xy or d_yaw > 0.5 * lim_yaw or near
        weak = res.inlier_ratio < 2.0 * m.kidnap_min_inlier_ratio
        # A weak match that still lands where odometry predicts, after the robot moved,
        # is a low-overlap view (people, a narrow field of view), not a kidnap; one far
        # from it, or a standing robot whose view changed, is suspicious.
        bad = (res.reason != '' or d_xy > lim_xy or d_yaw > lim_yaw
               or (res.inlier_ratio < m.kidnap_min_inlier_ratio and far))
        doubt = weak and far
        if res.degenerate and res.reason == '' and not weak and d_yaw <= 0.5 * lim_yaw:
            bad = doubt = False   # a corridor: the along-corridor offset is not observable
        if not bad and doubt:
            self.counts['local_check_doubtful'] += 1
            if self._doubt_since is None:
                self._doubt_since = t
            bad = t - self._doubt_since >= m.kidnap_doubt_time
            if not bad:
                return 'doubt'
            self._failed_checks = m.kidnap_checks - 1
        if not bad:
            self._doubt_since = None
            self._failed_checks = 0
            if res.ok and not res.degenerate and not weak:
                self._update_bias(t, kf, res)
            return 'ok'
        self._failed_checks += 1
        self.counts['kidnap_check_failed'] += 1
        if self._failed_checks < m.kidnap_checks:
            return 'doubt'
        # Kidnapped or carried: the map no longer locates the robot. Start a new one.
        self.counts['kidnaps'] += 1
        self.reports.append(ClosureReport(t=t, accepted=False, reason='kidnap_suspected',
                                          keyframes_tried=[kf.kid], scores=[],
                                          similarities=[], pose_before=self.pose,
                                          pose_after=self.pose,
                                          inlier_ratio=res.inlier_ratio))
        self.keyframes.clear()
        self.grid.clear()
        self.segment += 1
        self._last_kf_pose = None
        self._last_kf_id = None
        self._failed_checks = 0
        self._doubt_since = None
        self._last_fix_t = None
        return 'kidnap'

    def _update_bias(self, t: float, kf: Keyframe, res: MatchResult) -> None:
        """Scalar Kalman update of the residual gyro bias from one registration (improved)."""
        m = self.params.motion
        dt = t - kf.t
        if self.seed_mode or not self.using_imu or not m.estimate_gyro_bias or dt < 0.2:
            return
        if abs(kf.rate) > m.bias_max_rate or abs(self.rate) > m.bias_max_rate:
            self.counts['bias_skipped_turning'] += 1
            return
        # predict: the bias walks (rad/s)^2 per s
        if self._bias_t is not None:
            self.bias_var += m.bias_random_walk ** 2 * max(0.0, t - self._bias_t)
        self._bias_t = t
        d_est = wrap_angle(self.raw[2] - kf.raw[2])      # gyro heading change (bias removed)
        d_scan = wrap_angle(-res.pose[2])                  # scan heading change
        resid = (d_est - d_scan) / dt                      # = true bias - estimated bias
        var_yaw = res.covariance[2, 2] if np.isfinite(res.covariance[2, 2]) else 0.0
        r_var = (math.sqrt(max(0.0, var_yaw)) + m.scan_yaw_sigma) ** 2 / dt ** 2
        if resid ** 2 > 9.0 * (self.bias_var + r_var):
            self.counts['bias_updates_gated'] += 1
            return
        gain = self.bias_var / (self.bias_var + r_var)
        self.gyro_bias = float(np.clip(self.gyro_bias + gain * resid, -m.max_gyro_bias,
                                       m.max_gyro_bias))
        self.bias_var *= (1.0 - gain)
        self.counts['bias_updates'] += 1

    def _add_keyframe(self, t: float, pts: np.ndarray) -> None:
        kp = self.params.keyframes
        pose = self.pose
        cell = (int(math.floor(pose[0] / kp.cell_size)), int(math.floor(pose[1] / kp.cell_size)))
        self._last_kf_pose = pose
        thin = voxel_thin(pts, kp.voxel).astype(np.float32)
        kf = Keyframe(self._next_id, t, pose.copy(), thin, self.path, self.segment, cell,
                      raw=self.raw.copy(), rate=self.rate)
        self.keyframes.pop(-1, None)
        if len(self.grid[cell]) >= kp.max_per_cell or len(self.keyframes) >= kp.max_keyframes:
            # Not stored in the map; kept only as the reference of the local check.
            self.counts['keyframes_skipped_full'] += 1
            kf.kid = -1
            self.keyframes[-1] = kf
            self._last_kf_id = -1
            return
        self._next_id += 1
        self.keyframes[kf.kid] = kf
        self.grid[cell].append(kf.kid)
        self._last_kf_id = kf.kid
        self.counts['keyframes'] += 1

    # -- loop closure -----------------------------------------------------------------------
    def _candidates(self, pose: np.ndarray) -> tuple[list, float]:
        dp = self.params.detection
        kp = self.params.keyframes
        radius = min(dp.max_radius, dp.base_radius + dp.radius_gain * self.sigma_xy)
        reach = int(math.ceil(radius / kp.cell_size))
        cx, cy = int(math.floor(pose[0] / kp.cell_size)), int(math.floor(pose[1] / kp.cell_size))
        found = []
        for ix in range(cx - reach, cx + reach + 1):
            for iy in range(cy - reach, cy + reach + 1):
                for kid in self.grid.get((ix, iy), ()):
                    kf = self.keyframes[kid]
                    if self.path - kf.path < dp.min_loop_travel:
                        continue
                    dist = math.hypot(kf.pose[0] - pose[0], kf.pose[1] - pose[1])
                    if dist <= radius:
                        found.append((dist, kid))
        found.sort()
        return [kid for _, kid in found[:dp.max_prefilter]], radius

    def _similarity(self, kf: Keyframe, guess: np.ndarray, tree: cKDTree) -> tuple[float, float]:
        """Return the best overlap fraction and its yaw offset (rad) over a yaw grid."""
        dp = self.params.detection
        pts = kf.points.astype(float)
        if len(pts) > 120:
            pts = pts[::max(1, len(pts) // 120)]
        n = dp.similarity_yaw_steps
        span = min(math.radians(30.0), 3.0 * self.sigma_yaw)
        offsets = np.linspace(-span, span, n) if n > 1 else np.zeros(1)
        # All yaw hypotheses in one query: rotate the predicted keyframe points about
        # the current origin by each offset.
        base = se2_apply(guess, pts)
        c, s = np.cos(offsets), np.sin(offsets)
        xs = c[:, None] * base[None, :, 0] - s[:, None] * base[None, :, 1]
        ys = s[:, None] * base[None, :, 0] + c[:, None] * base[None, :, 1]
        dist, _ = tree.query(np.column_stack((xs.ravel(), ys.ravel())),
                             distance_upper_bound=dp.similarity_gate)
        frac = np.isfinite(dist).reshape(len(offsets), -1).mean(axis=1)
        k = int(np.argmax(frac))
        return float(frac[k]), float(offsets[k])

    def _attempt_closure(self, t: float, pts: np.ndarray) -> Optional[ClosureReport]:
        p = self.params
        sp = p.scoring
        pose = self.pose
        ids, radius = self._candidates(pose)
        if not ids:
            return None
        start = time.perf_counter()
        cpu_start = time.thread_time()
        current = PreparedScan(pts, self.match_params)
        sims = []
        for kid in ids:
            kf = self.keyframes[kid]
            guess = se2_between(pose, kf.pose)
            sim, off = self._similarity(kf, guess, current.tree)
            sims.append((sim, kid, off))
        sims.sort(key=lambda s: -s[0])
        chosen = [s for s in sims if s[0] >= p.detection.min_similarity][:p.detection.candidates]
        report = ClosureReport(t=t, accepted=False, reason='', keyframes_tried=[],
                               scores=[], similarities=[], pose_before=pose.copy(),
                               pose_after=pose.copy(), radius=radius)
        self.counts['closure_attempts'] += 1
        if not chosen:
            report.reason = 'no_similar_keyframe'
            report.similarities = [s[0] for s in sims[:p.detection.candidates]]
            report.keyframes_tried = [s[1] for s in sims[:p.detection.candidates]]
            return self._finish(report, start, cpu_start)
        cands = []
        for sim, kid, off in chosen:
            kf = self.keyframes[kid]
            guess = se2_between(pose, kf.pose)
            guess = np.array([*(rot2(off) @ guess[:2]), guess[2] + off])
            kf_pts = kf.points.astype(float)
            res = register(kf_pts, current, guess, self.match_params)
            cur_pose = se2_compose(kf.pose, se2_inverse(res.pose))
            if self.seed_mode and res.reason == '':
                cur_pose[2] = self._seed_heading(kf, kf_pts, res, current, cur_pose)
                rel = se2_between(cur_pose, kf.pose)
            else:
                rel = res.pose
            score, inl, out = score_candidate(kf_pts, rel, current.tree, sp.inlier_distance,
                                              sp.outlier_weight)
            cands.append(Candidate(kid, sim, res, cur_pose, score, inl, out))
            report.keyframes_tried.append(kid)
            report.scores.append(score)
            report.similarities.append(sim)
        best = max(cands, key=lambda c: c.score)
        report.chosen = best.keyframe
        report.min_eigenvalue = best.match.min_eigenvalue
        report.inlier_ratio = best.match.inlier_ratio
        reason = self._refusal(best, cands, pose)
        if reason:
            report.reason = reason
            return self._finish(report, start, cpu_start)
        self._apply(t, best, pose)
        report.accepted = True
        report.reason = 'accepted'
        report.pose_after = self.pose
        report.correction = np.array([*(report.pose_after[:2] - pose[:2]),
                                      wrap_angle(report.pose_after[2] - pose[2])])
        return self._finish(report, start, cpu_start)

    def _seed_heading(self, kf: Keyframe, kf_pts: np.ndarray, res: MatchResult,
                      current: PreparedScan, cur_pose: np.ndarray) -> float:
        """Heading from the centroids of the matched points (seed 001)."""
        moved = se2_apply(res.pose, kf_pts)
        dist, idx = current.tree.query(moved, distance_upper_bound=self.params.scoring
                                       .inlier_distance * 3)
        ok = np.isfinite(dist)
        if ok.sum() < 3:
            return float(cur_pose[2])
        return centroid_heading(kf.pose, kf_pts[ok], cur_pose[:2], current.points[idx[ok]])

    def _refusal(self, best: Candidate, cands: list, pose: np.ndarray) -> str:
        """Return why the best candidate is refused, or '' to accept it."""
        sp = self.params.scoring
        if best.match.reason:
            return 'match_failed_' + best.match.reason
        if best.score < sp.min_score:
            return 'low_score'
        if self.seed_mode:
            return ''
        if best.match.degenerate:
            return 'degenerate'
        if not best.match.converged:
            return 'not_converged'
        for c in cands:
            if c is best or c.match.reason:
                continue
            d = best.pose - c.pose
            same = (math.hypot(d[0], d[1]) <= sp.hypothesis_tolerance
                    and abs(wrap_angle(d[2])) <= 0.1)
            if not same and c.score >= best.score - sp.score_margin:
                return 'ambiguous'
        d = best.pose - pose
        k = sp.max_correction_sigma
        if (math.hypot(d[0], d[1]) > max(sp.min_correction_floor, k * self.sigma_xy)
                or abs(wrap_angle(d[2])) > max(0.1 * sp.min_correction_floor,
                                               k * self.sigma_yaw)):
            return 'implausible_correction'
        return ''

    def _apply(self, t: float, best: Candidate, pose: np.ndarray) -> None:
        """Make ``best.pose`` the current pose; keep later poses and the map consistent."""
        p = self.params
        new = best.pose
        if not self.seed_mode and p.distribute_correction:
            self._distribute(pose, new)
        self.correction = se2_compose(new, se2_inverse(self.raw))
        cov = best.match.covariance
        self.sigma_xy = float(math.sqrt(max(0.0, cov[0, 0] + cov[1, 1]))) \
            if np.all(np.isfinite(cov)) else 0.02
        self.sigma_yaw = float(math.sqrt(max(0.0, cov[2, 2]))) if np.isfinite(cov[2, 2]) \
            else 0.005
        self._last_fix_t = t
        self._last_fix_kf = self._next_id
        self.counts['closures_accepted'] += 1

    def _distribute(self, old: np.ndarray, new: np.ndarray) -> None:
        """Apply a growing share of the correction to the keyframes made since the last fix."""
        since = [kf for kf in self.keyframes.values()
                 if kf.kid >= self._last_fix_kf and kf.kid >= 0]
        if not since:
            return
        delta = se2_compose(new, se2_inverse(old))          # world-frame correction
        p0 = min(kf.path for kf in since)
        span = max(1e-6, self.path - p0)
        kp = self.params.keyframes
        for kf in since:
            w = (kf.path - p0) / span
            partial = np.array([w * delta[0], w * delta[1], w * delta[2]])
            # rotate about the current position, as the correction does
            rel = kf.pose - np.array([old[0], old[1], 0.0])
            moved = rot2(partial[2]) @ rel[:2] + old[:2] + w * (new[:2] - old[:2])
            kf.pose = np.array([moved[0], moved[1], wrap_angle(kf.pose[2] + partial[2])])
            cell = (int(math.floor(kf.pose[0] / kp.cell_size)),
                    int(math.floor(kf.pose[1] / kp.cell_size)))
            if cell != kf.cell:
                if kf.kid in self.grid.get(kf.cell, []):
                    self.grid[kf.cell].remove(kf.kid)
                self.grid[cell].append(kf.kid)
                kf.cell = cell

    def _finish(self, report: ClosureReport, start: float, cpu_start: float) -> ClosureReport:
        report.latency_ms = 1000.0 * (time.perf_counter() - start)
        report.cpu_ms = 1000.0 * (time.thread_time() - cpu_start)
        if not report.accepted:
            self.counts['closures_refused'] += 1
            self.counts['refused_' + report.reason] += 1
        self.reports.append(report)
        return report

    # -- summaries --------------------------------------------------------------------------
    def memory_bytes(self) -> int:
        """Return the bytes held by keyframe points and poses (B)."""
        return int(sum(kf.points.nbytes + kf.pose.nbytes for kf in self.keyframes.values()))

    def summary(self) -> dict:
        """Return counts, closures and latency statistics (JSON-ready)."""
        done = [r for r in self.reports if r.reason != 'kidnap_suspected']
        lat = [r.latency_ms for r in done]
        cpu = [r.cpu_ms for r in done]
        acc = [r for r in self.reports if r.accepted]
        return {
            'counts': dict(self.counts),
            'keyframes': len([k for k in self.keyframes if k >= 0]),
            'keyframe_memory_bytes': self.memory_bytes(),
            'closures_accepted': len(acc),
            'closures_refused': len(self.reports) - len(acc),
            'latency_ms_median': float(np.median(lat)) if lat else None,
            'latency_ms_p95': float(np.percentile(lat, 95)) if lat else None,
            'cpu_ms_median': float(np.median(cpu)) if cpu else None,
            'cpu_ms_p95': float(np.percentile(cpu, 95)) if cpu else None,
            'gyro_bias': self.gyro_bias,
            'heading_source': 'imu' if self.using_imu else 'odom',
            'segments': self.segment + 1,
        }


@dataclass
class LoopClosureResult:
    """Output of :func:`run`: corrected poses at the odometry times and every closure report."""

    t: np.ndarray
    poses: np.ndarray
    raw_poses: np.ndarray
    reports: list
    summary: dict


def run(messages: Iterable[tuple], params: Optional[LoopClosureParams] = None,
        scan_points=None) -> LoopClosureResult:
    """
    Run the correction over a whole recording (batch API).

    :param messages: (key, sample) in time order; keys 'imu' (ImuSample),
        'odom' (OdomSample), 'scan' (ScanSample); others are ignored.
    :param params: parameters (defaults when None).
    :param scan_points: optional function ScanSample -> (N, 2) points in base_link (m);
        default: the scan's own points (laser frame = base_link).
    :return: corrected and raw poses (m, m, rad) at each odometry time (s), and the reports.
    """
    lc = LoopClosureCorrector(params)
    ts, poses, raws = [], [], []
    for key, s in messages:
        if key == 'imu':
            lc.update_imu(s.t, float(s.gyro[2]))
        elif key == 'odom':
            poses.append(lc.update_odom(s.t, s.x, s.y, s.yaw))
            raws.append(lc.raw_pose)
            ts.append(s.t)
        elif key == 'scan':
            pts = scan_points(s) if scan_points is not None else s.points()
            lc.update_scan(s.t, pts)
    return LoopClosureResult(np.array(ts), np.array(poses).reshape(-1, 3),
                             np.array(raws).reshape(-1, 3), lc.reports, lc.summary())
