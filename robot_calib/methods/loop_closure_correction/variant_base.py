# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The streaming loop-closure corrector both variants build on (seed 001; Estimator protocol).

A cheap robot integrates its gyro for heading and its wheels for distance;
the heading drifts (bias, bias drift). Instead of a global pose-graph
optimisation after each loop closure (see
:mod:`robot_calib.methods.loop_closure_correction.pose_graph` for that
baseline), the seed corrects the current pose directly from ICP against
stored keyframes, in milliseconds.

:class:`LoopClosureBase` implements :class:`robot_calib.core.estimator.Estimator`
once; a variant (:mod:`.seed`, :mod:`.improved`) supplies the registration
settings, the candidate pose, the refusal rules, the bias learning and what
else a correction changes. One update:

0. **Frames**: mountings come through ``set_mounting`` (``base_frame ->
   imu`` rotates the gyro, ``base_frame -> laser`` moves the scan into the
   base frame); :func:`robot_calib.core.frames.scan_points` also de-skews
   the scan with the latest odometry speed and yaw rate.
1. **Dead reckoning**: heading from the gyro (``heading_source``: ``imu``,
   ``odom`` or ``auto``), distance from the wheel odometry increments; the
   published pose is ``correction (+) raw``. Its uncertainty grows with the
   distance and rotation travelled and with time (gyro bias drift).
2. **Keyframes** every ``keyframes.distance`` m or ``keyframes.angle`` rad:
   the corrected pose and the scan points (voxel-thinned, float32), in a
   bounded spatial grid (:mod:`.keyframe_map`; about 3 kB per keyframe).
3. **Loop detection** at each new keyframe: keyframes within a radius of the
   current estimate (``base_radius + radius_gain * sigma_xy``, capped) that
   were made at least ``min_loop_travel`` m of driving ago; each is confirmed
   by scan similarity (the fraction of its points that land near the current
   scan at the predicted pose, best over a small yaw grid); the ``candidates``
   (Y) most similar are registered.
4. **Registration** (:mod:`robot_calib.core.scan_match`): the keyframe's points
   against the current scan. Candidate pose of the current frame:
   ``keyframe_pose (+) inverse(relative)`` (the seed takes the heading from
   the centroids of the matched points instead).
5. **Scoring and choice** (seed 001): transform the keyframe's points by the
   candidate, count inliers (nearest current point within
   ``inlier_distance``) and outliers, ``score = (inliers - outlier_weight *
   outliers) / points``; take the best, unless the variant refuses it.
6. **Correction**: heading and position at once; later poses stay consistent
   because the correction is a transform applied to all later dead reckoning.

Bad input is refused and counted (``result().counts``): scans with too few
valid beams, degenerate matches, ambiguous or low-score matches, and a
kidnapped or carried robot (the scan stops agreeing with the last keyframe
at the dead-reckoning prediction ``kidnap_checks`` times in a row, checked at
each keyframe and every ``kidnap_check_interval`` s when standing): then the
map is dropped and a new one started, so no later closure is made against a
place the robot can no longer locate itself in.

Cost: most scans are neither checked nor made keyframes; they are only
counted, without computing their points when a bound shows that all lie
within ``keyframes.max_range``. A checked scan is prepared as registration
target once, for the local check and the closure attempt; the similarity
check settles most points with a grid (:class:`.keyframe_map.OverlapGrid`).
Each gives the answer of the work it skips.

