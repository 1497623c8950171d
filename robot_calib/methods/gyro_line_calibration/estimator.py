# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Gyro heading calibration from wall lines (seed 000), seed-faithful and automatic modes.

Heading is the integrated gyro z rate (IMU rotated into ``base_link`` by its
mounting), position the odometry translation rotated by that heading. Scan
hits go into an :class:`~robot_calib.core.lines.ObstacleGrid` with the
current pose and lines are fitted (condition 1, :mod:`robot_calib.core.lines`).

Seed mode (``mode='seed'``, seed 000 S1-S3 as written):

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

Automatic mode (``mode='improved'``, for robots that never announce a phase):
an extended Kalman filter over ``[x, y, heading, gyro bias, gyro scale]``
(odometry and gyro predict; a matched wall line updates angle and distance).
References accumulate all the time: a line that matches nothing becomes a
tentative reference, confirmed after it was seen again in several scans
(people and other moving things are never confirmed). Each reference keeps
the covariance its angle and distance had when it was made. Guards against
matching the wrong wall: the reference must overlap the new line along its
length (within the position uncertainty); the innovation (angle AND
perpendicular distance) must pass a chi-square gate built from the current
pose covariance; a line that could belong to two references at different
distances (parallel walls, shelves) is ambiguous and skipped; lines of one
scan must agree on the heading correction (the outliers are dropped and
their references marked; a reference that keeps disagreeing, such as moved
furniture, is retired); a correction needs support from two distinct
references, or from the same one in two scans that agree over time. A
90-degree symmetric room cannot alias because the heading uncertainty keeps
the angle gate far below 90 degrees.

Untrusted data gives no correction and no reference: scans while the robot
is carried (odometry stopped while the gyro turns, or scans that change
while odometry and gyro say stopped), after an odometry reset, after a time
jump, and while turning faster than ``max_turn_rate``. Everything rejected is
counted in :attr:`GyroLineCalibrator.counts`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
import math
import statistics
from typing import Iterable, Optional

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix, rot2
from robot_calib.core.geometry import wrap_half_pi
from robot_calib.core.lines import extract_lines, Line, line_from_endpoints, LineParams
from robot_calib.core.lines import ObstacleGrid
from robot_calib.core.params import param

_DEG = math.pi / 180.0
_HALF_PI = math.pi / 2


def _wrap(a: float) -> float:
    """Wrap a heading (rad) to (-pi, pi]."""
    w = math.fmod(a + math.pi, 2.0 * math.pi)
    if w <= 0.0:
        w += 2.0 * math.pi
    return w - math.pi


def _wrap_half(a):
    """Wrap line angles (rad, float or array) to [-pi/2, pi/2) (fast, no checks)."""
    return (a + _HALF_PI) % math.pi - _HALF_PI


@dataclass
class MatchParams:
    """Condition 2 (seed 000, S31-S33) and the correction threshold."""

    length_tolerance: float = param(1.0, 'm', 'Condition 2 (a): largest length difference.',
                                    minimum=0.0)
    endpoint_tolerance: float = param(0.5, 'm', 'Condition 2 (b): largest start-point and '
                                      'end-point distances.', minimum=0.0)
    angle_tolerance: float = param(8.0 * _DEG, 'rad', 'Condition 2 (c): largest angle '
                                   'difference (modulo pi).', minimum=0.0, maximum=math.pi / 2)
    angle_threshold: float = param(0.1 * _DEG, 'rad', 'Correct only when the angle error is '
                                   'above this.', minimum=0.0)


@dataclass
class SeedParams:
    """The seed-faithful mode: phases, weights and re-calibration."""

    phase: str = param('work', '', 'Initial phase: work (store references) or edge_following '
                       '(calibrate); the gyro_line/edge_following topic overrides it.',
                       choices=('work', 'edge_following'))
    phase_switch_time: float = param(0.0, 's', 'If > 0: switch to edge following this long '
                                     'after the first sample (0: never by time).', minimum=0.0)
    w1: float = param(0.8, '', 'Weight of the reference angle (w2 = 1 - w1, w1 > w2).',
                      minimum=0.5, maximum=1.0)
    recalibration_time: float = param(20.0, 's', 'Re-calibrate with a second line after this '
                                      'time while still edge-following.', minimum=0.0)
    recalibration_length_ratio: float = param(1.5, '', "N: a line N times the first line's "
                                              'length is used as the second line (N > 1).',
                                              minimum=1.0)
    max_references: int = param(2000, '', 'Most reference lines stored.', minimum=1)


