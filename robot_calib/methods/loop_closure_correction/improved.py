# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The improved loop-closure variant (``mode: improved``, the default).

Over the seed (:mod:`.seed`): registration per ``scan_match`` (by default
point-to-line refinement from the similarity check's prediction); the
candidate heading from the registration itself; refusals of degenerate
(corridor) and unconverged matches, of ambiguous closures (another
hypothesis nearly as good) and of implausible corrections given the pose
uncertainty; each correction spread over the keyframes made since the last
fix (``distribute_correction``); and the residual gyro bias, its drift rate
and the gyro scale error learned with a Kalman filter (:mod:`.gyro_filter`)
from the registrations against the last keyframe (``motion.estimate_gyro_bias``,
``estimate_bias_drift``, ``estimate_gyro_scale``).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from robot_calib.core.geometry import rot2, se2_compose, se2_inverse, wrap_angle
from robot_calib.core.scan_match import MatchResult, PreparedScan, ScanMatchParams
from robot_calib.methods.loop_closure_correction.common import (base_refusal, Candidate,
                                                                Keyframe)
from robot_calib.methods.loop_closure_correction.gyro_filter import GyroErrorFilter
from robot_calib.methods.loop_closure_correction.params import ScoringParams
from robot_calib.methods.loop_closure_correction.variant_base import LoopClosureBase


def refusal(best: Candidate, cands: list, pose: np.ndarray, sigma_xy: float,
            sigma_yaw: float, scoring: ScoringParams) -> str:
    """
    Return why the best candidate is refused, or '' to accept it.

    ``cands`` are all the registered candidates (``best`` among them or not),
    ``pose`` the current pose before the correction (m, m, rad), ``sigma_xy``
    (m) and ``sigma_yaw`` (rad) its uncertainty.
    """
    sp = scoring
    reason = base_refusal(best, sp.min_score)
    if reason:
        return reason
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
    if (math.hypot(d[0], d[1]) > max(sp.min_correction_floor, k * sigma_xy)
            or abs(wrap_angle(d[2])) > max(0.1 * sp.min_correction_floor, k * sigma_yaw)):
        return 'implausible_correction'
    return ''


class ImprovedLoopClosure(LoopClosureBase):
    """
    Loop-closure correction with refusals, map consistency and bias learning (Estimator).

    See :class:`robot_calib.methods.loop_closure_correction.variant_base.LoopClosureBase`
    for ``set_mounting``, ``update``, ``result`` and ``reset``.
    """

    mode: ClassVar[str] = 'improved'

    def _registration_params(self) -> ScanMatchParams:
        """Return the ``scan_match`` parameters as they are."""
        return self.params.scan_match

    def _candidate_pose(self, kf: Keyframe, kf_pts: np.ndarray, res: MatchResult,
                        current: PreparedScan) -> tuple[np.ndarray, np.ndarray]:
        """Return ``keyframe_pose (+) inverse(relative)`` and the registered relative pose."""
        return se2_compose(kf.pose, se2_inverse(res.pose)), res.pose

    def _refusal(self, best: Candidate, cands: list, pose: np.ndarray) -> str:
        """Return why the best candidate is refused, or '' to accept it (:func:`refusal`)."""
        return refusal(best, cands, pose, self.sigma_xy, self.sigma_yaw, self.params.scoring)

    def reset(self) -> None:
        """Forget the state, the gyro error filter's too."""
        super().reset()
        self.gyro_filter = GyroErrorFilter(self.params.motion)

    def _learn_bias(self, t: float, kf: Keyframe, res: MatchResult) -> None:
        """Update the gyro error filter (:mod:`.gyro_filter`) from one registration."""
        m = self.params.motion
        dt = t - kf.t
        if not self.using_imu or not m.estimate_gyro_bias or dt < 0.2:
            return
        if abs(kf.rate) > m.bias_max_rate or abs(self.rate) > m.bias_max_rate:
            self.counts['bias_skipped_turning'] += 1
            return
        d_est = wrap_angle(self.raw[2] - kf.raw[2])      # gyro heading change (errors removed)
        d_scan = wrap_angle(-res.pose[2])                  # scan heading change
        var_yaw = res.covariance[2, 2] if np.isfinite(res.covariance[2, 2]) else 0.0
        r_var = (math.sqrt(max(0.0, var_yaw)) + m.scan_yaw_sigma) ** 2
        f = self.gyro_filter
        if not f.update(t, dt, d_est - d_scan, d_scan, r_var):
            self.counts['bias_updates_gated'] += 1
            return
        self.gyro_bias = f.bias_at(t)
        self.gyro_bias_rate = float(f.x[1])
        self.gyro_scale = f.scale
        self.bias_var = float(f.P[0, 0])
        self._bias_t = t
        self.counts['bias_updates'] += 1

    def _before_correction(self, old: np.ndarray, new: np.ndarray) -> None:
        """Spread the correction over the keyframes made since the last fix (when asked)."""
        if self.params.distribute_correction:
            self._distribute(old, new)

    def _distribute(self, old: np.ndarray, new: np.ndarray) -> None:
        """Apply a growing share of the correction to the keyframes made since the last fix."""
        since = [kf for kf in self.map.keyframes.values()
                 if kf.kid >= self._last_fix_kf and kf.kid >= 0]
        if not since:
            return
        delta = se2_compose(new, se2_inverse(old))          # world-frame correction
        p0 = min(kf.path for kf in since)
        span = max(1e-6, self.path - p0)
        for kf in since:
            w = (kf.path - p0) / span
            partial = np.array([w * delta[0], w * delta[1], w * delta[2]])
            # rotate about the current position, as the correction does
            rel = kf.pose - np.array([old[0], old[1], 0.0])
            moved = rot2(partial[2]) @ rel[:2] + old[:2] + w * (new[:2] - old[:2])
            self.map.move(kf, np.array([moved[0], moved[1],
                                        wrap_angle(kf.pose[2] + partial[2])]))