Units: time s, lengths m, angles rad, rates rad/s.
"""

from __future__ import annotations

import abc
from collections import defaultdict
import math
import time
from typing import Any, ClassVar, Optional, Sequence

import numpy as np
from robot_calib.core.frames import (constant_motion, find_mounting, mirrored, planar_pose,
                                     rotation_matrix, scan_points, StaticTree, upside_down)
from robot_calib.core.geometry import (rot2, se2_between, se2_compose, se2_inverse,
                                       wrap_angle)
from robot_calib.core.notes import InputNotes
from robot_calib.core.odometry_twist import TwistFrame, TwistOnly
from robot_calib.core.scan_match import (MatchResult, PreparedScan, register,
                                         ScanMatchParams)
from robot_calib.core.types import ImuSample, OdomSample, ScanSample, StaticTransform
from robot_calib.core.zero_gyro import ZeroGyro
from robot_calib.methods.loop_closure_correction.common import (Candidate, ClosureReport,
                                                                frozen_counts, Keyframe,
                                                                LoopClosureResult,
                                                                score_candidate, surely_within,
                                                                voxel_thin)
from robot_calib.methods.loop_closure_correction.dead_reckoning import DeadReckoning
from robot_calib.methods.loop_closure_correction.keyframe_map import (KeyframeMap,
                                                                      OverlapGrid,
                                                                      similarities)
from robot_calib.methods.loop_closure_correction.params import LoopClosureParams


_LEVEL = np.eye(3)
_LEVEL.flags.writeable = False
"""The rotation of an IMU mounted level and aligned with the base frame."""


class LoopClosureBase(DeadReckoning, abc.ABC):
    """
    Streaming loop-closure heading and pose correction (seed 001), shared by both variants.

    Feed ``update`` ImuSample, OdomSample and ScanSample in time order (other
    samples are ignored); static transforms go to :meth:`set_mounting`.
    ``update(scan)`` returns the :class:`ClosureReport` the scan produced (a
    closure attempt or a suspected kidnap), else None; :meth:`result` returns
    the corrected pose and everything else estimated so far.

    :param params: the parameters (defaults when None); ``params.mode`` is not
        read here (see :mod:`robot_calib.methods.loop_closure_correction.variants`).
    """

    mode: ClassVar[str] = ''
    """The ``LoopClosureParams.mode`` this variant implements."""

    def __init__(self, params: Optional[LoopClosureParams] = None):
        """Start with an empty map at the origin and no mounting."""
        self.params = params if params is not None else LoopClosureParams()
        self.match_params = self._registration_params()
        self._mounts = StaticTree()
        # rotation sensor -> base of each IMU frame seen (None: no mounting), per frame id
        self._imu_rotations: dict[str, Optional[np.ndarray]] = {}
        # planar pose in the base frame of each laser frame seen (None: no mounting), per frame id
        self._sensor_poses: dict[str, Optional[tuple[float, float, float]]] = {}
        self._upside_down: set[str] = set()
        """Laser frames mounted upside down (their scans are mirrored)."""
        self.input_notes = InputNotes()
        """Standing warnings about the inputs (a frame not in the tree, twist-only odometry)."""
        self.reset()

    def reset(self) -> None:
        """Forget the state (map, pose, bias, reports); keep the parameters and mountings."""
        self.raw = np.zeros(3)
        self.correction = np.zeros(3)
        self.gyro_bias = 0.0
        """Learned residual gyro bias (rad/s) at ``_bias_t``."""
        self.gyro_bias_rate = 0.0
        """Learned drift rate of the gyro bias (rad/s^2)."""
        self.gyro_scale = 0.0
        """Learned gyro scale error (reading = (1 + scale) rate)."""
        self.bias_var = self.params.motion.initial_bias_sigma ** 2
        self._bias_t: Optional[float] = None
        self.sigma_xy = 0.0
        self.sigma_yaw = 0.0
        self.path = 0.0
        self.map = KeyframeMap(self.params.keyframes)
        self.reports: list[ClosureReport] = []
        self._closures: tuple = ()
        self.counts: dict[str, int] = defaultdict(int)
        self.scans_refused_few_beams = 0
        self.segment = 0
        self.using_imu = False
        self.rate = 0.0
        """Latest bias-corrected yaw rate (rad/s)."""
        self.speed = 0.0
        """Latest forward speed of the odometry (m/s), for de-skewing scans."""
        self.speed_lateral = 0.0
        """Its latest sideways speed (m/s; a holonomic robot's, else 0)."""
        self.twist_frame = TwistFrame()
        """Tells an odometry twist given in the odometry frame (a driver's mistake)."""
        self.twist_only = TwistOnly()
        """Tells an odometry that fills only its twist, and integrates its poses then."""
        self.input_notes.say('odom', '')
        self.zero_gyro = ZeroGyro()
        """Whether the IMU gives no yaw rate (exactly 0 while the wheels turn)."""
        self._odom_turn = 0.0
        self._last_imu: Optional[tuple[float, float]] = None
        self._last_odom = None
        self._last_kf_pose: Optional[np.ndarray] = None
        self._last_kf_id: Optional[int] = None
        self._last_fix_kf = -1
        self._last_check_t = -math.inf
        self._failed_checks = 0
        self._doubt_since: Optional[float] = None
        self._current: Optional[PreparedScan] = None
        self._current_cost = (0.0, 0.0)

    # -- Estimator protocol -----------------------------------------------------------------
    def set_mounting(self, transform: StaticTransform) -> None:
        """Take a static transform base_frame -> sensor frame (the imu's or the laser's)."""
        self._mounts.add(transform)
        self._imu_rotations.clear()
        self._sensor_poses.clear()

    def update(self, sample: Any) -> Optional[ClosureReport]:
        """
        Process one ImuSample, OdomSample or ScanSample (time order); ignore other samples.

        Returns the report of a closure attempt or a suspected kidnap that the
        scan produced, else None.
        """
        if isinstance(sample, ImuSample):
            self._integrate_gyro(sample.t, self._gyro_z(sample))
        elif isinstance(sample, OdomSample):
            if not self.twist_only.settled or self.twist_only.twist_only:
                sample = self._twist_only(sample)
            self._advance_odom(sample.t, sample.x, sample.y, sample.yaw)
            vx, vy = self.twist_frame.body_twist(sample)
            self.speed, self.speed_lateral = float(vx), float(vy)
            if self.twist_frame.in_odom_frame:
                self.counts['odometry_twist_rotated'] += 1
        elif isinstance(sample, ScanSample):
            return self._update_scan(sample)
        return None

    def result(self) -> LoopClosureResult:
        """Return the corrected pose, its uncertainty, counts, map size and every report."""
        if len(self._closures) != len(self.reports):
            self._closures = tuple(self.reports)
        return LoopClosureResult(
            mode=self.mode, pose=self.pose, raw_pose=self.raw.copy(),
            sigma_xy=self.sigma_xy, sigma_yaw=self.sigma_yaw, yaw_rate=self.rate,
            heading_source='imu' if self.using_imu else 'odom', gyro_bias=self.gyro_bias,
            path=self.path, segments=self.segment + 1, counts=frozen_counts(self.counts),
            keyframes=self.map.stored(), keyframe_memory_bytes=self.map.memory_bytes(),
            closures=self._closures, scans_refused_few_beams=self.scans_refused_few_beams)

    @property
    def pose(self) -> np.ndarray:
        """Return the corrected pose: x, y, yaw (m, m, rad)."""
        return se2_compose(self.correction, self.raw)

    def _gyro_z(self, sample: ImuSample) -> float:
        """Return the yaw rate (rad/s) of an IMU sample, rotated into the base frame."""
        gyro = np.asarray(sample.gyro, dtype=float)
        rotation = self._imu_rotation(sample.frame_id)
        if rotation is None:
            return float(gyro[2])
        z = float(gyro[2])
        if (rotation is _LEVEL and z != 0.0 and math.isfinite(z)
                and math.isfinite(gyro[0]) and math.isfinite(gyro[1])):
            return z    # (I gyro)[2] exactly: the zero products add nothing to a non-zero z
        return float((rotation @ gyro)[2])

    def _imu_rotation(self, frame: str) -> Optional[np.ndarray]:
        """
        Return the rotation sensor -> base of the IMU frame ``frame``, or None if unmounted.

        An identity rotation is returned as :data:`_LEVEL` (an IMU mounted level).
        """
        try:
            return self._imu_rotations[frame]
        except KeyError:
            mount = self._mount(frame, 'imu')
            rotation = rotation_matrix(mount) if mount is not None else None
            if rotation is not None and np.array_equal(rotation, _LEVEL):
                rotation = _LEVEL
            self._imu_rotations[frame] = rotation
            return rotation

    def _twist_only(self, sample: OdomSample) -> OdomSample:
        """Return an odometry sample with the poses its twist integrates to when twist-only."""
        was = self.twist_only.twist_only
        sample = self.twist_only.sample(sample)
        if self.twist_only.twist_only:
            self.counts['odometry_twist_only'] += 1
            if not was:
                self.input_notes.say('odom', self.twist_only.note())
        return sample

    def _mount(self, frame: str, kind: str) -> Optional[StaticTransform]:
        """
        Return the mounting of ``frame`` (through any chain, from its top), or None.

        By :func:`robot_calib.core.frames.find_mounting` (``kind`` 'imu' or 'lidar'),
        which says when the frame is not in the tree what is used instead.
        """
        fallback = 'the IMU taken as level in the base frame' if kind == 'imu' else \
            "the lidar taken at the base frame's origin"
        found = find_mounting(self._mounts, frame, None, kind, fallback)
        self.input_notes.say(f'{kind}:{frame}', found.note)
        return found.transform

    # -- what a variant supplies --------------------------------------------------------------
    @abc.abstractmethod
    def _registration_params(self) -> ScanMatchParams:
        """Return the scan-matching settings of this variant."""

    @abc.abstractmethod
    def _candidate_pose(self, kf: Keyframe, kf_pts: np.ndarray, res: MatchResult,
                        current: PreparedScan) -> tuple[np.ndarray, np.ndarray]:
        """Return the candidate pose of the current frame and the keyframe seen from it."""

    @abc.abstractmethod
    def _refusal(self, best: Candidate, cands: list, pose: np.ndarray) -> str:
        """Return why the best candidate is refused, or '' to accept it."""

    @abc.abstractmethod
    def _learn_bias(self, t: float, kf: Keyframe, res: MatchResult) -> None:
        """Learn from a good registration of the scan against the last keyframe."""

    @abc.abstractmethod
    def _before_correction(self, old: np.ndarray, new: np.ndarray) -> None:
        """Adjust the map before the pose jumps from ``old`` to ``new`` (m, m, rad)."""

    # -- scans --------------------------------------------------------------------------------
    def _update_scan(self, scan: ScanSample) -> Optional[ClosureReport]:
        """Turn the scan into points in the base frame (de-skewed) and process them."""
        sensor = self._sensor_pose(scan.frame_id)
        if scan.frame_id in self._upside_down:
            scan = mirrored(scan)
        if not self._scan_needed(scan.t) and self._count_unneeded(scan, sensor):
            return None
        motion = constant_motion(self.speed, self.rate, self.speed_lateral)
        pts, _ = scan_points(scan, sensor, motion=motion)
        if len(pts) < self.params.min_valid_beams:
            self.scans_refused_few_beams += 1
            return None
        reports = len(self.reports)
        self._process_points(scan.t, pts)
        return self.reports[-1] if len(self.reports) > reports else None

    def _sensor_pose(self, frame: str) -> Optional[tuple[float, float, float]]:
        """Return the planar pose (m, m, rad) of the laser frame ``frame``, or None."""
        try:
            return self._sensor_poses[frame]
        except KeyError:
            mount = self._mount(frame, 'lidar')
            pose = planar_pose(mount) if mount is not None else None
            self._sensor_poses[frame] = pose
            if mount is not None and upside_down(mount):
                self._upside_down.add(frame)
            else:
                self._upside_down.discard(frame)
            return pose

    def _scan_needed(self, t: float) -> bool:
        """Return True when a scan at ``t`` (s) is checked or made a keyframe, not only counted."""
        return self._keyframe_due() or (
            self._last_kf_id is not None
            and t - self._last_check_t >= self.params.motion.kidnap_check_interval)

    def _keyframe_due(self) -> bool:
        """Return True when the pose has moved a keyframe step from the last keyframe's."""
        if self._last_kf_pose is None:
            return True
        kp = self.params.keyframes
        d = se2_between(self._last_kf_pose, self.pose)
        return math.hypot(d[0], d[1]) >= kp.distance or abs(d[2]) >= kp.angle

    def _count_unneeded(self, scan: ScanSample, sensor: Optional[Sequence[float]]) -> bool:
        """
        Count a scan that is neither checked nor made a keyframe without computing its points.

        Its only effect is a count: refused (few valid beams) or used (as many
        points within ``keyframes.max_range``, when :func:`surely_within` proves
        that every point is); returns False, counting nothing, when that needs
        the points.
        """
        idx, r, _ = scan.beams()
        if len(idx) < self.params.min_valid_beams:
            self.scans_refused_few_beams += 1
            return True
        speed = math.hypot(self.speed, self.speed_lateral)
        if not surely_within(scan, r, sensor, speed, self.rate, self.params.keyframes.max_range):
            return False
        self.counts['scans_used'] += 1
        return True

    def _process_points(self, t: float, points: np.ndarray) -> None:
        """
        Process one scan (points (N, 2) in base_link, m) at ``t`` (s).

        Makes a keyframe when due, attempts a loop closure first, and checks
        for a kidnap.
        """
        p = self.params
        pts = np.asarray(points, dtype=float)
        pts = pts[np.all(np.isfinite(pts), axis=1)] if pts.ndim == 2 else np.zeros((0, 2))
        if len(pts):
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= p.keyframes.max_range]
        if len(pts) < p.min_valid_beams:
            self.counts['scans_rejected_few_beams'] += 1
            return
        self.counts['scans_used'] += 1
        self._current = None            # this scan's registration target: not prepared yet
        due = self._keyframe_due()
        if self._last_kf_id is not None and (
                due or t - self._last_check_t >= p.motion.kidnap_check_interval):
            self._last_check_t = t
            if self._local_check(t, pts) != 'ok':
                return          # kidnapped, or in doubt: no keyframe, no closure
        if not due:
            return
        self._attempt_closure(t, pts)
        self._add_keyframe(t, pts)

    def _prepared(self, pts: np.ndarray) -> PreparedScan:
        """
        Return the current scan ``pts`` prepared as registration target (once per scan).

        The local check and the closure attempt register against the same scan
        with the same settings; the time taken (s, wall and CPU) is kept in
        ``_current_cost`` so that an attempt's latency still counts it.
        """
        if self._current is None:
            start, cpu_start = time.perf_counter(), time.thread_time()
            self._current = PreparedScan(pts, self.match_params)
            self._current_cost = (time.perf_counter() - start, time.thread_time() - cpu_start)
        return self._current

    def _local_check(self, t: float, pts: np.ndarray) -> str:
        """
        Register the scan against the last keyframe at the dead-reckoning prediction.

        Learns the gyro bias from the heading difference (improved variant).
        Returns 'ok'; 'doubt' when the match is weak (under twice the kidnap
        inlier ratio) and lands over half the offset limits away from the
        prediction, or failed: then no keyframe is made from this scan and the
        next scan is checked again; or 'kidnap' (after restarting the map) when
        the scan has disagreed with odometry ``kidnap_checks`` times in a row,
        or stayed in doubt for ``kidnap_doubt_time``: the robot was kidnapped
        or carried.
        """
        m = self.params.motion
        kf = self.map.keyframes.get(self._last_kf_id)
        if kf is None:
            return 'ok'
        guess = se2_between(self.raw, kf.raw)             # keyframe frame in current frame
        res = register(kf.points.astype(float), self._prepared(pts), guess, self.match_params)
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
                self._learn_bias(t, kf, res)
            return 'ok'
        self._failed_checks += 1
        self.counts['kidnap_check_failed'] += 1
        if self._failed_checks < m.kidnap_checks:
            return 'doubt'
        self._restart_map(t, kf, res)
        return 'kidnap'

    def _restart_map(self, t: float, kf: Keyframe, res: MatchResult) -> None:
        """Kidnapped or carried: the map no longer locates the robot. Start a new one."""
        self.counts['kidnaps'] += 1
        self.reports.append(ClosureReport(t=t, accepted=False, reason='kidnap_suspected',
                                          keyframes_tried=(kf.kid,), scores=(),
                                          similarities=(), pose_before=self.pose,
                                          pose_after=self.pose,
                                          inlier_ratio=res.inlier_ratio))
        self.map.clear()
        self.segment += 1
        self._last_kf_pose = None
        self._last_kf_id = None
        self._failed_checks = 0
        self._doubt_since = None

    def _add_keyframe(self, t: float, pts: np.ndarray) -> None:
        """Make a keyframe of the scan at the corrected pose (voxel-thinned float32 points)."""
        kp = self.params.keyframes
        pose = self.pose
        self._last_kf_pose = pose
        thin = voxel_thin(pts, kp.voxel).astype(np.float32)
        kf = Keyframe(self.map.next_id, t, pose.copy(), thin, self.path, self.segment,
                      self.map.cell(pose), raw=self.raw.copy(), rate=self.rate)
        stored = self.map.add(kf)
        self._last_kf_id = kf.kid
        if not stored:
            # Not stored in the map; kept only as the reference of the local check.
            self.counts['keyframes_skipped_full'] += 1
            return
        self.counts['keyframes'] += 1

    # -- loop closure -------------------------------------------------------------------------
    def _attempt_closure(self, t: float, pts: np.ndarray) -> None:
        """Register the most similar nearby keyframes, choose, refuse or correct; report."""
        p = self.params
        pose = self.pose
        dp = p.detection
        radius = min(dp.max_radius, dp.base_radius + dp.radius_gain * self.sigma_xy)
        ids = self.map.near(pose, radius, self.path, dp.min_loop_travel, dp.max_prefilter)
        if not ids:
            return
        start = time.perf_counter()
        cpu_start = time.thread_time()
        if self._current is not None:
            # prepared by the local check: the attempt's latency counts it all the same
            start -= self._current_cost[0]
            cpu_start -= self._current_cost[1]
        current = self._prepared(pts)
        kfs = [self.map.keyframes[kid] for kid in ids]
        grid = OverlapGrid(current.points, current.tree, dp.similarity_gate)
        found = similarities(kfs, [se2_between(pose, kf.pose) for kf in kfs], grid, dp,
                             self.sigma_yaw)
        sims = [(sim, kid, off) for kid, (sim, off) in zip(ids, found)]
        sims.sort(key=lambda s: -s[0])
        chosen = [s for s in sims if s[0] >= dp.min_similarity][:dp.candidates]
        fields = {'t': t, 'pose_before': pose.copy(), 'pose_after': pose.copy(),
                  'radius': radius}
        self.counts['closure_attempts'] += 1
        if not chosen:
            top = sims[:dp.candidates]
            self._finish(start, cpu_start, accepted=False, reason='no_similar_keyframe',
                         keyframes_tried=tuple(s[1] for s in top), scores=(),
                         similarities=tuple(s[0] for s in top), **fields)
            return
        cands = [self._register(kid, sim, off, pose, current) for sim, kid, off in chosen]
        best = max(cands, key=lambda c: c.score)
        fields.update(keyframes_tried=tuple(c.keyframe for c in cands),
                      scores=tuple(c.score for c in cands),
                      similarities=tuple(c.similarity for c in cands), chosen=best.keyframe,
                      min_eigenvalue=best.match.min_eigenvalue,
                      inlier_ratio=best.match.inlier_ratio)
        reason = self._refusal(best, cands, pose)
        if reason:
            self._finish(start, cpu_start, accepted=False, reason=reason, **fields)
            return
        self._apply(t, best, pose)
        fields['pose_after'] = after = self.pose
        correction = np.array([*(after[:2] - pose[:2]), wrap_angle(after[2] - pose[2])])
        self._finish(start, cpu_start, accepted=True, reason='accepted', correction=correction,
                     **fields)

    def _register(self, kid: int, sim: float, off: float, pose: np.ndarray,
                  current: PreparedScan) -> Candidate:
        """Register keyframe ``kid`` against the current scan from the yaw offset ``off``."""
        sp = self.params.scoring
        kf = self.map.keyframes[kid]
        guess = se2_between(pose, kf.pose)
        guess = np.array([*(rot2(off) @ guess[:2]), guess[2] + off])
        kf_pts = kf.points.astype(float)
        res = register(kf_pts, current, guess, self.match_params)
        cur_pose, rel = self._candidate_pose(kf, kf_pts, res, current)
        score, inl, out = score_candidate(kf_pts, rel, current.tree, sp.inlier_distance,
                                          sp.outlier_weight)
        return Candidate(kid, sim, res, cur_pose, score, inl, out)

    def _apply(self, t: float, best: Candidate, pose: np.ndarray) -> None:
        """Make ``best.pose`` the current pose; keep later poses and the map consistent."""
        new = best.pose
        self._before_correction(pose, new)
        self.correction = se2_compose(new, se2_inverse(self.raw))
        cov = best.match.covariance
        self.sigma_xy = float(math.sqrt(max(0.0, cov[0, 0] + cov[1, 1]))) \
            if np.all(np.isfinite(cov)) else 0.02
        self.sigma_yaw = float(math.sqrt(max(0.0, cov[2, 2]))) if np.isfinite(cov[2, 2]) \
            else 0.005
        self._last_fix_kf = self.map.next_id
        self.counts['closures_accepted'] += 1

    def _finish(self, start: float, cpu_start: float, **fields: Any) -> None:
        """Time the attempt (ms since ``start``), count a refusal, and keep the report."""
        report = ClosureReport(latency_ms=1000.0 * (time.perf_counter() - start),
                               cpu_ms=1000.0 * (time.thread_time() - cpu_start), **fields)
        if not report.accepted:
            self.counts['closures_refused'] += 1
            self.counts['refused_' + report.reason] += 1
        self.reports.append(report)