@dataclass
class ImprovedParams:
    """The automatic mode: filter noise, reference life cycle and wrong-wall guards."""

    heading_sigma0: float = param(0.1 * _DEG, 'rad', 'Initial heading uncertainty (1 sigma).',
                                  minimum=0.0)
    gyro_noise: float = param(0.001, 'rad/sqrt(s)', 'Gyro angle random walk (with margin: a '
                              'consumer MEMS gyro has 1e-4 to 3e-4).', minimum=0.0)
    odom_yaw_noise: float = param(0.005, 'rad/sqrt(s)', 'Random walk of the odometry yaw when it '
                                  'stands in for the gyro (wheel slip).', minimum=0.0)
    bias_sigma0: float = param(60.0 * _DEG / 3600.0, 'rad/s', 'Initial gyro bias uncertainty.',
                               minimum=0.0)
    bias_walk: float = param(2.0e-5, 'rad/s/sqrt(s)', 'Gyro bias random walk.', minimum=0.0)
    scale_sigma0: float = param(0.01, '', 'Initial gyro scale-error uncertainty.', minimum=0.0)
    odom_noise: float = param(0.02, 'm/sqrt(m)', 'Odometry position noise per sqrt(metre).',
                              minimum=0.0)
    line_sigma: float = param(0.03, 'm', 'Extra 1-sigma distance noise of a fitted line.',
                              minimum=0.0)
    line_angle_sigma: float = param(0.3 * _DEG, 'rad', 'Extra 1-sigma angle noise of a line.',
                                    minimum=0.0)
    gate_chi2: float = param(9.21, '', 'Chi-square gate (2 dof) on the innovation.',
                             minimum=0.0)
    overlap_margin: float = param(0.3, 'm', 'A reference must overlap the new line within '
                                  'this plus 3 sigma of position.', minimum=0.0)
    ambiguity_distance: float = param(0.1, 'm', 'Two gated references farther apart than this '
                                      'make a line ambiguous.', minimum=0.0)
    consistency_sigma: float = param(3.0, '', 'Lines of one scan must agree within this many '
                                     'sigma.', minimum=0.0)
    min_support: int = param(2, '', 'Distinct references (or agreeing scans) a correction '
                             'needs.', minimum=1)
    support_window: float = param(3.0, 's', 'Time over which supporting matches count.',
                                  minimum=0.0)
    confirm_scans: int = param(3, '', 'Scans a tentative reference must be seen in.', minimum=1)
    confirm_time: float = param(1.0, 's', 'Time a tentative reference must span.', minimum=0.0)
    tentative_timeout: float = param(5.0, 's', 'A tentative reference unseen this long is '
                                     'dropped.', minimum=0.0)
    reference_max_heading_sigma: float = param(2.0 * _DEG, 'rad', 'No new reference while the '
                                               'heading is more uncertain.', minimum=0.0)
    reference_max_position_sigma: float = param(0.5, 'm', 'No new reference while the '
                                                'position is more uncertain.', minimum=0.0)
    retire_conflicts: int = param(3, '', 'A reference that disagreed this often (and with more '
                                  'than a third of its matches) is retired.', minimum=1)
    max_references: int = param(400, '', 'Most references kept (least recently seen dropped).',
                                minimum=1)
    update_interval: float = param(0.5, 's', 'Shortest time between two filter updates.',
                                   minimum=0.0)
    refine_references: bool = param(True, '', 'Refine a reference with every supported match '
                                    '(Kalman-weighted angle and distance).')
    reference_floor: bool = param(False, '', 'Never let the heading variance fall below the '
                                  'best reference used (its error is common to every match).')
    correct_position: bool = param(True, '', 'Also correct the position across matched walls.')


@dataclass
class GyroLineParams:
    """Parameters of ``gyro_line_calibration`` (seed 000)."""

    mode: str = param('improved', '', 'improved (automatic) or seed (explicit work then '
                      'edge-following phases).', choices=('improved', 'seed'))
    heading_source: str = param('auto', '', 'imu (gyro z), odom (odometry yaw stands in for '
                                'the gyro) or auto (gyro when IMU data arrive).',
                                choices=('auto', 'imu', 'odom'))
    imu_rpy: list = param([0.0, 0.0, 0.0], 'rad', 'IMU mounting roll, pitch, yaw in base_link '
                          '(used until /tf_static gives it).', length=3)
    laser_pose: list = param([0.0, 0.0, 0.0], 'm, m, rad', 'Laser x, y, yaw in base_link '
                             '(used until /tf_static gives it).', length=3)
    base_frame: str = param('base_link', '', 'Robot body frame in /tf_static.')
    max_dt: float = param(0.5, 's', 'A larger gap between two IMU or odometry samples is a '
                          'time jump (not integrated; no correction until trusted again).',
                          minimum=0.0)
    max_speed: float = param(2.0, 'm/s', 'Faster odometry steps are resets.', minimum=0.0)
    max_turn_rate: float = param(1.5, 'rad/s', 'No line is used while turning faster.',
                                 minimum=0.0)
    carried_rate: float = param(0.3, 'rad/s', 'Gyro rate while the odometry is stopped that '
                                'means the robot is carried.', minimum=0.0)
    carried_scan_change: float = param(0.3, '', 'Fraction of beams changing by > 5 cm while '
                                       'stopped that means the robot is carried.',
                                       minimum=0.0, maximum=1.0)
    untrusted_hold: float = param(2.0, 's', 'Time after the last untrusted event before lines '
                                  'are used again.', minimum=0.0)
    min_valid_beams: int = param(20, '', 'Fewer valid beams reject the scan.', minimum=1)
    diagnostics_period: float = param(1.0, 's', 'Period of /diagnostics (sensor time); also '
                                      'published at every correction.', minimum=0.0)
    lines: LineParams = field(default_factory=LineParams)
    match: MatchParams = field(default_factory=MatchParams)
    seed: SeedParams = field(default_factory=SeedParams)
    improved: ImprovedParams = field(default_factory=ImprovedParams)


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


