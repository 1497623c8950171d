# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The seed-faithful loop-closure variant (``mode: seed``, seed 001).

Registration is kiss-icp alone (point-to-point, no point-to-line
refinement); the heading of a candidate comes from the centroids of the
matched points (:func:`centroid_heading`); the best-scoring candidate is
taken whenever its match succeeded and its score reaches ``min_score``
(no ambiguity, degeneracy or plausibility refusals); no gyro bias is
learned and a correction moves only the current pose.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from robot_calib.core.geometry import se2_apply, se2_between, se2_compose, se2_inverse, wrap_angle
from robot_calib.core.scan_match import MatchResult, PreparedScan, ScanMatchParams
from robot_calib.methods.loop_closure_correction.common import (base_refusal, Candidate,
                                                                Keyframe)
from robot_calib.methods.loop_closure_correction.params import ScoringParams
from robot_calib.methods.loop_closure_correction.variant_base import LoopClosureBase


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


def refusal(best: Candidate, scoring: ScoringParams) -> str:
    """Return why the seed refuses the best candidate (failed match, low score), or ''."""
    return base_refusal(best, scoring.min_score)


class SeedLoopClosure(LoopClosureBase):
    """
    Loop-closure correction as seed 001 describes it (Estimator protocol).

    See :class:`robot_calib.methods.loop_closure_correction.variant_base.LoopClosureBase`
    for ``set_mounting``, ``update``, ``result`` and ``reset``.
    """

    mode: ClassVar[str] = 'seed'

    def _registration_params(self) -> ScanMatchParams:
        """Return kiss-icp's point-to-point ICP without the refinement."""
        return ScanMatchParams(**{**self.params.scan_match.__dict__, 'refine': False,
                                  'coarse': 'kiss_icp'})

    def _candidate_pose(self, kf: Keyframe, kf_pts: np.ndarray, res: MatchResult,
                        current: PreparedScan) -> tuple[np.ndarray, np.ndarray]:
        """Return the registered position with the centroid heading, and the keyframe seen."""
        cur_pose = se2_compose(kf.pose, se2_inverse(res.pose))
        if res.reason != '':
            return cur_pose, res.pose
        cur_pose[2] = self._seed_heading(kf, kf_pts, res, current, cur_pose)
        return cur_pose, se2_between(cur_pose, kf.pose)

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
        """Return why the best candidate is refused, or '' (the seed takes the best)."""
        return refusal(best, self.params.scoring)

    def _learn_bias(self, t: float, kf: Keyframe, res: MatchResult) -> None:
        """Learn nothing: the seed has no bias estimate."""

    def _before_correction(self, old: np.ndarray, new: np.ndarray) -> None:
        """Leave the map as it is: the seed corrects only the current pose."""
