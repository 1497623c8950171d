# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Input handling shared by both variants of ``gyro_line_calibration`` (seed 000).

Heading is the integrated gyro z rate (IMU rotated into ``base_link`` by its
mounting), position the odometry translation rotated by that heading. Scan
hits (:func:`robot_calib.core.frames.scan_points`: mounted, de-skewed by the
motion during the scan) go into an :class:`~robot_calib.core.lines.ObstacleGrid`
with the current pose and lines are fitted (condition 1,
:mod:`robot_calib.core.lines`); what is done with the lines is the variant's
(:mod:`.seed`, :mod:`.improved`). The state ``[x, y, heading, gyro bias, gyro
scale]`` and its covariance are propagated here for both variants.

Untrusted data gives no correction and no reference: scans while the robot
is carried (odometry stopped while the gyro turns, or scans that change
while odometry and gyro say stopped), after an odometry reset, after a time
jump, and while turning faster than ``max_turn_rate``. Everything rejected is
counted in :attr:`GyroLineResult.counts`.

The seed phase (work or edge following) is input handling too: it comes from
``seed.phase``, ``seed.phase_switch_time`` or a :class:`~robot_calib.core.types.BoolSample`
(``gyro_line/edge_following``); only the seed variant acts on it.
"""

from __future__ import annotations

import abc
from collections import deque
import math
from typing import Any, Optional, Union

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.frames import constant_motion, mirrored, scan_points, StaticTree
from robot_calib.core.geometry import rot2, wrap_angle
from robot_calib.core.lines import extract_lines, Line, ObstacleGrid
from robot_calib.core.notes import InputNotes
from robot_calib.core.odometry_twist import TwistOnly
from robot_calib.core.series import Thinned
from robot_calib.core.zero_gyro import ZeroGyro
from robot_calib.methods.gyro_line_calibration.common import (
    Correction, frozen_counts, GyroLineResult, PoseEstimate, Reference, within_hold)
from robot_calib.methods.gyro_line_calibration.mounting import SensorMountings
from robot_calib.methods.gyro_line_calibration.params import GyroLineParams

_DEG = math.pi / 180.0
KEPT_CORRECTIONS = 2000
"""The latest corrections kept whole (lines, references, poses: a few kB each) for audits.

