# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The streaming front end of wheel calibration: wheel data + scans -> segments and stages.

Wheel data: joint positions (rad) of the named joints (``JointStateSample``),
or ``OdomSample`` inverted into virtual wheel rotations by the nominal
geometry. Scans (``ScanSample``) become points through
:func:`robot_calib.core.frames.scan_points`, de-skewed by the wheel odometry.
A key frame closes a :class:`robot_calib.core.kinematics.Segment`; in a
steered-wheel drive consecutive straight segments also form the seed's stages
(seed 003), whose first and last scans are matched directly. Both variants
consume what :class:`DriveSegmenter` cuts.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import math
import sys
from typing import Any, Callable, Optional

import numpy as np
from robot_calib.core import frames
from robot_calib.core import kinematics as K
from robot_calib.core.kinematics import Segment
from robot_calib.core.series import Thinned
from robot_calib.methods.wheel_odometry_calibration import drive_detect
from robot_calib.methods.wheel_odometry_calibration import wheels as W
from robot_calib.methods.wheel_odometry_calibration.params import keys_of, WheelCalibParams

MatchFn = Callable[[Any, Any, np.ndarray], Optional[tuple[np.ndarray, dict]]]


def default_matcher(source: np.ndarray, target: Any, guess: np.ndarray) -> Optional[tuple]:
    """
    Register ``source`` points to a prepared ``target`` (robot_calib.core.scan_match).

    Returns ``(pose, info)`` (pose of the source frame in the target frame, m,
    m, rad) or None when the match failed or is degenerate. The guess is the
    nominal wheel odometry between key frames (centimetres and tenths of a
    degree off on a calibration drive), inside the refinement's own annealed
    gate (``refine_max_correspondence``, 0.8 m, against kiss-icp's 1.0 m), so
    the refinement runs first; only a match it fails (its quality check
    refuses it) is registered again with kiss-icp's coarse alignment before
    the refinement.
    """
    from robot_calib.core import scan_match
    res = scan_match.register(source, target, guess, scan_match.ScanMatchParams(coarse='none'))
    if not res.ok:
        res = scan_match.register(source, target, guess)
    return _motion(res)


def default_rematcher(source: np.ndarray, target: Any, guess: np.ndarray) -> Optional[tuple]:
    """
    Register again from the pose a first match found: the refinement alone, no kiss-icp.

    The re-deskew moves points by millimetres, so the first match's pose is
    already in the basin the coarse alignment looks for; the point-to-line
    refinement (unchanged: a narrower first gate would stop it earlier, 1e-4 m
    from where the full match stops) and its quality check run as in
    :func:`default_matcher`.
    """
    from robot_calib.core import scan_match
    return _motion(scan_match.register(source, target, guess,
                                       scan_match.ScanMatchParams(coarse='none')))


def default_rematch_many(sources: list[np.ndarray], targets: list[Any],
                         guesses: list[np.ndarray]) -> list[Optional[tuple]]:
    """
    Return :func:`default_rematcher` of many pairs, run together (scan_match_many).

    The pairs' refinements iterate in lock step over stacked arrays: the same
    iterations and quality check as one by one, poses equal to rounding.
    """
    from robot_calib.core import scan_match, scan_match_many
    results = scan_match_many.register_many(sources, targets, guesses,
                                            scan_match.ScanMatchParams(coarse='none'))
    return [_motion(r) for r in results]


def _motion(res: Any) -> Optional[tuple]:
    """Return (sensor motion, match quality) of a registration result, None when it failed."""
    if not res.ok:
        return None
    return np.asarray(res.pose, dtype=float), {'rmse': float(res.rmse),
                                               'min_eigenvalue': float(res.min_eigenvalue)}


REMATCH_CHUNK = 128
"""Key-frame pairs re-matched together (bounds the memory of the prepared targets).

On the 1 h drive (2841 pairs) 128 gives the node alone a peak of 187 MB against 210 MB for
256 at the same speed; 64 gives 177 MB and a 5 % slower re-match."""

STUCK_TURN = 2.0 * math.pi
"""Turn (rad) a joint's velocity integrates to while its position stays put: positions unset."""

MOVING_RATE = 0.1
"""Joint speed (rad/s) above which that turn is counted."""

SIDEWAYS_SHARE = 0.1
"""Share of the odometry's path moved sideways beyond which it is called holonomic (-).

An arc's chord integrated to first order stays within the allowance of
:meth:`DriveSegmenter._measure_sideways`; a mecanum robot's straight sideways runs count whole."""

