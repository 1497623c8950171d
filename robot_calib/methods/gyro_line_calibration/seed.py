# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Seed-faithful variant of ``gyro_line_calibration`` (``mode='seed'``, seed 000 S1-S3 as written).

- work phase (S1): every line passing condition 1 is stored as a reference
  line (both endpoints, angle modulo pi, time), except a line satisfying
  condition 2 with a stored reference: that is the same wall again, and the
  earliest, least-drifted copy is kept. At most ``seed.max_references`` are
  stored (later ones are dropped).
- edge-following phase (S2, selected by the ``seed.phase`` parameter, the
  ``gyro_line/edge_following`` topic or ``seed.phase_switch_time``): the first
  line passing condition 1 is the *first line*. If no reference satisfies
  condition 2 with it, the next line is tried (the seed is silent here).
- S3: among references satisfying condition 2 (length difference, start AND
  end point distances, angle difference, each within its tolerance) take the
  smallest angle error; when ``angle_threshold < |error| <= angle_tolerance``:
  ``calibrated = w1 * reference + w2 * line`` (w1 + w2 = 1, w1 > w2) and the
  heading is corrected by ``calibrated - line`` (so by ``w1 * error``).
- Re-calibration: while still edge-following, a line fitted more than
  ``recalibration_time`` after the last calibration, or any line at least
  ``recalibration_length_ratio`` times as long as the first line, is the
  *second line* and is calibrated the same way.

The input handling (heading, pose, scans, trust) is :mod:`.variant_base`'s.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from robot_calib.core.geometry import wrap_half_pi
from robot_calib.core.lines import Line
from robot_calib.methods.gyro_line_calibration.common import Correction
from robot_calib.methods.gyro_line_calibration.params import MatchParams
from robot_calib.methods.gyro_line_calibration.variant_base import GyroLineBase


def condition2(ref: Line, new: Line, match: MatchParams) -> Optional[float]:
    """
    Return the angle error ref - new (rad, modulo pi) when condition 2 holds, else None.

    Seed 000, S31-S33: (a) length difference, (b) start points AND end points,
    (c) angle difference, each within its tolerance.
    """
    if abs(ref.length - new.length) > match.length_tolerance:  # S31
        return None
    err = wrap_half_pi(ref.angle - new.angle)
    p1, p2 = new.p1, new.p2
    if abs(ref.angle - new.angle) > math.pi / 2:  # directions flipped across +-pi/2
        p1, p2 = p2, p1
    if (np.linalg.norm(ref.p1 - p1) > match.endpoint_tolerance
            or np.linalg.norm(ref.p2 - p2) > match.endpoint_tolerance):  # S32
        return None
    if abs(err) > match.angle_tolerance:  # S33
        return None
    return err


def condition2_many(refs: np.ndarray, new: Line, match: MatchParams) -> np.ndarray:
    """
    Vectorised :func:`condition2` over references (N, 6).

    Columns: ``[p1x, p1y, p2x, p2y, angle, length]`` (m, rad).

    Returns the angle errors (rad), NaN where condition 2 fails.
    """
    if refs.shape[0] == 0:
        return np.zeros(0)
    err = wrap_half_pi(refs[:, 4] - new.angle)
    flip = np.abs(refs[:, 4] - new.angle) > math.pi / 2
    n1 = np.where(flip[:, None], new.p2, new.p1)
    n2 = np.where(flip[:, None], new.p1, new.p2)
    ok = np.abs(refs[:, 5] - new.length) <= match.length_tolerance  # S31
    ok &= np.hypot(*(refs[:, 0:2] - n1).T) <= match.endpoint_tolerance  # S32
    ok &= np.hypot(*(refs[:, 2:4] - n2).T) <= match.endpoint_tolerance
    ok &= np.abs(err) <= match.angle_tolerance  # S33
    return np.where(ok, err, np.nan)


def condition2_near(refs: np.ndarray, mids: np.ndarray, new: Line,
                    match: MatchParams) -> tuple[np.ndarray, np.ndarray]:
    """
    Return :func:`condition2_many` on the references that can pass, and their indices.

    ``mids`` (2, N) are the references' midpoints (m), x then y. Both endpoints within
    ``endpoint_tolerance`` of the new line's (S32) put the midpoints within it
    too (the mean of the two offsets), so only references whose midpoint is
    that close (each coordinate, plus a rounding slack) are tested; the angle
    errors (rad, NaN where condition 2 fails) are those of :func:`condition2_many`,
    element by element, in index order.
    """
    if refs.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    mx, my = new.midpoint.tolist()
    lim = match.endpoint_tolerance + 1e-6
    near = np.abs(mids[0] - mx) <= lim
    near &= np.abs(mids[1] - my) <= lim
    idx = near.nonzero()[0]
    return idx, condition2_many(refs[idx], new, match)