@dataclass
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


def _ref_arrays(refs: list) -> tuple:
    """Return angle, direction, normal, start offset, extent and rho arrays of references."""
    ang = np.array([r.line.angle for r in refs])
    u = np.column_stack((np.cos(ang), np.sin(ang)))
    nrm = np.column_stack((-u[:, 1], u[:, 0]))
    p1 = np.array([r.line.p1 for r in refs])
    p2 = np.array([r.line.p2 for r in refs])
    o = np.einsum('ij,ij->i', u, p1)
    r2 = np.einsum('ij,ij->i', u, p2) - o
    rho = np.einsum('ij,ij->i', nrm, p1)
    return ang, u, nrm, o, r2, rho


def condition2_many(refs: np.ndarray, new: Line, match: MatchParams) -> np.ndarray:
    """
    Vectorised :func:`condition2` over references (N, 6).

    Columns: ``[p1x, p1y, p2x, p2y, angle, length]`` (m, rad).

    Returns the angle errors (rad), NaN where condition 2 fails.
    """
    if refs.shape[0] == 0:
        return np.zeros(0)
    err = _wrap_half(refs[:, 4] - new.angle)
    flip = np.abs(refs[:, 4] - new.angle) > math.pi / 2
    n1 = np.where(flip[:, None], new.p2, new.p1)
    n2 = np.where(flip[:, None], new.p1, new.p2)
    ok = np.abs(refs[:, 5] - new.length) <= match.length_tolerance  # S31
    ok &= np.hypot(*(refs[:, 0:2] - n1).T) <= match.endpoint_tolerance  # S32
    ok &= np.hypot(*(refs[:, 2:4] - n2).T) <= match.endpoint_tolerance
    ok &= np.abs(err) <= match.angle_tolerance  # S33
    return np.where(ok, err, np.nan)


def seed_calibrated_angle(ref_angle: float, line_angle: float, w1: float) -> float:
    """Return ``w1 * ref + w2 * line`` (rad), line unwrapped next to ref (seed 000, S3)."""
    line_near = ref_angle - wrap_half_pi(ref_angle - line_angle)
    return w1 * ref_angle + (1.0 - w1) * line_near  # seed 000 S3: calibrated angle


def seed_heading_correction(ref_angle: float, line_angle: float, w1: float) -> float:
    """Return the heading correction ``calibrated - line`` (rad) (seed 000, S3)."""
    line_near = ref_angle - wrap_half_pi(ref_angle - line_angle)
    return seed_calibrated_angle(ref_angle, line_angle, w1) - line_near


