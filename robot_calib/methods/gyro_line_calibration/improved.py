# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Improved variant of ``gyro_line_calibration`` (``mode='improved'``, automatic).

For robots that never announce a phase: an extended Kalman filter over
``[x, y, heading, gyro bias, gyro scale]`` (odometry and gyro predict,
:mod:`.variant_base`; a matched wall line updates angle and distance, here).
References accumulate all the time: a line that matches nothing becomes a
tentative reference, confirmed after it was seen again in several scans
(people and other moving things are never confirmed). Each reference keeps
the covariance its angle and distance had when it was made. Guards against
matching the wrong wall (:mod:`.improved_gate`): the reference must overlap
the new line along its length (within the position uncertainty); the
innovation (angle AND perpendicular distance) must pass a chi-square gate
built from the current pose covariance; a line that could belong to two
references at different distances (parallel walls, shelves) or angles (the
facets of a round wall) is ambiguous and skipped; lines of one scan must agree
on the heading correction (the outliers are dropped and their references
marked; a reference that keeps disagreeing, such as moved furniture, is
retired); a correction needs support from two
distinct references, or from the same one in two scans that agree over time.
A 90-degree symmetric room cannot alias because the heading uncertainty keeps
the angle gate far below 90 degrees.

While the odometry stands still the gyro reads its own bias (a zero angular
rate update, here): a turn-on bias far beyond ``bias_sigma0`` is learnt at the
first stop instead of rotating the first references and drifting past every gate.
"""

from __future__ import annotations

from collections import deque
import math
import statistics
from typing import Optional

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.geometry import rot2, wrap_angle, wrap_half_pi
from robot_calib.core.lines import Line, line_from_endpoints
from robot_calib.methods.gyro_line_calibration.common import Correction, Reference
from robot_calib.methods.gyro_line_calibration.improved_gate import (
    gate, gate_state, line_jacobian, line_model, line_noise, line_noise_diag, overlaps, prefilter,
    ref_arrays)
from robot_calib.methods.gyro_line_calibration.variant_base import GyroLineBase

_I2 = np.eye(2)
_I5 = np.eye(5)
_I2.flags.writeable = _I5.flags.writeable = False  # shared identities: read only


class ImprovedGyroLine(GyroLineBase):
    """
    The automatic estimator: a Kalman filter corrected by matched, supported wall lines.

    An :class:`~robot_calib.core.estimator.Estimator`: ``set_mounting``,
    ``update`` (the pose estimate of an odometry sample, the corrections of a scan), ``result``
    (:class:`~robot_calib.methods.gyro_line_calibration.common.GyroLineResult`), ``reset``.

    :param params: the parameters (defaults when None; ``mode`` is not read).
    """

    def reset(self) -> None:
        """Forget the state (pose, references, support); keep the parameters and mountings."""
        super().reset()
        self.tentative: list[Reference] = []
        self._support: deque = deque()
        self._last_update = -math.inf
        self._cum_correction = 0.0
        self._ref_cache: tuple = ((), None)  # (reference lines, their ref_arrays)
        self._still_since: Optional[float] = None  # odometry standing still since (s)
        self._still_rates: list = []  # (s, rad/s) gyro intervals of the standstill block
        self._lock: deque = deque(maxlen=50)  # (lines agreeing, contradicting) per scan
        self._lock_sums = [0, 0]  # the window's lines on references, and contradicting ones

    # -- standstill -----------------------------------------------------------------------
    def _update_odom(self, s: T.OdomSample) -> None:
        """Apply one odometry sample, then learn the gyro bias if the robot stands still."""
        super()._update_odom(s)
        gyro_dt, gyro_int = self._flushed_dt, self._flushed_wdt
        self._flushed_dt = self._flushed_wdt = 0.0
        ip = self.params.improved
        if not ip.standstill_update or self._odom_t != s.t or gyro_dt <= 0.0:
            return  # off, or the sample was not applied (a repeat, a jump)
        if self._odom_speed >= ip.standstill_speed or abs(self._odom_rate) >= ip.standstill_rate:
            self._still_since = None
            self._still_rates.clear()
            return
        if self._still_since is None:
            self._still_since = s.t
        if s.t - self._still_since < ip.standstill_settle or not self._use_gyro(s.t) \
                or s.t < self._untrusted_until:
            self._still_rates.clear()
            return
        mean_rate = gyro_int / gyro_dt
        if abs(mean_rate) > ip.standstill_max_rate:
            self.count('standstill_refused_gyro_turning')
            self._still_rates.clear()
            return
        self._still_rates.append((gyro_dt, mean_rate))
        if len(self._still_rates) >= 5 and \
                sum(d for d, _ in self._still_rates) >= ip.standstill_block:
            self._zero_rate_update(self._still_rates)
            self._still_rates.clear()

    def _zero_rate_update(self, intervals: list) -> None:
        """
        Update with the gyro rates (rad/s) averaged over intervals (s) of standing still.

        The heading rate ``rate * (1 - s) - b`` is zero, so ``rate * (1 - s)``
        measures ``b`` (the scale is not seen at rest: it is held). The noise of
        the block's mean comes from the spread of its intervals (white noise:
        variance of an interval's mean = q^2 / its length), never below a tenth
        of ``gyro_noise``. The heading follows through its correlation with the bias.
        """
        total = sum(d for d, _ in intervals)
        mean = sum(d * r for d, r in intervals) / total
        q2 = sum(d * (r - mean) ** 2 for d, r in intervals) / (len(intervals) - 1)
        x, P = self.x, self.P
        gain = 1.0 - x[4]
        variance = max(q2, (0.1 * self.params.improved.gyro_noise) ** 2) / total * gain ** 2
        PH = P[:, 3].copy()
        K = PH / (PH[3] + variance)
        x += K * (mean * gain - x[3])
        P -= np.outer(K, PH)
        self.count('standstill_updates')

    def _tentative_count(self) -> int:
        return len(self.tentative)

    def _step(self, lines: list[Line], t: float) -> list[Correction]:
        return self._improved_step(lines, t)

    # -- matching ------------------------------------------------------------------------
    def _line_noise(self, line: Line) -> np.ndarray:
        return line_noise(line, self.params.improved)

    def _reference_cov(self, line: Line) -> np.ndarray:
        """Covariance (angle, distance) of a new reference: pose covariance + fit noise."""
        H = line_jacobian(line, line.normal, self.x[:2])
        return H @ self.P @ H.T + self._line_noise(line)

    def _gate(self, refs: list, line: Line, margin: float, chi2: float,
              pre: Optional[tuple] = None, state: Optional[tuple] = None) -> list[tuple]:
        """Return :func:`gate` of ``line`` (``state``: :func:`gate_state`, made when None)."""
        if not refs or (pre is not None and not any(pre[2])):
            return []  # nothing to gate: no need for the line's noise
        return gate(refs, line, margin, chi2, state or gate_state(self.x, self.P),
                    line_noise_diag(line, self.params.improved),
                    self.params.match.angle_tolerance, pre)

    def _ref_arrays(self) -> tuple:
        """Return :func:`ref_arrays` of the references, rebuilt only when a line changed."""
        key = [r.line for r in self.references]
        old, arrays = self._ref_cache
        if arrays is None or len(key) != len(old) or any(a is not b for a, b in zip(key, old)):
            arrays = ref_arrays(self.references)
            self._ref_cache = (key, arrays)  # the lines are frozen: identity is enough
        return arrays

    def _improved_step(self, lines: list[Line], t: float) -> list[Correction]:
        """Match one scan's lines, grow the tentative references, update the filter."""
        ip = self.params.improved
        pos_sigma = math.sqrt(max(self.P[0, 0], self.P[1, 1], 0.0))
        margin = ip.overlap_margin + 3.0 * pos_sigma
        matches, contradicting = [], 0
        pre = prefilter(self.references, lines, margin, self.params.match.angle_tolerance,
                        self._ref_arrays()) if self.references else None
        state = gate_state(self.x, self.P)  # neither changes before the filter update
        for k, line in enumerate(lines):
            gated = self._gate(self.references, line, margin, 4.0 * ip.gate_chi2,
                               None if pre is None else
                               (pre[0][k], pre[1][k], pre[2][k], pre[3], pre[4]), state)
            close = [g for g in gated if g[0] <= ip.gate_chi2]
            if gated:
                if not close:
                    self.count('lines_outside_gate')
                    contradicting += pre[5][k]
                    continue
                rhos = [g[2][1] for g in gated]
                angles = [g[2][0] for g in gated]
                if len(gated) > 1 and (max(rhos) - min(rhos) > ip.ambiguity_distance + 1e-9 or
                                       max(angles) - min(angles) > ip.ambiguity_angle + 1e-12):
                    # two references within reach at different distances (parallel walls) or
                    # at different angles (the facets of a curved wall): either could be meant
                    self.count('lines_ambiguous')
                    continue
                nis, ref, y, H, R = min(close, key=lambda g: g[0])
                ref.t_last = t
                matches.append((line, ref, y, H, R))
                continue
            if pre is not None:
                contradicting += pre[5][k]
            self._tentative_step(line, t, margin)
        self._age_tentative(t)
        self._watch_lock(t, len(matches), contradicting)
        if not matches:
            return []
        return self._filter_update(matches, t)

    # -- lock on the walls ----------------------------------------------------------------
    def _watch_lock(self, t: float, agreeing: int, contradicting: int) -> None:
        """
        Watch whether the walls still agree with the heading (one scan at ``t``, s).

        ``contradicting`` lines lie on a reference (:func:`prefilter`) but matched
        nothing; ``agreeing`` ones were matched. When the former are a large
        share of the lines on references over the last 50 scans, the heading has
        lost the walls: a turn with a gyro scale far beyond its prior left it
        outside every gate, and new references are being made in the rotated
        frame, where they will agree with it from then on.
        """
        if not (agreeing or contradicting):
            return
        lock, sums = self._lock, self._lock_sums
        if len(lock) == lock.maxlen:
            a, c = lock[0]
            sums[0] -= a + c
            sums[1] -= c
        lock.append((agreeing, contradicting))
        sums[0] += agreeing + contradicting
        sums[1] += contradicting
        ip = self.params.improved
        on_refs, against = sums
        if against >= ip.lock_min_contradictions and against >= ip.lock_contradiction * on_refs:
            if not self.walls_contradict(t):
                self.lock_lost_episodes += 1
                self.count('heading_contradicted_by_walls')
            self.lock_lost_last = t

    # -- references ----------------------------------------------------------------------
    def _extend(self, ref: Reference, line: Line) -> None:
        """Extend a reference's endpoints to cover a matched line (projected onto it)."""
        u = ref.line.direction
        c = ref.line.midpoint
        proj = [float(u @ (p - c)) for p in (ref.line.p1, ref.line.p2, line.p1, line.p2)]
        lo, hi = min(proj), max(proj)
        if hi - lo > ref.line.length + 1e-6:
            ref.line = line_from_endpoints(c + lo * u, c + hi * u, ref.line.t, ref.line.variance,
                                           ref.line.n_cells)

    def _replace(self, line: Line, before: np.ndarray) -> Line:
        """Return ``line`` moved from pose ``before`` to the current pose estimate."""
        dth = float(self.x[2] - before[2])
        if dth == 0.0 and self.x[0] == before[0] and self.x[1] == before[1]:
            return line
        R = rot2(dth)
        o = before[:2]
        p1 = R @ (line.p1 - o) + self.x[:2]
        p2 = R @ (line.p2 - o) + self.x[:2]
        return line_from_endpoints(p1, p2, line.t, line.variance, line.n_cells)

    def _refine(self, ref: Reference, line: Line) -> None:
        """
        Fuse a matched observation into a reference (angle and distance, Kalman weights).

        The observation's covariance is the current pose covariance projected on
        the line plus the fit noise, doubled because the pose was itself corrected
        with this reference before (the two are not independent).
        """
        y, H, s = line_model(ref.line, line, self.x[:2])
        A = np.array([[1.0, 0.0], [s, 1.0]])
        c_obs = 2.0 * (H @ self.P @ H.T + self._line_noise(line))
        # observation in the reference's (angle, distance at its midpoint) coordinates
        Ainv = np.linalg.inv(A)
        z = Ainv @ (-y)
        c_z = Ainv @ c_obs @ Ainv.T
        K = ref.cov @ np.linalg.inv(ref.cov + c_z)
        dz = K @ z
        ref.cov = (_I2 - K) @ ref.cov
        mid = ref.line.midpoint
        half = 0.5 * ref.line.length
        ang = ref.line.angle + float(dz[0])
        u = np.array([math.cos(ang), math.sin(ang)])
        mid = mid + float(dz[1]) * ref.line.normal
        ref.line = line_from_endpoints(mid - half * u, mid + half * u, ref.line.t,
                                       ref.line.variance, ref.line.n_cells)

    def _tentative_step(self, line: Line, t: float, margin: float) -> None:
        """Confirm the tentative reference ``line`` matches, or make it a new tentative one."""
        ip = self.params.improved
        loose = self._gate(self.tentative, line, margin, 4.0 * ip.gate_chi2)
        if loose:
            nis, ref, y, H, R = min(loose, key=lambda g: g[0])
            if t > ref.t_last:
                ref.n_seen += 1
            ref.t_last = t
            self._extend(ref, line)
            if ref.n_seen >= ip.confirm_scans and t - ref.t_created >= ip.confirm_time:
                ref.confirmed = True
                self.tentative.remove(ref)
                self._add_reference(ref)
                self.count('references_confirmed')
            return
        # never next to an existing reference: that would duplicate a wall at a drifted place
        for ref in self.references:
            err = wrap_half_pi(ref.line.angle - line.angle)
            if abs(err) <= self.params.match.angle_tolerance \
                    and abs(ref.line.rho - float(ref.line.normal @ line.midpoint)) < \
                    0.3 + 3.0 * math.sqrt(self.P[0, 0] + self.P[1, 1]) \
                    and overlaps(ref.line, line, margin):
                self.count('lines_near_reference')
                return
        if math.sqrt(self.P[2, 2]) > ip.reference_max_heading_sigma \
                or math.sqrt(max(self.P[0, 0], self.P[1, 1])) > ip.reference_max_position_sigma:
            self.count('references_not_made_uncertain')
            return
        self.tentative.append(self._new_reference(line, t, self._reference_cov(line)))

    def _add_reference(self, ref: Reference) -> None:
        self._log_reference(ref)
        self.references.append(ref)
        cap = self.params.improved.max_references
        if len(self.references) > cap:
            self.references.sort(key=lambda r: r.t_last)
            del self.references[:len(self.references) - cap]
            self.count('references_dropped_full')

    def _age_tentative(self, t: float) -> None:
        limit = t - self.params.improved.tentative_timeout
        keep = [r for r in self.tentative if r.t_last >= limit]
        if len(keep) != len(self.tentative):
            self.count('tentative_expired', len(self.tentative) - len(keep))
            self.tentative = keep

    # -- filter update -------------------------------------------------------------------
    def _filter_update(self, matches: list, t: float) -> list[Correction]:
        """Correct the filter with one scan's matches when they agree and are supported."""
        keep = self._consistent(matches)
        if not keep or not self._supported(keep, t):
            return []
        if t - self._last_update < self.params.improved.update_interval:
            return []
        self._last_update = t
        corr = self._correct(keep, t)
        self._record(corr)
        return [corr]

    def _consistent(self, matches: list) -> list:
        """Return the matches that agree on the heading error; mark (or retire) the others."""
        ip = self.params.improved
        errs = [float(m[2][0]) for m in matches]
        sig = [math.sqrt(m[4][0][0]) for m in matches]
        med = statistics.median(errs)
        med_sig = statistics.median(sig)
        keep = []
        for m, e, sg in zip(matches, errs, sig):
            if abs(e - med) > ip.consistency_sigma * math.hypot(sg, med_sig) \
                    and len(matches) > 2:
                m[1].conflicts += 1
                self.count('lines_inconsistent')
                if m[1].conflicts >= ip.retire_conflicts and 3 * m[1].conflicts > m[1].matches:
                    self.references.remove(m[1])
                    self.count('references_retired')
                continue
            keep.append(m)
        return keep

    def _supported(self, keep: list, t: float) -> bool:
        """Return True when distinct references now, or agreeing scans over time, support."""
        ip = self.params.improved
        for line, ref, y, H, R in keep:
            self._support.append((t, ref.id, y[0] + self._cum_correction,
                                  math.sqrt(R[0][0])))
        while self._support and self._support[0][0] < t - ip.support_window:
            self._support.popleft()
        ids_now = {m[1].id for m in keep}
        support = len(ids_now)
        if support < ip.min_support:
            a_now = float(np.mean([m[2][0] for m in keep])) + self._cum_correction
            s_now = float(np.mean([math.sqrt(m[4][0][0]) for m in keep]))
            agreeing = {(tt, rid) for tt, rid, a, sg in self._support
                        if tt < t and abs(a - a_now) <= ip.consistency_sigma
                        * math.hypot(sg, s_now)}
            support += len({tt for tt, _ in agreeing})
        if support < ip.min_support:
            self.count('matches_unsupported')
            return False
        return True

    def _correct(self, keep: list, t: float) -> Correction:
        """Update the filter with the kept matches (sequentially, Joseph form)."""
        ip = self.params.improved
        before = self.x.copy()
        min_ref_var = math.inf
        if ip.refine_references:
            for line, ref, y, H, R in keep:
                self._refine(ref, line)
        for line, ref, y, H, R in keep:
            line = self._replace(line, before)  # re-place with the pose updated so far
            y, H, s = line_model(ref.line, line, self.x[:2])
            A = np.array([[1.0, 0.0], [s, 1.0]])
            R = A @ ref.cov @ A.T + self._line_noise(line)
            if not ip.correct_position:
                H, y, R = H[:1], y[:1], R[:1, :1]
            S = H @ self.P @ H.T + R
            K = self.P @ H.T @ np.linalg.inv(S)
            self.x = self.x + K @ y
            I_KH = _I5 - K @ H
            self.P = I_KH @ self.P @ I_KH.T + K @ R @ K.T  # Joseph form
            ref.matches += 1
            self._extend(ref, line)
            min_ref_var = min(min_ref_var, ref.cov[0, 0])
        # a reference's own angle error is common to every later match with it:
        # the heading can never become more certain than the best reference used.
        if ip.reference_floor:
            self.P[2, 2] = max(self.P[2, 2], min_ref_var)
        delta = float(self.x[2] - before[2])
        self._cum_correction += delta
        return Correction(t, delta, float(np.mean([m[2][0] for m in keep])),
                          tuple(m[1].id for m in keep), tuple(m[0] for m in keep),
                          tuple(m[1].line for m in keep), self.pose, 'filter',
                          float(np.hypot(*(self.x[:2] - before[:2]))),
                          np.array([before[0], before[1], wrap_angle(before[2])]))