Every correction counts in :attr:`GyroLineBase.correction_total`, ``correction_abs_max``
and ``correction_trace``, which do not grow with the run."""


class GyroLineBase(SensorMountings, abc.ABC):
    """
    Streaming gyro-line heading calibration; feed samples in time order.

    A variant implements ``_step(lines, t)``: what the lines fitted in one
    trusted scan at time ``t`` (s) do; it returns the corrections made.

    :param params: the parameters (defaults when None).
    """

    def __init__(self, params: Optional[GyroLineParams] = None):
        """Create the estimator; the pose starts at the first odometry pose."""
        self.params = params if params is not None else GyroLineParams()
        self._param_mountings()
        self._mountings = StaticTree()
        self._imu_frame: Optional[str] = None
        self._laser_frame: Optional[str] = None
        self.input_notes = InputNotes()
        """Standing warnings about the inputs (a frame not in the tree, twist-only odometry)."""
        self.reset()

    def reset(self) -> None:
        """Forget the state (pose, references, counters); keep the parameters and mountings."""
        p = self.params
        self.grid = ObstacleGrid(p.lines)
        self.counts: dict[str, int] = {}
        self.corrections: deque = deque(maxlen=KEPT_CORRECTIONS)
        self.correction_total = 0.0
        """Sum of every heading correction so far (rad)."""
        self.correction_abs_max = 0.0
        """Largest |heading correction| so far (rad)."""
        self.correction_trace = Thinned()
        """(t s, cumulative heading correction rad) over the whole run, thinned to bound it."""
        self.references: list[Reference] = []
        self.reference_log: dict[int, Reference] = {}
        self._next_id = 0
        self.x = np.zeros(5)  # x, y, heading, gyro bias, gyro scale error
        ip = p.improved
        self.P = np.diag([0.0, 0.0, ip.heading_sigma0 ** 2, ip.bias_sigma0 ** 2,
                          ip.scale_sigma0 ** 2])
        self.initialized = False
        self.edge_following = p.seed.phase == 'edge_following'
        self._switched = False
        self._t0 = None
        self._imu_t = None
        self._rot_seen, self._rot_identity = None, False
        self._last_imu_rate = 0.0
        self._odom_prev = None
        self._odom_t = None
        self._odom_speed = 0.0
        self._odom_v = 0.0
        self._odom_rate = 0.0
        self.zero_gyro = ZeroGyro()
        """Whether the IMU gives no yaw rate (exactly 0 while the odometry turns)."""
        self.twist_only = TwistOnly()
        """Tells an odometry that fills only its twist, and integrates its poses then."""
        self.input_notes.say('odom', '')
        self._acc_dt = 0.0
        self._acc_wdt = 0.0
        self._acc_q = 0.0
        self.lock_lost_episodes = 0
        """Times the walls began to contradict the heading (improved variant)."""
        self.lock_lost_last: Optional[float] = None
        """Time (s) of the latest scan whose lines contradicted the heading."""
        self._flushed_dt = 0.0  # s and rad of gyro flushed since the last odometry sample
        self._flushed_wdt = 0.0
        self._untrusted_until = -math.inf
        self._stopped_turning_since = None
        self._prev_ranges = None
        self._beam_count = None
        self._new_count = (None, 0)
        self._scan_rejected = None
        self._snapshot = ((None, None), ())

    # -- the Estimator protocol ----------------------------------------------------------
    def update(self, sample: Any) -> Union[None, PoseEstimate, tuple[Correction, ...]]:
        """
        Process one core sample (IMU, odometry, scan, phase Bool, static transform).

        Returns the pose estimate after an odometry sample, the heading corrections
        a scan made (None when it made none), and None for the other samples.
        """
        if isinstance(sample, T.ImuSample):
            if self._imu_frame is None:
                self._imu_frame = sample.frame_id
                self._apply_mountings()
            self._update_imu(sample)
        elif isinstance(sample, T.OdomSample):
            if not self.twist_only.settled or self.twist_only.twist_only:
                sample = self._twist_only(sample)
            self._update_odom(sample)
            return PoseEstimate(self.initialized, self.pose, np.array(self.P[:3, :3]),
                                self.rate, self.counts.get('odom_resets', 0))
        elif isinstance(sample, T.ScanSample):
            if self._laser_frame is None:
                self._laser_frame = sample.frame_id
                self._apply_mountings()
            out = self._update_scan(mirrored(sample) if self._laser_upside_down else sample)
            return tuple(out) if out else None
        elif isinstance(sample, T.StaticTransform):
            self.set_mounting(sample)
        elif isinstance(sample, T.BoolSample):
            self.set_phase(sample.value, sample.t)
        return None

    def _twist_only(self, sample: T.OdomSample) -> T.OdomSample:
        """Return an odometry sample with the poses its twist integrates to when twist-only."""
        was = self.twist_only.twist_only
        sample = self.twist_only.sample(sample)
        if self.twist_only.twist_only:
            self.count('odometry_twist_only')
            if not was:
                self.input_notes.say('odom', self.twist_only.note())
        return sample

    def result(self) -> GyroLineResult:
        """Return the estimates so far (does not change the state)."""
        pose = self.pose
        P = self._flushed_covariance()
        return GyroLineResult(
            initialized=self.initialized, pose=pose, heading=float(pose[2]),
            pose_cov=np.array(self.P[:3, :3]), heading_sigma=math.sqrt(max(P[2, 2], 0.0)),
            gyro_bias=float(self.x[3]), rate=self.rate, edge_following=self.edge_following,
            untrusted_until=self._untrusted_until, corrections=self._corrections_snapshot(),
            references=tuple(r.line for r in self.references),
            tentative_references=self._tentative_count(), counts=frozen_counts(self.counts),
            scan_rejected=self._scan_rejected, lock_lost_episodes=self.lock_lost_episodes,
            lock_lost_last=self.lock_lost_last)

    # -- state shortcuts -----------------------------------------------------------------
    @property
    def heading(self) -> float:
        """Return the corrected heading in rad, (-pi, pi]."""
        return wrap_angle(self.x[2])

    @property
    def pose(self) -> np.ndarray:
        """Return the estimated pose [x, y, yaw] (m, m, rad)."""
        return np.array([self.x[0], self.x[1], wrap_angle(self.x[2])])

    @property
    def rate(self) -> float:
        """Return the corrected yaw speed (rad/s): gyro minus bias, or the odometry one."""
        if self._imu_t is not None and self._use_gyro(self._imu_t):
            return float(self._last_imu_rate * (1.0 - self.x[4]) - self.x[3])
        return float(self._odom_rate)

    def trusted(self, t: float) -> bool:
        """Return True when lines may be used at time ``t`` (s)."""
        return self.initialized and t >= self._untrusted_until

    def walls_contradict(self, t: float) -> bool:
        """Return True when the walls contradicted the heading within ``lock_hold`` of ``t``."""
        return within_hold(self.lock_lost_last, t, self.params.improved.lock_hold)

    @property
    def scan_rejected(self) -> Optional[str]:
        """Return why the last scan was rejected (None: accepted), without a whole result."""
        return self._scan_rejected

    def _corrections_snapshot(self) -> tuple:
        """Return the corrections as a tuple, rebuilt only when one was added."""
        last = self.corrections[-1] if self.corrections else None
        (deq, seen), snap = self._snapshot
        if deq is not self.corrections or seen is not last:
            snap = tuple(self.corrections)
            self._snapshot = ((self.corrections, last), snap)
        return snap

    def _tentative_count(self) -> int:
        return 0

    # -- bookkeeping ---------------------------------------------------------------------
    def _record(self, corr: Correction) -> None:
        """Keep one correction made: the latest few whole, every one in the totals and trace."""
        self.corrections.append(corr)
        self.count('corrections')
        self.correction_total += corr.delta
        self.correction_abs_max = max(self.correction_abs_max, abs(corr.delta))
        self.correction_trace.append((corr.t, self.correction_total))

    def count(self, key: str, n: int = 1) -> None:
        """Increment counter ``key``."""
        self.counts[key] = self.counts.get(key, 0) + n

    def distrust(self, t: float, reason: str) -> None:
        """Mark data untrusted from ``t`` (s) for ``untrusted_hold`` seconds; clear the grid."""
        if t >= self._untrusted_until:
            self.count('untrusted_' + reason)
        self._untrusted_until = max(self._untrusted_until, t + self.params.untrusted_hold)
        self.grid.clear()

    def _new_reference(self, line: Line, t: float, cov: np.ndarray) -> Reference:
        ref = Reference(self._next_id, line, t, cov, self.pose, t_last=t, origin=line)
        self._next_id += 1
        return ref

    def _log_reference(self, ref: Reference) -> None:
        """Keep every reference ever used (bounded) so corrections can be audited."""
        self.reference_log[ref.id] = ref
        if len(self.reference_log) > 10000:
            del self.reference_log[next(iter(self.reference_log))]

    # -- phase ---------------------------------------------------------------------------
    def set_phase(self, edge_following: bool, t: Optional[float] = None) -> None:
        """Select the seed phase: True for edge following, False for work (time ``t`` s)."""
        if edge_following and not self.edge_following:
            self._phase_started()
            self.count('phase_edge_following')
        self.edge_following = bool(edge_following)

    def _phase_started(self) -> None:
        """Edge following starts now (the seed variant looks for a first line again)."""

    def _check_phase_time(self, t: float) -> None:
        sw = self.params.seed.phase_switch_time
        if sw > 0.0 and not self.edge_following and self._t0 is not None \
                and t - self._t0 >= sw and not self._switched:
            self._switched = True
            self.set_phase(True, t)

    # -- prediction ----------------------------------------------------------------------
    def _use_gyro(self, t: float) -> bool:
        src = self.params.heading_source
        if src == 'imu':
            return True
        if src == 'odom':
            return False
        return self._imu_t is not None and t - self._imu_t <= 1.0

    def _start(self, t: float) -> None:
        if self._t0 is None:
            self._t0 = t

    def _update_imu(self, s: T.ImuSample) -> None:
        """Integrate one IMU sample (gyro rad/s in the IMU frame)."""
        t = s.t
        self._start(t)
        rate = self._gyro_z(s.gyro)
        if rate == 0.0:
            was = self.zero_gyro.missing
            if self.zero_gyro.zero(t, self._odom_rate):
                if not was:  # a driver that fills no angular velocity: the odometry's heading,
                    self._imu_t = None  # with the turn the zeros hid
                    self._forget_gyro(self.zero_gyro.hidden_turn, self.zero_gyro.since)
                return
        else:
            self.zero_gyro.reading()
        prev = self._imu_t
        prev_rate = self._last_imu_rate
        self._imu_t = t
        self._last_imu_rate = rate
        if self.params.seed.phase_switch_time > 0.0:
            self._check_phase_time(t)
        if prev is None or not self._use_gyro(t):
            return
        dt = t - prev
        if dt <= 0.0:
            return
        p = self.params
        if dt > p.max_dt:
            self.count('imu_time_jumps')
            self.P[2, 2] += (p.max_turn_rate * min(dt, 10.0)) ** 2 * 0.01
            self.distrust(t, 'time_jump')
            return
        self._integrate_rate(0.5 * (rate + prev_rate), dt,  # trapezoidal rule
                             p.improved.gyro_noise)
        self._carried_check(t)

    def _forget_gyro(self, hidden_turn: float, since: Optional[float]) -> None:
        """
        Undo what an all-zero gyro did from ``since`` (s) on.

        Add the turn (rad) it hid, reset the gyro terms it taught the filter and
        drop the references made in the heading it left wrong.
        """
        ip = self.params.improved
        self._flush_gyro()
        if since is not None:
            self.references = [r for r in self.references if r.t_created < since]
        self.x[2] = wrap_angle(self.x[2] + hidden_turn)
        self.x[3] = self.x[4] = 0.0
        for i, var in ((3, ip.bias_sigma0 ** 2), (4, ip.scale_sigma0 ** 2)):
            self.P[i, :] = 0.0
            self.P[:, i] = 0.0
            self.P[i, i] = var
        self.count('gyro_missing_periods')

    def _gyro_z(self, gyro: np.ndarray) -> float:
        """Return the yaw rate (rad/s) in base_link of a gyro vector (rad/s, IMU frame)."""
        rot = self._imu_rot
        if rot is not self._rot_seen:  # a new mounting: is it exactly the identity?
            self._rot_seen = rot
            self._rot_identity = bool(np.array_equal(rot, np.eye(3)))
        if self._rot_identity:
            gx, gy, gz = gyro[0], gyro[1], gyro[2]
            # the identity's row 2 gives gz exactly, in any summation order, unless an
            # inf or nan spoils 0 * g or gz is a zero whose sign the sum may change
            if gz != 0.0 and math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz):
                return float(gz)
        return float((rot @ np.asarray(gyro, dtype=float))[2])

    def _integrate_rate(self, rate: float, dt: float, noise: float) -> None:
        # heading = integral of (1 - s) * rate - b; noise: angle random walk (rad/sqrt(s))
        x = self.x
        x[2] += (rate * (1.0 - x[4]) - x[3]) * dt
        self._acc_dt += dt
        self._acc_wdt += rate * dt
        self._acc_q += noise ** 2 * dt

    def _propagate_gyro(self, P: list) -> None:
        """Propagate covariance ``P`` (rows as lists, in place) over the unflushed gyro samples."""
        a, w = self._acc_dt, self._acc_wdt
        # P = F P F^T with F = I - a e2 e3^T - w e2 e4^T (rows, then columns), element by element
        r2, r3, r4 = P[2], P[3], P[4]
        for j in range(5):
            r2[j] -= a * r3[j] + w * r4[j]
        for row in P:
            row[2] -= a * row[3] + w * row[4]
        r2[2] += self._acc_q
        r3[3] += self.params.improved.bias_walk ** 2 * self._acc_dt

    def _flush_gyro(self, P: Optional[list] = None) -> None:
        """
        Propagate the covariance over the gyro samples integrated since the last flush.

        With ``P`` (``self.P`` as rows of lists) that is propagated, and the
        caller writes it back; else ``self.P`` is.
        """
        if self._acc_dt <= 0.0:
            return
        self._flushed_dt += self._acc_dt
        self._flushed_wdt += self._acc_wdt
        if P is None:
            rows = self.P.tolist()
            self._propagate_gyro(rows)
            self.P[:] = rows
        else:
            self._propagate_gyro(P)
        self._acc_dt = 0.0
        self._acc_wdt = 0.0
        self._acc_q = 0.0

    def _flushed_covariance(self) -> np.ndarray:
        """Return a copy of the covariance with the pending gyro samples propagated."""
        if self._acc_dt <= 0.0:
            return self.P.copy()
        rows = self.P.tolist()
        self._propagate_gyro(rows)
        return np.array(rows)

    def _update_odom(self, s: T.OdomSample) -> None:
        """Apply one odometry sample (pose in the odometry frame, m and rad)."""
        self._start(s.t)
        self._check_phase_time(s.t)
        cur = (float(s.x), float(s.y), float(s.yaw))
        if not self.initialized:
            self.x[:3] = cur
            self.initialized = True
            self._odom_prev, self._odom_t = cur, s.t
            return
        dt = s.t - self._odom_t
        if dt <= 0.0:
            return
        px, py, pth = self._odom_prev
        c0, s0 = math.cos(pth), math.sin(pth)
        ex, ey = cur[0] - px, cur[1] - py
        d = (c0 * ex + s0 * ey, -s0 * ex + c0 * ey, wrap_angle(cur[2] - pth))  # prev^-1 (+) cur
        dist = math.hypot(d[0], d[1])
        self._odom_prev, self._odom_t = cur, s.t
        if dt > self.params.max_dt:
            self.count('odom_time_jumps')
            self.distrust(s.t, 'time_jump')
            self._inflate_position(dist + 0.1)
            return
        if dist > self.params.max_speed * dt + 0.05 or abs(d[2]) > 6.0 * dt + 0.5:
            self.count('odom_resets')
            self.distrust(s.t, 'odom_reset')
            return
        self._odom_speed = dist / dt
        self._odom_v = d[0] / dt
        self._odom_rate = d[2] / dt
        if not self._use_gyro(s.t):
            self._integrate_rate(d[2] / dt, dt, self.params.improved.odom_yaw_noise)
        rows = self.P.tolist()  # 5 x 5: scalar arithmetic is cheaper than numpy's, and the same
        self._flush_gyro(rows)
        self._move(d, dist, rows)
        self.P[:] = rows
        self._carried_check(s.t)

    def _move(self, d: tuple, dist: float, P: list) -> None:
        """
        Move the pose by an odometry step ``d`` (dx, dy m in the robot frame) of ``dist`` m.

        ``P`` is the covariance as rows of lists, propagated in place.
        """
        th = self.x[2]
        c, sn = math.cos(th), math.sin(th)
        dx = c * d[0] - sn * d[1]
        dy = sn * d[0] + c * d[1]
        self.x[0] += dx
        self.x[1] += dy
        # P = F P F^T with F = I - dy e0 e2^T + dx e1 e2^T (rows, then columns), element by
        # element; p + (-dy) q is p - dy q exactly (IEEE)
        f0, f1 = -dy, dx
        r0, r1, r2 = P[0], P[1], P[2]
        for j in range(5):
            r0[j] += f0 * r2[j]
            r1[j] += f1 * r2[j]
        for row in P:
            p2 = row[2]
            row[0] += p2 * f0
            row[1] += p2 * f1
        q = self.params.improved.odom_noise ** 2 * dist
        r0[0] += q
        r1[1] += q

    def _inflate_position(self, sigma: float) -> None:
        self.P[0, 0] += sigma ** 2
        self.P[1, 1] += sigma ** 2

    def _carried_check(self, t: float) -> None:
        """Odometry says stopped while the gyro turns: the robot is being carried."""
        if self._odom_t is None or self._imu_t is None or not self._use_gyro(t):
            return
        stopped = self._odom_speed < 0.01 and abs(self._odom_rate) < 0.05
        if stopped and abs(self._last_imu_rate) > self.params.carried_rate:
            if self._stopped_turning_since is None:
                self._stopped_turning_since = t
            elif t - self._stopped_turning_since > 0.2:
                if t >= self._untrusted_until:
                    self._inflate_position(0.5)
                self.distrust(t, 'carried')
        else:
            self._stopped_turning_since = None

    # -- scans ---------------------------------------------------------------------------
    def _scan_points(self, s: T.ScanSample) -> tuple[Optional[np.ndarray], Optional[str]]:
        """Return the valid hits (N, 2) in base_link (m) and None, or None and a reject reason."""
        size = np.asarray(s.ranges).size
        if size == 0:
            return None, 'empty_scan'
        if self._beam_count is None:
            self._beam_count = size
        elif size != self._beam_count:
            n, k = self._new_count
            self._new_count = (size, k + 1 if n == size else 1)
            if self._new_count[1] < 10:
                self._prev_ranges = None
                return None, 'beam_count_changed'
            self._beam_count = size  # a reconfigured driver: accept after 10 scans
            self._prev_ranges = None
        # de-skew a rotating lidar: the robot turns and moves at constant speed over a scan
        rate = self._last_imu_rate - self.x[3] if self._use_gyro(s.t) else self._odom_rate
        pts, idx = scan_points(s, self.laser_pose, self.params.lines.max_range,
                               constant_motion(self._odom_v, rate))
        if idx.size < self.params.min_valid_beams:
            return None, 'too_few_valid_beams'
        return pts, None

    def _scan_changed_while_stopped(self, s: T.ScanSample, t: float) -> bool:
        r = np.asarray(s.ranges, dtype=float)
        prev = self._prev_ranges
        self._prev_ranges = r
        if prev is None or prev.size != r.size:
            return False
        stopped = self._odom_speed < 0.01 and abs(self._odom_rate) < 0.05 \
            and abs(self._last_imu_rate) < 0.05
        if not stopped or self._odom_t is None or t - self._odom_t > 0.5:
            return False
        with np.errstate(invalid='ignore'):
            both = np.isfinite(r) & np.isfinite(prev)
            if both.sum() < self.params.min_valid_beams:
                return False
            changed = np.abs(r[both] - prev[both]) > 0.05
        return float(changed.mean()) > self.params.carried_scan_change

    def _update_scan(self, s: T.ScanSample) -> list[Correction]:
        """Process one scan; return the corrections made (the reject reason is kept)."""
        self._start(s.t)
        self._check_phase_time(s.t)
        self._scan_rejected = None
        pts, reason = self._scan_points(s)
        if pts is None:
            self.count('scans_rejected_' + reason)
            self._scan_rejected = reason
            return []
        if not self.initialized:
            self.count('scans_before_odometry')
            self._scan_rejected = 'no_odometry_yet'
            return []
        if self._scan_changed_while_stopped(s, s.t):
            self._inflate_position(0.5)
            self.distrust(s.t, 'carried')
        if not self.trusted(s.t):
            self.count('scans_untrusted')
            return []
        rate = self._last_imu_rate if self._use_gyro(s.t) else self._odom_rate
        if abs(rate) > self.params.max_turn_rate:
            self.count('scans_turning_fast')
            return []
        self._flush_gyro()
        world = pts @ rot2(self.x[2]).T + self.x[:2]
        cells = self.grid.add_points(world, s.t)
        lines = extract_lines(cells, self.params.lines, s.t)
        self.count('lines', len(lines))
        if not lines:
            return []
        out = self._step(lines, s.t)
        if any(c.kind != 'filter' or abs(c.delta) > 0.2 * _DEG or c.position_delta > 0.03
               for c in out):
            self.grid.clear()  # its hits were placed with the old pose
        return out

    @abc.abstractmethod
    def _step(self, lines: list[Line], t: float) -> list[Correction]:
        """Use the lines of one trusted scan at ``t`` (s); return the corrections made."""