class GyroLineCalibrator:
    """
    Streaming gyro-line heading calibration; feed samples in time order.

    :param params: the parameters (defaults when None).
    """

    def __init__(self, params: Optional[GyroLineParams] = None):
        """Create the calibrator; the pose starts at the first odometry pose."""
        self.params = params if params is not None else GyroLineParams()
        p = self.params
        self.grid = ObstacleGrid(p.lines)
        self.counts: dict[str, int] = {}
        self.corrections: deque = deque(maxlen=20000)  # the latest, bounded for a long life
        self.references: list[Reference] = []
        self.tentative: list[Reference] = []
        self.reference_log: dict[int, Reference] = {}
        self._next_id = 0
        self.x = np.zeros(5)  # x, y, heading, gyro bias, gyro scale error
        ip = p.improved
        self.P = np.diag([0.0, 0.0, ip.heading_sigma0 ** 2, ip.bias_sigma0 ** 2,
                          ip.scale_sigma0 ** 2])
        self.initialized = False
        self._switched = False
        self._t0 = None
        self._imu_t = None
        self._last_imu_rate = 0.0
        self._odom_prev = None
        self._odom_t = None
        self._odom_speed = 0.0
        self._odom_v = 0.0
        self._odom_rate = 0.0
        self._acc_dt = 0.0
        self._acc_wdt = 0.0
        self._acc_q = 0.0
        self._untrusted_until = -math.inf
        self._stopped_turning_since = None
        self._prev_ranges = None
        self._beam_count = None
        self._new_count = (None, 0)
        r, pi_, y = (list(p.imu_rpy) + [0.0, 0.0, 0.0])[:3]
        self._imu_rot = quat_to_matrix(quat_from_rpy(r, pi_, y))
        lp = (list(p.laser_pose) + [0.0, 0.0, 0.0])[:3]
        self.laser_pose = np.array(lp, dtype=float)
        # seed phase state
        self.edge_following = p.seed.phase == 'edge_following'
        self._seed_state = 'first'
        self._seed_t_cal = -math.inf
        self._seed_first_len = math.inf
        self._seed_refs = np.zeros((p.seed.max_references, 6))
        # improved mode state
        self._support: deque = deque()
        self._last_update = -math.inf
        self._cum_correction = 0.0
        self.heading_trace: list = []

    # -- bookkeeping ---------------------------------------------------------------------
    def count(self, key: str, n: int = 1) -> None:
        """Increment counter ``key``."""
        self.counts[key] = self.counts.get(key, 0) + n

    @property
    def heading(self) -> float:
        """Return the corrected heading in rad."""
        return _wrap(self.x[2])

    @property
    def pose(self) -> np.ndarray:
        """Return the estimated pose [x, y, yaw] (m, m, rad)."""
        return np.array([self.x[0], self.x[1], _wrap(self.x[2])])

    @property
    def heading_sigma(self) -> float:
        """Return the 1-sigma heading uncertainty (rad) (improved mode's filter)."""
        self._flush_gyro()
        return math.sqrt(max(self.P[2, 2], 0.0))

    @property
    def rate(self) -> float:
        """Return the corrected yaw speed (rad/s): gyro minus bias, or the odometry one."""
        if self._imu_t is not None and self._use_gyro(self._imu_t):
            return float(self._last_imu_rate * (1.0 - self.x[4]) - self.x[3])
        return float(self._odom_rate)

    @property
    def gyro_bias(self) -> float:
        """Return the estimated gyro z bias (rad/s) (0 in seed mode)."""
        return float(self.x[3])

    def trusted(self, t: float) -> bool:
        """Return True when lines may be used at time ``t`` (s)."""
        return self.initialized and t >= self._untrusted_until

    def distrust(self, t: float, reason: str) -> None:
        """Mark data untrusted from ``t`` (s) for ``untrusted_hold`` seconds; clear the grid."""
        if t >= self._untrusted_until:
            self.count('untrusted_' + reason)
        self._untrusted_until = max(self._untrusted_until, t + self.params.untrusted_hold)
        self.grid.clear()

    # -- mounting ------------------------------------------------------------------------
    def set_transform(self, tf: T.StaticTransform) -> None:
        """Take the IMU or laser mounting from a static transform base_frame -> sensor."""
        if tf.parent != self.params.base_frame:
            return
        rot = quat_to_matrix(tf.rotation)
        if 'imu' in tf.child.lower():
            self._imu_rot = rot
        elif any(k in tf.child.lower() for k in ('laser', 'scan', 'lidar')):
            yaw = math.atan2(rot[1, 0], rot[0, 0])
            self.laser_pose = np.array([tf.translation[0], tf.translation[1], yaw])

    def set_imu_mounting(self, rotation: np.ndarray) -> None:
        """Set the IMU-to-base rotation matrix (3x3)."""
        self._imu_rot = np.asarray(rotation, dtype=float)

    def set_phase(self, edge_following: bool, t: Optional[float] = None) -> None:
        """Select the seed mode's phase: True for edge following, False for work."""
        if edge_following and not self.edge_following:
            self._seed_state = 'first'
            self.count('phase_edge_following')
        self.edge_following = bool(edge_following)

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

    def update_imu(self, s: T.ImuSample) -> None:
        """Integrate one IMU sample (gyro rad/s in the IMU frame)."""
        self._start(s.t)
        rate = float((self._imu_rot @ np.asarray(s.gyro, dtype=float))[2])
        prev = self._imu_t
        prev_rate = self._last_imu_rate
        self._imu_t = s.t
        self._last_imu_rate = rate
        self._check_phase_time(s.t)
        if not self._use_gyro(s.t) or prev is None:
            return
        dt = s.t - prev
        if dt <= 0.0:
            return
        if dt > self.params.max_dt:
            self.count('imu_time_jumps')
            self.P[2, 2] += (self.params.max_turn_rate * min(dt, 10.0)) ** 2 * 0.01
            self.distrust(s.t, 'time_jump')
            return
        self._integrate_rate(0.5 * (rate + prev_rate), dt,  # trapezoidal rule
                             self.params.improved.gyro_noise)
        self._carried_check(s.t)

    def _integrate_rate(self, rate: float, dt: float, noise: float) -> None:
        # heading = integral of (1 - s) * rate - b; noise: angle random walk (rad/sqrt(s))
        self.x[2] += (rate * (1.0 - self.x[4]) - self.x[3]) * dt
        self._acc_dt += dt
        self._acc_wdt += rate * dt
        self._acc_q += noise ** 2 * dt

    def _flush_gyro(self) -> None:
        """Propagate the covariance over the gyro samples integrated since the last flush."""
        if self._acc_dt <= 0.0:
            return
        ip = self.params.improved
        P = self.P
        a, w = self._acc_dt, self._acc_wdt
        # P = F P F^T with F = I - a e2 e3^T - w e2 e4^T (rows, then columns)
        P[2, :] -= a * P[3, :] + w * P[4, :]
        P[:, 2] -= a * P[:, 3] + w * P[:, 4]
        P[2, 2] += self._acc_q
        P[3, 3] += ip.bias_walk ** 2 * self._acc_dt
        self._acc_dt = 0.0
        self._acc_wdt = 0.0
        self._acc_q = 0.0

    def update_odom(self, s: T.OdomSample) -> np.ndarray:
        """Apply one odometry sample; return the estimated pose [x, y, yaw] (m, m, rad)."""
        self._start(s.t)
        self._check_phase_time(s.t)
        cur = np.array([s.x, s.y, s.yaw])
        if not self.initialized:
            self.x[:3] = cur
            self.initialized = True
            self._odom_prev, self._odom_t = cur, s.t
            return self.pose
        dt = s.t - self._odom_t
        if dt <= 0.0:
            return self.pose
        px, py, pth = self._odom_prev
        c0, s0 = math.cos(pth), math.sin(pth)
        ex, ey = cur[0] - px, cur[1] - py
        d = (c0 * ex + s0 * ey, -s0 * ex + c0 * ey, _wrap(cur[2] - pth))  # prev^-1 (+) cur
        dist = math.hypot(d[0], d[1])
        self._odom_prev, self._odom_t = cur, s.t
        if dt > self.params.max_dt:
            self.count('odom_time_jumps')
            self.distrust(s.t, 'time_jump')
            self._inflate_position(dist + 0.1)
            return self.pose
        if dist > self.params.max_speed * dt + 0.05 or abs(d[2]) > 6.0 * dt + 0.5:
            self.count('odom_resets')
            self.distrust(s.t, 'odom_reset')
            return self.pose
        self._odom_speed = dist / dt
        self._odom_v = d[0] / dt
        self._odom_rate = d[2] / dt
        if not self._use_gyro(s.t):
            self._integrate_rate(d[2] / dt, dt, self.params.improved.odom_yaw_noise)
        self._flush_gyro()
        th = self.x[2]
        c, sn = math.cos(th), math.sin(th)
        dx = c * d[0] - sn * d[1]
        dy = sn * d[0] + c * d[1]
        self.x[0] += dx
        self.x[1] += dy
        P = self.P
        # P = F P F^T with F = I - dy e0 e2^T + dx e1 e2^T (rows, then columns)
        P[0, :] -= dy * P[2, :]
        P[1, :] += dx * P[2, :]
        P[:, 0] -= dy * P[:, 2]
        P[:, 1] += dx * P[:, 2]
        q = self.params.improved.odom_noise ** 2 * dist
        P[0, 0] += q
        P[1, 1] += q
        self._carried_check(s.t)
        return self.pose

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

    def _check_phase_time(self, t: float) -> None:
        sw = self.params.seed.phase_switch_time
        if sw > 0.0 and not self.edge_following and self._t0 is not None \
                and t - self._t0 >= sw and not self._switched:
            self._switched = True
            self.set_phase(True, t)

    # -- scans ---------------------------------------------------------------------------
    def scan_points(self, s: T.ScanSample) -> tuple[Optional[np.ndarray], Optional[str]]:
        """Return the valid hits (N, 2) in base_link (m) and None, or None and a reject reason."""
        r = np.asarray(s.ranges, dtype=float)
        if r.size == 0:
            return None, 'empty_scan'
        if self._beam_count is None:
            self._beam_count = r.size
        elif r.size != self._beam_count:
            n, k = self._new_count
            self._new_count = (r.size, k + 1 if n == r.size else 1)
            if self._new_count[1] < 10:
                self._prev_ranges = None
                return None, 'beam_count_changed'
            self._beam_count = r.size  # a reconfigured driver: accept after 10 scans
            self._prev_ranges = None
        idx, rv, a = s.beams(self.params.lines.max_range)
        if idx.size < self.params.min_valid_beams:
            return None, 'too_few_valid_beams'
        lx, ly, lyaw = self.laser_pose
        c, sn = math.cos(lyaw), math.sin(lyaw)
        px = rv * np.cos(a)
        py = rv * np.sin(a)
        bx, by = lx + c * px - sn * py, ly + sn * px + c * py
        if s.time_increment != 0.0 and math.isfinite(s.time_increment):
            # de-skew a rotating lidar: beam i is measured at t + i * time_increment, when
            # the robot has turned by rate * dt_i and moved by v * dt_i (constant over a scan)
            dti = s.beam_times(idx)
            rate = self._last_imu_rate - self.x[3] if self._use_gyro(s.t) else self._odom_rate
            th = rate * dti
            ct, st = np.cos(th), np.sin(th)
            bx, by = ct * bx - st * by + self._odom_v * dti, st * bx + ct * by
        return np.column_stack((bx, by)), None

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

    def update_scan(self, s: T.ScanSample) -> tuple[list[Correction], Optional[str]]:
        """Process one scan; return (corrections made, reject reason or None)."""
        self._start(s.t)
        self._check_phase_time(s.t)
        pts, reason = self.scan_points(s)
        if pts is None:
            self.count('scans_rejected_' + reason)
            return [], reason
        if not self.initialized:
            self.count('scans_before_odometry')
            return [], 'no_odometry_yet'
        if self._scan_changed_while_stopped(s, s.t):
            self._inflate_position(0.5)
            self.distrust(s.t, 'carried')
        if not self.trusted(s.t):
            self.count('scans_untrusted')
            return [], None
        rate = self._last_imu_rate if self._use_gyro(s.t) else self._odom_rate
        if abs(rate) > self.params.max_turn_rate:
            self.count('scans_turning_fast')
            return [], None
        self._flush_gyro()
        world = pts @ rot2(self.x[2]).T + self.x[:2]
        cells = self.grid.add_points(world, s.t)
        lines = extract_lines(cells, self.params.lines, s.t)
        self.count('lines', len(lines))
        if not lines:
            return [], None
        if self.params.mode == 'seed':
            out = self._seed_step(lines, s.t)
        else:
            out = self._improved_step(lines, s.t)
        if any(c.kind != 'filter' or abs(c.delta) > 0.2 * _DEG or c.position_delta > 0.03
               for c in out):
            self.grid.clear()  # its hits were placed with the old pose
        return out, None

    def update(self, sample) -> list[Correction]:
        """Dispatch one core sample (IMU, odometry, scan, static transform, phase Bool)."""
        if isinstance(sample, T.ImuSample):
            self.update_imu(sample)
        elif isinstance(sample, T.OdomSample):
            self.update_odom(sample)
        elif isinstance(sample, T.ScanSample):
            return self.update_scan(sample)[0]
        elif isinstance(sample, T.StaticTransform):
            self.set_transform(sample)
        elif isinstance(sample, T.BoolSample):
            self.set_phase(sample.value, sample.t)
        return []

    # -- seed mode -----------------------------------------------------------------------
    def _new_reference(self, line: Line, t: float, cov: np.ndarray) -> Reference:
        ref = Reference(self._next_id, line, t, cov, self.pose, t_last=t, origin=line)
        self._next_id += 1
        return ref

    def _seed_step(self, lines: list[Line], t: float) -> list[Correction]:
        p = self.params
        refs = self._seed_refs[:len(self.references)]
        if not self.edge_following:  # S1: store references
            for line in lines:
                refs = self._seed_refs[:len(self.references)]
                if np.any(np.isfinite(condition2_many(refs, line, p.match))):
                    continue  # the same wall as a stored reference: keep the earliest copy
                if len(self.references) >= p.seed.max_references:
                    self.count('references_full')
                    continue
                ref = self._new_reference(line, t, np.zeros((2, 2)))
                ref.confirmed = True
                self._seed_refs[len(self.references)] = [*line.p1, *line.p2, line.angle,
                                                         line.length]
                self._log_reference(ref)
                self.references.append(ref)
            return []
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
            errs = condition2_many(refs, line, p.match)
            if not np.any(np.isfinite(errs)):
                self.count('seed_unmatched_lines')
                continue
            i = int(np.nanargmin(np.abs(errs)))  # S3: smallest angle error
            best, best_err = self.references[i], float(errs[i])
            if self._seed_state == 'first' or kind == 'length':
                self._seed_first_len = line.length
            self._seed_state = 'calibrated'
            self._seed_t_cal = t
            if abs(best_err) <= p.match.angle_threshold:
                self.count('seed_below_threshold')
                continue
            delta = seed_heading_correction(best.line.angle, line.angle, p.seed.w1)
            before = self.pose
            self._apply_heading(delta)
            best.matches += 1
            out.append(Correction(t, delta, best_err, (best.id,), (line,), (best.line,),
                                  self.pose, kind, 0.0, before))
            self.count('corrections')
            self.corrections.append(out[-1])
            break  # the pose changed: later lines of this scan were placed with the old one
        return out

    def _apply_heading(self, delta: float) -> None:
        self.x[2] += delta
        self._cum_correction += delta

    # -- improved mode -------------------------------------------------------------------
    def _line_model(self, ref: Line, line: Line):
        """Return (innovation y, Jacobian H (2x5), lever s) of a line against a reference."""
        n = ref.normal
        m = line.midpoint
        y = np.array([_wrap_half(ref.angle - line.angle), ref.rho - float(n @ m)])
        lever = m - self.x[:2]
        H = np.zeros((2, 5))
        H[0, 2] = 1.0
        H[1, 0], H[1, 1] = n[0], n[1]
        H[1, 2] = float(n @ np.array([-lever[1], lever[0]]))
        s = float(ref.direction @ (m - ref.midpoint))
        return y, H, s

    def _line_noise(self, line: Line) -> np.ndarray:
        ip = self.params.improved
        sa = line.angle_sigma() ** 2 + ip.line_angle_sigma ** 2
        sr = line.variance / max(line.n_cells, 1) + ip.line_sigma ** 2
        return np.diag([sa, sr])

    def _reference_cov(self, line: Line) -> np.ndarray:
        """Covariance (angle, distance) of a new reference: pose covariance + fit noise."""
        n = line.normal
        lever = line.midpoint - self.x[:2]
        H = np.zeros((2, 5))
        H[0, 2] = 1.0
        H[1, 0], H[1, 1] = n[0], n[1]
        H[1, 2] = float(n @ np.array([-lever[1], lever[0]]))
        return H @ self.P @ H.T + self._line_noise(line)

    def _overlaps(self, ref: Line, line: Line, margin: float) -> bool:
        u = ref.direction
        o = float(u @ ref.p1)
        r1, r2 = 0.0, float(u @ ref.p2) - o
        a, b = sorted((float(u @ line.p1) - o, float(u @ line.p2) - o))
        return b >= r1 - margin and a <= r2 + margin

    def _extend(self, ref: Reference, line: Line) -> None:
        """Extend a reference's endpoints to cover a matched line (projected onto it)."""
        u = ref.line.direction
        c = ref.line.midpoint
        proj = [float(u @ (p - c)) for p in (ref.line.p1, ref.line.p2, line.p1, line.p2)]
        lo, hi = min(proj), max(proj)
        if hi - lo > ref.line.length + 1e-6:
            ref.line = line_from_endpoints(c + lo * u, c + hi * u, ref.line.t, ref.line.variance,
                                           ref.line.n_cells)

    def _prefilter(self, refs: list, lines: list[Line], margin: float,
                   arrays: Optional[tuple] = None) -> tuple:
        """Vectorised (lines x references) pre-filter: angle, overlap, distance (loose)."""
        tol = self.params.match.angle_tolerance
        ang, u, nrm, o, r2, rho = arrays if arrays is not None else _ref_arrays(refs)
        la = np.array([ln.angle for ln in lines])
        lp1 = np.array([ln.p1 for ln in lines])
        lp2 = np.array([ln.p2 for ln in lines])
        err = _wrap_half(ang[None, :] - la[:, None])
        a1 = lp1 @ u.T - o[None, :]
        a2 = lp2 @ u.T - o[None, :]
        lo, hi = np.minimum(a1, a2), np.maximum(a1, a2)
        dist = rho[None, :] - (0.5 * (lp1 + lp2)) @ nrm.T
        ok = (np.abs(err) <= tol) & (hi >= -margin) & (lo <= r2[None, :] + margin) \
            & (np.abs(dist) < margin + 1.0)
        return err, dist, ok, u, nrm

    def _gate(self, refs: list, line: Line, margin: float, chi2: float,
              pre: Optional[tuple] = None) -> list[tuple]:
        if not refs:
            return []
        if pre is None:
            err, dist, ok, u, nrm = self._prefilter(refs, [line], margin)
            pre = (err[0], dist[0], ok[0], u, nrm)
        err, dist, ok, u, nrm = pre
        out = []
        R_line = self._line_noise(line)
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            return out
        P = self.P
        p00, p01, p02, p11, p12, p22 = P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2]
        m = line.midpoint
        lx, ly = m[0] - self.x[0], m[1] - self.x[1]
        rl0, rl1 = R_line[0, 0], R_line[1, 1]
        for i in idx.tolist():
            ref = refs[i]
            nx, ny = float(nrm[i, 0]), float(nrm[i, 1])
            ux, uy = float(u[i, 0]), float(u[i, 1])
            y0 = float(err[i])
            y1 = float(dist[i])  # rho_ref - n . midpoint
            h12 = nx * -ly + ny * lx
            rm = ref.line.midpoint
            sl = ux * (m[0] - rm[0]) + uy * (m[1] - rm[1])
            C = ref.cov
            # S = H P H^T + A C A^T + R_line, H = [[0, 0, 1], [nx, ny, h12]], A = [[1, 0], [s, 1]]
            s00 = p22 + C[0, 0] + rl0
            s01 = nx * p02 + ny * p12 + h12 * p22 + sl * C[0, 0] + C[0, 1]
            s11 = (nx * nx * p00 + 2 * nx * ny * p01 + ny * ny * p11 + 2 * nx * h12 * p02
                   + 2 * ny * h12 * p12 + h12 * h12 * p22
                   + sl * sl * C[0, 0] + 2 * sl * C[0, 1] + C[1, 1] + rl1)
            det = s00 * s11 - s01 * s01
            if not det > 0.0:
                continue
            nis = (s11 * y0 * y0 - 2.0 * s01 * y0 * y1 + s00 * y1 * y1) / det
            if nis <= chi2:
                r01 = sl * C[0, 0] + C[0, 1]
                R = np.array([[C[0, 0] + rl0, r01],
                              [r01, sl * sl * C[0, 0] + 2 * sl * C[0, 1] + C[1, 1] + rl1]])
                out.append((nis, ref, np.array([y0, y1]), None, R))
        return out

    def _improved_step(self, lines: list[Line], t: float) -> list[Correction]:
        ip = self.params.improved
        pos_sigma = math.sqrt(max(self.P[0, 0], self.P[1, 1], 0.0))
        margin = ip.overlap_margin + 3.0 * pos_sigma
        matches = []
        pre = self._prefilter(self.references, lines, margin) if self.references else None
        for k, line in enumerate(lines):
            gated = self._gate(self.references, line, margin, 4.0 * ip.gate_chi2,
                               None if pre is None else
                               (pre[0][k], pre[1][k], pre[2][k], pre[3], pre[4]))
            close = [g for g in gated if g[0] <= ip.gate_chi2]
            if gated:
                if not close:
                    self.count('lines_outside_gate')
                    continue
                rhos = [g[2][1] for g in gated]
                if max(rhos) - min(rhos) > ip.ambiguity_distance + 1e-9 and len(gated) > 1:
                    # two references within reach at different distances: parallel walls
                    self.count('lines_ambiguous')
                    continue
                nis, ref, y, H, R = min(close, key=lambda g: g[0])
                ref.t_last = t
                matches.append((line, ref, y, H, R))
                continue
            self._tentative_step(line, t, margin)
        self._age_tentative(t)
        if not matches:
            return []
        return self._filter_update(matches, t)

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
        y, H, s = self._line_model(ref.line, line)
        A = np.array([[1.0, 0.0], [s, 1.0]])
        c_obs = 2.0 * (H @ self.P @ H.T + self._line_noise(line))
        # observation in the reference's (angle, distance at its midpoint) coordinates
        Ainv = np.linalg.inv(A)
        z = Ainv @ (-y)
        c_z = Ainv @ c_obs @ Ainv.T
        K = ref.cov @ np.linalg.inv(ref.cov + c_z)
        dz = K @ z
        ref.cov = (np.eye(2) - K) @ ref.cov
        mid = ref.line.midpoint
        half = 0.5 * ref.line.length
        ang = ref.line.angle + float(dz[0])
        u = np.array([math.cos(ang), math.sin(ang)])
        mid = mid + float(dz[1]) * ref.line.normal
        ref.line = line_from_endpoints(mid - half * u, mid + half * u, ref.line.t,
                                       ref.line.variance, ref.line.n_cells)

    def _tentative_step(self, line: Line, t: float, margin: float) -> None:
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
                    and self._overlaps(ref.line, line, margin):
                self.count('lines_near_reference')
                return
        if math.sqrt(self.P[2, 2]) > ip.reference_max_heading_sigma \
                or math.sqrt(max(self.P[0, 0], self.P[1, 1])) > ip.reference_max_position_sigma:
            self.count('references_not_made_uncertain')
            return
        self.tentative.append(self._new_reference(line, t, self._reference_cov(line)))

    def _log_reference(self, ref: Reference) -> None:
        """Keep every reference ever used (bounded) so corrections can be audited."""
        self.reference_log[ref.id] = ref
        if len(self.reference_log) > 10000:
            del self.reference_log[next(iter(self.reference_log))]

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

    def _filter_update(self, matches: list, t: float) -> list[Correction]:
        ip = self.params.improved
        # lines of one scan must agree on the heading error
        errs = [float(m[2][0]) for m in matches]
        sig = [math.sqrt(m[4][0, 0]) for m in matches]
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
        if not keep:
            return []
        # support: distinct references now, or agreement over time
        for line, ref, y, H, R in keep:
            self._support.append((t, ref.id, y[0] + self._cum_correction,
                                  math.sqrt(R[0, 0])))
        while self._support and self._support[0][0] < t - ip.support_window:
            self._support.popleft()
        ids_now = {m[1].id for m in keep}
        support = len(ids_now)
        if support < ip.min_support:
            a_now = float(np.mean([m[2][0] for m in keep])) + self._cum_correction
            s_now = float(np.mean([math.sqrt(m[4][0, 0]) for m in keep]))
            agreeing = {(tt, rid) for tt, rid, a, sg in self._support
                        if tt < t and abs(a - a_now) <= ip.consistency_sigma
                        * math.hypot(sg, s_now)}
            support += len({tt for tt, _ in agreeing})
        if support < ip.min_support:
            self.count('matches_unsupported')
            return []
        if t - self._last_update < ip.update_interval:
            return []
        self._last_update = t
        before = self.x.copy()
        min_ref_var = math.inf
        if ip.refine_references:
            for line, ref, y, H, R in keep:
                self._refine(ref, line)
        for line, ref, y, H, R in keep:
            line = self._replace(line, before)  # re-place with the pose updated so far
            y, H, s = self._line_model(ref.line, line)
            A = np.array([[1.0, 0.0], [s, 1.0]])
            R = A @ ref.cov @ A.T + self._line_noise(line)
            if not ip.correct_position:
                H, y, R = H[:1], y[:1], R[:1, :1]
            S = H @ self.P @ H.T + R
            K = self.P @ H.T @ np.linalg.inv(S)
            self.x = self.x + K @ y
            I_KH = np.eye(5) - K @ H
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
        corr = Correction(t, delta, float(np.mean([m[2][0] for m in keep])),
                          tuple(m[1].id for m in keep), tuple(m[0] for m in keep),
                          tuple(m[1].line for m in keep), self.pose, 'filter',
                          float(np.hypot(*(self.x[:2] - before[:2]))),
                          np.array([before[0], before[1], _wrap(before[2])]))
        self.corrections.append(corr)
        self.count('corrections')
        return [corr]

    # -- batch ---------------------------------------------------------------------------
    def run(self, samples: Iterable) -> dict:
        """
        Process a whole recording (core samples in time order); return a result dict.

        The result holds ``poses`` (list of (t, x, y, yaw) at each odometry
        sample), ``corrections`` and ``counts``.
        """
        poses = []
        for s in samples:
            self.update(s)
            if isinstance(s, T.OdomSample):
                p = self.pose
                poses.append((s.t, p[0], p[1], p[2]))
        return {'poses': np.array(poses).reshape(-1, 4), 'corrections': list(self.corrections),
                'counts': dict(self.counts)}