def seed_calibrated_angle(ref_angle: float, line_angle: float, w1: float) -> float:
    """Return ``w1 * ref + w2 * line`` (rad), line unwrapped next to ref (seed 000, S3)."""
    line_near = ref_angle - wrap_half_pi(ref_angle - line_angle)
    return w1 * ref_angle + (1.0 - w1) * line_near  # seed 000 S3: calibrated angle


def seed_heading_correction(ref_angle: float, line_angle: float, w1: float) -> float:
    """Return the heading correction ``calibrated - line`` (rad) (seed 000, S3)."""
    line_near = ref_angle - wrap_half_pi(ref_angle - line_angle)
    return seed_calibrated_angle(ref_angle, line_angle, w1) - line_near


class SeedGyroLine(GyroLineBase):
    """
    The seed-faithful estimator: store references in the work phase, correct when edge-following.

    An :class:`~robot_calib.core.estimator.Estimator`: ``set_mounting``,
    ``update`` (the pose estimate of an odometry sample, the corrections of a scan), ``result``
    (:class:`~robot_calib.methods.gyro_line_calibration.common.GyroLineResult`), ``reset``.

    :param params: the parameters (defaults when None; ``mode`` is not read).
    """

    def reset(self) -> None:
        """Forget the state (pose, references, phase); keep the parameters and mountings."""
        super().reset()
        self._seed_state = 'first'
        self._seed_t_cal = -math.inf
        self._seed_first_len = math.inf
        self._seed_refs = np.zeros((self.params.seed.max_references, 6))
        self._seed_mids = np.zeros((2, self.params.seed.max_references))  # midpoints x, y (m)

    def _phase_started(self) -> None:
        self._seed_state = 'first'

    def _step(self, lines: list[Line], t: float) -> list[Correction]:
        return self._seed_step(lines, t)

    def _seed_step(self, lines: list[Line], t: float) -> list[Correction]:
        """Store references (work phase) or calibrate (edge following) with one scan's lines."""
        n = len(self.references)
        refs, mids = self._seed_refs[:n], self._seed_mids[:, :n]
        if not self.edge_following:  # S1: store references
            self._store_references(lines, t)
            return []
        p = self.params
        out = []
        for line in lines:  # S2, S3 and re-calibration
            if self._seed_state == 'first':
                kind = 'first'
            elif t - self._seed_t_cal > p.seed.recalibration_time:
                kind = 'time'
            elif line.length >= p.seed.recalibration_length_ratio * self._seed_first_len:
                kind = 'length'
            else:
                continue
            idx, errs = condition2_near(refs, mids, line, p.match)
            if not np.any(np.isfinite(errs)):
                self.count('seed_unmatched_lines')
                continue
            i = int(np.nanargmin(np.abs(errs)))  # S3: smallest angle error (first of equals)
            best, best_err = self.references[int(idx[i])], float(errs[i])
            if self._seed_state == 'first' or kind == 'length':
                self._seed_first_len = line.length
            self._seed_state = 'calibrated'
            self._seed_t_cal = t
            if abs(best_err) <= p.match.angle_threshold:
                self.count('seed_below_threshold')
                continue
            delta = seed_heading_correction(best.line.angle, line.angle, p.seed.w1)
            before = self.pose
            self.x[2] += delta
            best.matches += 1
            out.append(Correction(t, delta, best_err, (best.id,), (line,), (best.line,),
                                  self.pose, kind, 0.0, before))
            self._record(out[-1])
            break  # the pose changed: later lines of this scan were placed with the old one
        return out

    def _store_references(self, lines: list[Line], t: float) -> None:
        """S1: store each line as a reference unless it is a stored wall again (condition 2)."""
        p = self.params
        for line in lines:
            n = len(self.references)
            _, errs = condition2_near(self._seed_refs[:n], self._seed_mids[:, :n], line,
                                      p.match)
            if np.any(np.isfinite(errs)):
                continue  # the same wall as a stored reference: keep the earliest copy
            if len(self.references) >= p.seed.max_references:
                self.count('references_full')
                continue
            ref = self._new_reference(line, t, np.zeros((2, 2)))
            ref.confirmed = True
            self._seed_refs[len(self.references)] = [*line.p1, *line.p2, line.angle,
                                                     line.length]
            self._seed_mids[:, len(self.references)] = line.midpoint
            self._log_reference(ref)
            self.references.append(ref)