SIDEWAYS_MIN_PATH = 2.0
"""Odometry path (m) before the sideways share is judged."""


def prepare_target(points: np.ndarray) -> Any:
    """Prepare key-frame points as a registration target (scan_match.PreparedScan)."""
    from robot_calib.core import scan_match
    return scan_match.PreparedScan(points)


def _scan_end(scan: Any) -> float:
    """Return the time (s) of the last beam a scan measured."""
    return scan.time_span()[1]


@dataclass
class _KeyFrame:
    t: float
    points: np.ndarray
    target: Any
    odom: np.ndarray
    scan: Any = None
    wheels: Optional[W.WheelWindow] = None


class DriveSegmenter:
    """
    Cut a calibration drive into segments between key-frame scans (and seed stages).

    Feed wheel data with :meth:`add_joint_state` / :meth:`add_odom` and scans
    with :meth:`add_scan`; :attr:`segments` grows, the stages of a steered
    drive wheel are collected with :meth:`take_stages`. A key frame closes a
    segment after ``keyframe.distance`` or ``keyframe.angle`` of nominal
    odometry motion; its scan is registered against the previous key frame's
    scan, guessed from the nominal odometry. A segment keeps its two scans
    and the wheel samples around them for :meth:`redeskew`; the wheel history
    itself keeps only the recent part. At most ``max_segments`` segments are
    kept: beyond that every other one goes and later ones are kept at twice the
    stride, so the kept ones span the whole drive and memory stays bounded
    (:attr:`stride`, :attr:`segments_cut`). When the drive type changes
    (``auto`` deciding from the joint names), everything so far is dropped and
    :attr:`epoch` counts up.
    """

    def __init__(self, params: WheelCalibParams, matcher: Optional[MatchFn] = None,
                 prepare: Optional[Callable[[np.ndarray], Any]] = None,
                 max_range: float = 30.0):
        """Create an empty front end (``matcher``/``prepare`` replace the scan registration)."""
        self.params = params
        p = self.params
        self.nominal = p.nominal()
        self.sensor_pose = np.array([p.lidar_x, p.lidar_y, p.lidar_yaw], dtype=float)
        self.matcher = matcher or default_matcher
        self.rematcher = matcher or default_rematcher
        self.rematch_many = None if matcher else default_rematch_many
        self.prepare = prepare or prepare_target
        self.max_range = max_range
        self.joint_names = drive_detect.JointNames(p.left_wheel_joint, p.right_wheel_joint,
                                                   p.traction_joint, p.steering_joint)
        self._joints: Optional[tuple[str, str]] = None
        self._seen_names: tuple = ()
        self.drive_problem = ''
        """Why the drive type is not known, or contradicts the joints ('' when fine)."""
        self.configured_drive = p.drive_type
        self.drive_source = 'configured' if p.drive_type != 'auto' else 'undecided'
        self._pending: list[Any] = []
        self.counts = {'wheel_samples': 0, 'scans': 0, 'match_attempts': 0, 'match_failed': 0,
                       'wheel_gaps': 0, 'encoder_unwraps': 0, 'stages': 0,
                       'stage_match_failed': 0, 'scans_without_wheel_data': 0,
                       'missing_joints': 0, 'segments_thinned': 0}
        self.epoch = -1
        """Counts the (re)starts of the calibration (a new drive type drops the data)."""
        self._joint_integrals: dict[str, list] = {}
        """Per wheel joint: last stamp, velocity, its integral, first position, turn moving."""
        self._integrated: set[str] = set()
        """Wheel joints whose position is their integrated velocity (the driver gives none)."""
        self._set_drive(p.drive_type if p.drive_type != 'auto' else drive_detect.DIFFERENTIAL)

    def _set_drive(self, drive: str) -> None:
        """(Re)start the calibration for ``drive``: wheel data and segments so far are dropped."""
        self.drive = drive
        self.params = dataclasses.replace(self.params, drive_type=drive)
        self.x_nom = np.array([self.nominal[k] for k in keys_of(drive)], dtype=float)
        self.segments = Thinned(self.params.max_segments or sys.maxsize)
        """The segments kept: at most ``max_segments``, evenly thinned over the drive."""
        self._stages: list[Segment] = []
        self.epoch += 1
        self._reset_wheels()
        self._use_joints = False
        self._odom_prev: Optional[Any] = None
        self.odom_path = 0.0
        """Distance (m) the odometry moved (while it stands in for the wheels)."""
        self.odom_sideways = 0.0
        """Of it, the sideways motion (m) no wheel that rolls without sliding gives."""

    def set_sensor_pose(self, x: float, y: float, yaw: float) -> None:
        """Set the nominal sensor pose in base_link (m, m, rad), e.g. from /tf_static."""
        self.sensor_pose = np.array([x, y, yaw], dtype=float)
        self.nominal.update(lidar_x=float(x), lidar_y=float(y), lidar_yaw=float(yaw))
        self.params = dataclasses.replace(self.params, lidar_x=float(x), lidar_y=float(y),
                                          lidar_yaw=float(yaw))
        self.x_nom[-3:] = self.sensor_pose

    # -- wheel input ----------------------------------------------------------------------
    def add_wheel(self, t: float, a: float, b: float, va: float = math.nan,
                  vb: float = math.nan) -> None:
        """
        Add one wheel sample: differential (phi_l, phi_r) or steered (traction, reading).

        :param t: time (s)
        :param a: left wheel / traction joint position (rad)
        :param b: right wheel position / steering reading (rad)
        :param va: velocity of ``a`` (rad/s, NaN when unknown), used to unwrap
        :param vb: velocity of ``b`` (rad/s, NaN when unknown)
        """
        first = not self.wheels.t
        self.counts['encoder_unwraps'] += self.wheels.add(t, a, b, va, vb)
        self.counts['wheel_samples'] += 1
        if not first:
            self._drain()

    def add_joint_state(self, js: Any) -> bool:
        """Add a ``JointStateSample``; return False when the drive's joints are absent."""
        if tuple(js.names) != self._seen_names:
            self._on_joint_names(tuple(js.names))
        if self._joints is None:
            self.counts['missing_joints'] += 1
            return False
        (a, va), (b, vb) = js.get(self._joints[0]), js.get(self._joints[1])
        a = self._joint_position(self._joints[0], js.t, a, va)
        if self.drive == 'differential':  # (a steering reading cannot be integrated)
            b = self._joint_position(self._joints[1], js.t, b, vb)
        if not (math.isfinite(a) and math.isfinite(b)):
            self.counts['missing_joints'] += 1
            return False
        if not self._use_joints:
            self._use_joints = True
            self._reset_wheels()
        self.add_wheel(js.t, a, b, va, vb)
        return True

    def _joint_position(self, name: str, t: float, position: float, velocity: float) -> float:
        """
        Return a wheel joint's position (rad): as given, or its velocity integrated.

        Some drivers fill only the velocities: positions missing (NaN), or left at
        one value while the velocities turn the wheel a whole turn (counting only
        speeds above MOVING_RATE, so a velocity offset at rest does not). That joint's
        position is then the trapezoid integral of its velocity (rad/s) from its
        first sample on, and the calibration restarts with it.
        """
        st = self._joint_integrals.get(name)
        if st is None:
            st = self._joint_integrals[name] = [t, velocity, 0.0, position, 0.0]
        dt = t - st[0]
        if math.isfinite(velocity) and math.isfinite(st[1]) and \
                0.0 < dt <= self.params.keyframe.max_wheel_gap:
            st[2] += 0.5 * (velocity + st[1]) * dt
            if abs(velocity) > MOVING_RATE:
                st[4] += abs(velocity) * dt
        st[0], st[1] = t, velocity
        if name in self._integrated:
            return st[2]
        if not math.isfinite(velocity):
            return position
        if not math.isfinite(position) or (position == st[3] and st[4] > STUCK_TURN):
            self._integrated.add(name)
            self.counts['joints_from_velocity'] = len(self._integrated)
            if math.isfinite(position):  # the data cut so far had a wheel standing still
                self._set_drive(self.drive)
            return st[2]
        return position

    @property
    def uses_joints(self) -> bool:
        """Return True while joint states drive the odometry (odometry input is then unused)."""
        return self._use_joints

    @property
    def drive_joints(self) -> tuple[str, ...]:
        """Return the two joints in use: (left, right) or (traction, steering); () for none."""
        return self._joints or ()

    def _on_joint_names(self, names: tuple) -> None:
        """
        Tell the drive (``auto``) or check it (configured) from a new set of joint names.

        ``auto`` decides once, at the first names that tell exactly one drive
        (odometry integrated before under the assumed drive is dropped). A
        configured drive whose joints are absent while the joints of the other
        drive are present is recorded in :attr:`drive_problem`: the result is
        then never ``converged``.
        """
        self._seen_names = names
        found, why = drive_detect.detect(names, self.joint_names)
        if self._joints is not None:
            return
        if self.configured_drive == 'auto':
            if found is None:
                self.drive_problem = (f'drive type not told by joint_states ({why}): set '
                                      'drive_type and the joint names')
                return
            if found.drive_type != self.drive or self.counts['wheel_samples']:
                self._set_drive(found.drive_type)
            self._joints, self.drive_source, self.drive_problem = found.joints, found.how, ''
            return
        joints = self.joint_names.configured(self.drive)
        if all(j in names for j in joints):
            self._joints, self.drive_problem = joints, ''
        elif found is not None and found.drive_type != self.drive:
            self.drive_problem = (f'joint_states carry {found.joints[0]} and {found.joints[1]}: '
                                  f'the robot looks {found.drive_type}, but drive_type is '
                                  f'{self.drive} (set drive_type: {found.drive_type}, or auto)')

    def _reset_wheels(self) -> None:
        self.wheels = W.WheelHistory(self.drive, self.x_nom, self.params.keyframe.max_wheel_gap)
        self._kf: Optional[_KeyFrame] = None
        self._stage: list[Segment] = []
        self._stage_start: Optional[_KeyFrame] = None

    def add_odom(self, od: Any) -> bool:
        """Add an ``OdomSample`` as virtual wheel rotations; False when joints are used instead."""
        if self._use_joints:
            return False
        prev = self._odom_prev
        self._odom_prev = od
        if prev is None:
            self.add_wheel(od.t, 0.0, 0.0 if self.drive == 'differential' else
                           (0.0 - self.nominal['steering_offset'])
                           / self.nominal['steering_scale'])
            return True
        rel = K.compose(K.inverse(np.array([prev.x, prev.y, prev.yaw])),
                        np.array([od.x, od.y, od.yaw]))
        self._measure_sideways(rel)
        a, b = self.wheels.virtual_rotations(rel, self.nominal)
        self.add_wheel(od.t, a, b)
        return True

    def _measure_sideways(self, rel: np.ndarray) -> None:
        """
        Add one odometry increment ``rel`` (dx, dy m in the earlier pose's frame, dyaw rad).

        A differential or steered drive's base moves along an arc; what is beyond it
        (:func:`robot_calib.core.kinematics.off_arc`) is a holonomic robot's motion.
        """
        dx, dy, dyaw = float(rel[0]), float(rel[1]), float(rel[2])
        step = math.hypot(dx, dy)
        if not (math.isfinite(step) and abs(dyaw) < 1.0):
            return
        self.odom_path += step
        self.odom_sideways += abs(K.off_arc(dx, dy, dyaw))

    # -- scans ----------------------------------------------------------------------------
    def add_scan(self, scan: Any) -> None:
        """Add a ``ScanSample`` (processed once wheel data covers its time)."""
        self.counts['scans'] += 1
        if self.params.scan_time_offset:
            scan = dataclasses.replace(scan, t=scan.t + self.params.scan_time_offset)
        self._pending.append(scan)
        if len(self._pending) > 200:
            self._pending.pop(0)
            self.counts['scans_without_wheel_data'] += 1
        self._drain()

    def _drain(self) -> None:
        times = self.wheels.t
        drained = False
        while self._pending and times and _scan_end(self._pending[0]) <= times[-1]:
            scan = self._pending.pop(0)
            drained = True
            if scan.t < times[0]:
                self.counts['scans_without_wheel_data'] += 1
                continue
            self._on_scan(scan)
        if drained:
            self._trim_wheels()

    def _trim_wheels(self) -> None:
        """Forget wheel data no key frame or waiting scan needs any more."""
        needed = [self.wheels.t[-1]]
        if self._kf is not None:
            needed.append(self._kf.t)
        if self._pending:
            needed.append(min(self._pending[0].t, self._pending[0].time_span()[0]))
        self.wheels.trim_before(min(needed))

    def range_limit(self, scan: Any) -> float:
        """Return the farthest range (m) matched in ``scan`` (``range_margin`` below its max)."""
        limit = self.max_range
        if scan.range_max > 0.0:
            limit = min(limit, scan.range_max * (1.0 - self.params.range_margin))
        return limit

    def deskewed_points(self, scan: Any) -> np.ndarray:
        """
        Return the scan's points (m) in its frame at the stamp, motion-compensated.

        A rotating lidar measures beam i at ``t + i * time_increment``; the
        nominal wheel odometry moves each point into the sensor frame at the
        stamp (without this, turns bias the scan-matched rotation);
        :meth:`redeskew` does it again with the calibrated odometry.
        """
        motion = None
        if len(self.wheels.t) >= 2:
            motion = self.wheels.sensor_motion_during(scan, self.sensor_pose)
        return frames.scan_points(scan, max_range=self.range_limit(scan), motion=motion)[0]

    def _on_scan(self, scan: Any) -> None:
        odom, _ = self.wheels.odom_at(scan.t)
        if self._kf is None:
            self._kf = self._key_frame(scan, self.deskewed_points(scan), odom)
            return
        kp = self.params.keyframe
        kf = self._kf
        rel = K.between_scalar(kf.odom.tolist(), odom.tolist())
        dist, ang = math.hypot(rel[0], rel[1]), abs(rel[2])
        moving = dist > 1e-3 or ang > 1e-3
        if not (dist >= kp.distance or ang >= kp.angle or
                (scan.t - kf.t >= kp.max_time and moving)):
            if scan.t - kf.t >= kp.max_time:
                self._kf = self._key_frame(scan, self.deskewed_points(scan), odom)
            return
        pts = self.deskewed_points(scan)
        steps = self.wheels.steps(kf.t, scan.t)
        new_kf = self._key_frame(scan, pts, odom)
        if steps is None:
            self.counts['wheel_gaps'] += 1
            self.close_stage()
            self._kf = new_kf
            return
        guess = K.sensor_motion(np.array(rel), self.sensor_pose)
        if kf.target is None:
            kf.target = self.prepare(kf.points)
        self.counts['match_attempts'] += 1
        m = self.matcher(pts, kf.target, guess)
        self._kf = new_kf
        if m is None:
            self.counts['match_failed'] += 1
            self.close_stage()
            return
        seg = Segment(kf.t, scan.t, steps, np.asarray(m[0], dtype=float),
                      {**m[1], 'scans': (kf.scan, scan), 'wheels': (kf.wheels, new_kf.wheels)})
        self._keep(seg)
        if self.drive == 'steered_wheel':
            self._stage_add(seg, kf, new_kf)

    def _key_frame(self, scan: Any, points: np.ndarray, odom: np.ndarray) -> _KeyFrame:
        """Return a key frame of ``scan`` with the wheel samples around it."""
        return _KeyFrame(scan.t, points, None, odom, scan, self.wheels.window(scan))

    def _keep(self, seg: Segment) -> None:
        """Keep a segment cut, evenly thinned past ``max_segments``."""
        self.segments.append(seg)
        self.counts['segments_thinned'] = self.segments.count - len(self.segments)

    @property
    def segments_cut(self) -> int:
        """Return how many segments were cut (matched) in this drive, kept or thinned out."""
        return self.segments.count

    @property
    def stride(self) -> int:
        """Return the thinning stride: every ``stride``-th segment cut is kept from now on."""
        return self.segments.stride

    # -- seed stages ----------------------------------------------------------------------
    def _is_straight(self, seg: Segment) -> bool:
        n = self.nominal
        ang = n['steering_scale'] * seg.steps[:, 1] + n['steering_offset']
        moving = abs(np.sum(seg.steps[:, 0])) * n['wheel_radius'] > 1e-3
        return moving and bool(np.max(np.abs(ang)) < self.params.seed.straight_steering)

    def _stage_add(self, seg: Segment, start: _KeyFrame, end: _KeyFrame) -> None:
        if not self._is_straight(seg):
            self.close_stage()
            return
        if not self._stage:
            self._stage_start = start
        self._stage.append(seg)
        self._stage_end = end
        length = self.nominal['wheel_radius'] * abs(sum(float(np.sum(s.steps[:, 0]))
                                                        for s in self._stage))
        if length >= self.params.seed.max_stage_length:
            self.close_stage()

    def close_stage(self) -> None:
        """Close the straight stage under way: match its first and last scans, keep it."""
        stage, start = self._stage, self._stage_start
        self._stage, self._stage_start = [], None
        if not stage or start is None:
            return
        length = self.nominal['wheel_radius'] * abs(sum(float(np.sum(s.steps[:, 0]))
                                                        for s in stage))
        if length < self.params.seed.min_stage_length:
            return
        guess = np.zeros(3)
        for s in stage:
            guess = K.compose(guess, s.sensor_motion)
        if start.target is None:
            start.target = self.prepare(start.points)
        m = self.matcher(self._stage_end.points, start.target, guess)
        if m is None:
            self.counts['stage_match_failed'] += 1
            return
        steps = np.concatenate([s.steps for s in stage])
        self.counts['stages'] += 1
        self._stages.append(Segment(stage[0].t0, stage[-1].t1, steps,
                                    np.asarray(m[0], dtype=float)))

    def take_stages(self) -> list[Segment]:
        """Return the stages closed since the last call (sensor motion: the direct match)."""
        stages, self._stages = self._stages, []
        return stages

    # -- what the drive lacked, and the second pass -----------------------------------------
    def problems(self) -> list[str]:
        """Return what the input lacked so far (no wheel data, failed matches...)."""
        c = self.counts
        out = [self.drive_problem] if self.drive_problem else []
        if self.configured_drive == 'auto' and self._joints is None and not out:
            out.append("drive type unknown: no joint_states named a drive's joints, and "
                       'odometry alone cannot tell a steered wheel from a differential drive '
                       '(set drive_type)')
        if c['wheel_samples'] < 2:
            out.append('no wheel data (need odom or joint_states with the named joints)')
        if self.odom_path > SIDEWAYS_MIN_PATH and \
                self.odom_sideways > SIDEWAYS_SHARE * self.odom_path:
            out.append(f'the odometry moves sideways ({self.odom_sideways:.1f} m of its '
                       f'{self.odom_path:.1f} m): a holonomic drive (mecanum or omni wheels), '
                       'neither differential nor steered, so its wheels cannot be calibrated '
                       'here')
        if c['scans'] == 0:
            out.append('no scans')
        if c['match_attempts'] and c['match_failed'] > 0.25 * c['match_attempts']:
            out.append(f'scans failed to match in {c["match_failed"]} of '
                       f'{c["match_attempts"]} segments (featureless surroundings or fast '
                       'motion)')
        return out

    def redeskew(self, x: np.ndarray) -> Optional[list[Segment]]:
        """
        Return the segments re-matched with scans deskewed by the calibrated odometry.

        ``x`` holds the calibrated parameters in :func:`keys_of` order. The
        first pass deskews with the nominal geometry; a wrong track width or
        radius left in the deskew biases the matched motion (measured: 0.03 deg
        of lidar yaw in simulation). The pairs are re-matched together,
        ``REMATCH_CHUNK`` at a time (:func:`default_rematch_many`; one by one
        with a replaced matcher). Returns None when no scan needs deskewing.
        """
        segs = [s for s in self.segments if 'scans' in s.info]
        if not segs or not any(s.info['scans'][1].time_increment != 0 for s in segs):
            return None
        lp = np.asarray(x[-3:], dtype=float)
        out = []
        cache: dict = {}

        def points(seg: Segment, k: int) -> np.ndarray:
            scan, wheels = seg.info['scans'][k], seg.info['wheels'][k]
            key = id(scan)
            if key not in cache:
                poses = W.integrate(self.drive, wheels.a, wheels.b, x)
                cache[key] = frames.scan_points(scan, max_range=self.range_limit(scan),
                                                motion=W.motion(scan, wheels.t, poses, lp))[0]
            return cache[key]
        for lo in range(0, len(segs), REMATCH_CHUNK):
            chunk = segs[lo:lo + REMATCH_CHUNK]
            sources = [points(seg, 1) for seg in chunk]
            targets = [self.prepare(points(seg, 0)) for seg in chunk]
            # the first match is the guess: deskewing moves points, not the scan stamps
            guesses = [seg.sensor_motion for seg in chunk]
            if self.rematch_many is not None:
                found = self.rematch_many(sources, targets, guesses)
            else:
                found = [self.rematcher(*job) for job in zip(sources, targets, guesses)]
            for seg, m in zip(chunk, found):
                if m is not None:
                    out.append(Segment(seg.t0, seg.t1, seg.steps, np.asarray(m[0], dtype=float),
                                       {**m[1], 'scans': seg.info['scans'],
                                        'wheels': seg.info['wheels']}))
        return out
