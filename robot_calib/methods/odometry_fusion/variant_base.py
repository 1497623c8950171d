# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The base of both fusion filters: the Estimator API, input checks, counters and warnings.

:class:`FusionFilter` implements :class:`robot_calib.core.estimator.Estimator`
for both variants: ``set_mounting`` takes the IMU mounting from static
transforms, ``update`` checks a sample and hands it to the variant
(``_imu_step``, ``_wheel_step``), ``result`` collects what both share plus
the variant's own fields (``_variant_result``). Wheel odometry is checked for
pose resets (a jump beyond what its twist explains) and for drivers that fill
only the pose (velocity from the pose increments).
"""

from __future__ import annotations

import abc
import math
from typing import Any, Callable, Optional, Union

import numpy as np
from robot_calib.core import types as T
from robot_calib.core.frames import find_mounting, rotation_matrix, StaticTree
from robot_calib.core.geometry import same_rotation, wrap_scalar
from robot_calib.core.kinematics import off_arc
from robot_calib.core.notes import InputNotes
from robot_calib.core.odometry_twist import TwistFrame, TwistOnly
from robot_calib.core.zero_gyro import READINGS, SPAN, ZeroGyro
from robot_calib.methods.odometry_fusion.common import (
    FusionOutput, FusionResult, lidar_accuracy, LidarOdomSample, Rejected, wheel_twist)
from robot_calib.methods.odometry_fusion.frontend import ImuFrontEnd
from robot_calib.methods.odometry_fusion.params import FusionParams

Log = Callable[[str, str], None]
"""A logger: (level 'info' or 'warn', message)."""


class FusionFilter(abc.ABC):
    """Common bookkeeping of both filters (Estimator API, counters, warnings, lidar check)."""

    mode = ''
    """The variant's name (``params.mode``)."""

    def __init__(self, params: Optional[FusionParams] = None, log: Optional[Log] = None):
        """Create the filter with ``params`` (defaults when None); ``log`` hears its warnings."""
        self.params = params if params is not None else FusionParams()
        self.p = self.params
        self._log = log
        self._mountings: list[T.StaticTransform] = []
        self._imu_frame: Optional[str] = None
        self.input_notes = InputNotes()
        """Standing warnings about the inputs (a frame not in the tree, twist-only odometry)."""
        self._start()

    def _start(self) -> None:
        """Set the state of a filter that has seen no sample (variants extend it)."""
        self.front = ImuFrontEnd(self.p)
        self._tf_rotation: Any = None  # the /tf_static mounting in use (w, x, y, z)
        self._for_status = False  # set by result(): whether it serves a periodic status
        self.t: Optional[float] = None
        self.counts: dict[str, int] = {}
        self.events: list[tuple[float, str]] = []
        self.path_length = 0.0
        self.last_imu_t: Optional[float] = None
        self.imu_run_start = -math.inf
        """Stamp (s) of the first IMU sample after the IMU's last silence (or ever)."""
        self.last_odom_t: Optional[float] = None
        self.initialised = False
        self._odom_last: Optional[T.OdomSample] = None
        self.twist_frame = TwistFrame()
        self.twist_only = TwistOnly()
        """Tells an odometry that fills only its twist (the filter uses the twist anyway)."""
        self.input_notes.say('odom', '')
        self.wheel_turn = 0.0
        """The wheels' last yaw rate (rad/s), as measured."""
        self.zero_gyro = ZeroGyro()
        """Whether the IMU gives no angular velocity (all zeros while the wheels turn)."""
        self.odom_lateral = 0.0
        """The sideways speed (m/s) of the last odometry used (a holonomic robot's; else 0)."""
        self._joints_last: Optional[T.JointStateSample] = None
        self.lidar_distance = 0.0
        self._lidar_last: Optional[T.OdomSample] = None
        self._fused_at_lidar_start: Optional[float] = None

    # -- Estimator API ---------------------------------------------------------------------
    def set_mounting(self, transform: T.StaticTransform) -> None:
        """Take a static transform; a chain base_frame -> IMU frame sets the IMU mounting."""
        self._apply_mounting(transform, announce=True)

    def update(self, sample: Any) -> Union[FusionOutput, Rejected, None]:
        """
        Process one time-ordered sample; return an estimate, a rejection or None.

        ``ImuSample`` drives the prediction (an estimate comes back only while the
        odometry is silent for longer than ``sensor_timeout``: IMU dead
        reckoning); ``OdomSample`` and ``JointStateSample`` are the wheel
        observation (an estimate comes back when used); ``LidarOdomSample`` feeds
        the seed's distance check (None).
        """
        if isinstance(sample, T.ImuSample):
            return self._update_imu(sample)
        if isinstance(sample, T.OdomSample):
            reason = self._odom_sample(sample)
        elif isinstance(sample, T.JointStateSample):
            reason = self._joint_sample(sample)
        elif isinstance(sample, LidarOdomSample):
            self._lidar_sample(sample.odom)
            return None
        else:
            raise TypeError(f'odometry fusion takes no {type(sample).__name__}')
        return Rejected(reason) if reason is not None else self._output()

    def result(self, for_status: bool = False) -> FusionResult:
        """
        Return the estimates, counters and warnings so far (covariance: as last propagated).

        ``for_status``: for a periodic status, where a calibration over the recording
        may be the one last refitted (the improved filter's yaw-rate fit, at each block).
        """
        self._for_status = for_status
        acc, valid = self._lidar_check()
        rot = self.front.rot
        return FusionResult(
            mode=self.mode, t=self.t, state=np.array(self.x, dtype=float),
            covariance=self.P.copy(),
            estimates=self._estimates(), imu_extrinsic=self.front.rot_source,
            imu_rotation=None if rot is None else rot.copy(),
            imu_forward_known=self.front.forward_known, accel_units=self.front.units_source,
            counts=dict(self.counts), warnings=tuple(self.events),
            path_length=self.path_length, lidar_accuracy=acc, lidar_valid=valid,
            **self._variant_result())

    @property
    def imu_frame(self) -> Optional[str]:
        """Return the IMU messages' frame (None before the first one)."""
        return self._imu_frame

    def reset(self) -> None:
        """Forget the state; keep the parameters and the mountings."""
        mountings, self._mountings = self._mountings, []
        self._start()
        for transform in mountings:
            self._apply_mounting(transform, announce=False)

    # -- bookkeeping -----------------------------------------------------------------------
    def count(self, key: str, n: int = 1) -> None:
        """Increase counter ``key`` by ``n``."""
        self.counts[key] = self.counts.get(key, 0) + n

    def warn(self, t: float, message: str) -> None:
        """Record a warning event at time ``t`` (s) and log it."""
        self.events.append((t, message))
        if len(self.events) > 1000:
            del self.events[:500]
        if self._log is not None:
            self._log('warn', message)

    def _apply_mounting(self, transform: T.StaticTransform, announce: bool) -> None:
        """Use the static transform chain base_frame -> IMU frame as the IMU mounting."""
        self._mountings.append(transform)
        self._find_mounting(announce)

    def _find_mounting(self, announce: bool) -> None:
        """
        Set the IMU mounting from the transforms kept.

        Before the IMU's own frame is known, the first sensor frame named like
        'imu'; then the IMU's frame by the rule of every node
        (:func:`robot_calib.core.frames.find_mounting`), which also takes back
        that first guess when it does not hold.
        """
        if self.p.imu_extrinsic not in ('auto', 'tf'):
            return
        tree = StaticTree()
        for tf in self._mountings:
            tree.add(tf)
        base = self.p.base_frame
        if self._imu_frame is None:
            frame = next(
                (f for f in tree.leaves() if 'imu' in f.lower() and tree.mounting(f, base)), None)
            mounting = tree.mounting(frame, base) if frame else None
        else:
            fallback = ('the IMU unused until one is known (imu_extrinsic tf)'
                        if self.p.imu_extrinsic == 'tf' else
                        'the up axis taken from gravity at start (the forward axis unknown: '
                        'the accelerometer unused)')
            found = find_mounting(tree, self._imu_frame, base, 'imu', fallback)
            self.input_notes.say('imu', found.note)
            frame, mounting = found.frame, found.transform
            if mounting is None and self.front.rot_source == 'tf':
                self.front.rot, self.front.rot_source = None, 'none'   # the guess did not hold
                self.front.forward_known = False
        if mounting is None:
            return
        if self.front.rot_source == 'tf' and same_rotation(mounting.rotation, self._tf_rotation):
            return  # the mounting in use, sent again: nothing to apply, nothing to say
        self._tf_rotation = mounting.rotation
        self.front.set_rotation(rotation_matrix(mounting), 'tf')
        if announce and self._log is not None:
            self._log('info', f'IMU extrinsic from /tf_static ({base} -> {frame})')

    # -- input adapters --------------------------------------------------------------------
    def _update_imu(self, s: T.ImuSample) -> Optional[Union[FusionOutput, Rejected]]:
        """Feed one IMU sample; an estimate while the odometry is silent, else None."""
        if self._imu_frame is None:
            # the IMU's frame is known now: a mounting may be found that was not before
            self._imu_frame = s.frame_id.lstrip('/')
            if self._mountings:
                self._find_mounting(announce=False)
        reason = self._imu_sample(s)
        if reason == 'initialising':
            return None
        if reason is not None:
            return Rejected(reason)
        if self.last_odom_t is not None and s.t - self.last_odom_t > self.p.sensor_timeout:
            return self._output()
        return None

    def _imu_invalid(self, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
                     t: float) -> Optional[str]:
        """Return why an IMU reading cannot be used (non-finite, out of range), or None."""
        p = self.p
        if not math.isfinite(gx + gy + gz + ax + ay + az + t):
            return 'non_finite'
        if max(abs(gx), abs(gy), abs(gz)) > p.max_gyro:
            return 'gyro_out_of_range'
        if math.sqrt(ax * ax + ay * ay + az * az) * (self.front.accel_scale or 1.0) > p.max_accel:
            return 'accel_out_of_range'
        return None

    def _imu_sample(self, s: T.ImuSample) -> Optional[str]:
        """Check one IMU sample and use it; return a rejection reason or None when used."""
        gx, gy, gz = np.asarray(s.gyro, dtype=float).tolist()
        ax, ay, az = np.asarray(s.accel, dtype=float).tolist()
        t = s.t
        p = self.p
        front = self.front
        reason = self._imu_invalid(gx, gy, gz, ax, ay, az, t)
        if reason is not None:
            return reason
        if gx == 0.0 and gy == 0.0 and gz == 0.0:
            if self._gyro_absent(t):
                return 'no_angular_velocity'
        elif self.zero_gyro.reading():  # it was missing until now
            self.warn(t, 'IMU angular velocity reads again: the gyro is used')
        last = self.last_imu_t
        if last is not None and t <= last:
            return 'out_of_order'
        silent = last is None or t - last > p.sensor_timeout
        if silent:
            self.imu_run_start = t
        conv = front.convert(s, (gx, gy, gz), (ax, ay, az))
        while front.warnings:
            self.warn(t, front.warnings.pop(0))
        self.last_imu_t = t
        if conv is None:
            return 'initialising'
        if silent and last is not None:
            self.count('imu_gaps')
            self.warn(t, f'IMU silent for {t - last:.2f} s; resumed')
        return self._imu_step(t, *conv)

    def _gyro_absent(self, t: float) -> bool:
        """
        Return True when an all-zero gyro reading means the driver gives no angular velocity.

        (:mod:`robot_calib.core.zero_gyro`.) The filter then runs on the wheels,
        as with a silent IMU, until the gyro reads again.
        """
        was = self.zero_gyro.missing
        if not self.zero_gyro.zero(t, self.wheel_turn):
            return False
        if not was:
            self.last_imu_t = None  # stale from now on: the wheels carry the heading
            self._on_gyro_missing(t)
            self.count('gyro_missing_periods')
            self.warn(t, f'IMU angular velocity exactly 0 on every axis in {READINGS} or '
                      f'more readings over {SPAN} s while the wheels turn (the driver fills '
                      'none?): the gyro is not used until it reads again; wheel odometry only')
        return True

    def _on_gyro_missing(self, t: float) -> None:
        """Forget what the all-zero gyro taught the filter (variants extend it)."""

    def _odom_sample(self, s: T.OdomSample) -> Optional[str]:
        """Check one wheel-odometry message and use it; return a rejection reason or None."""
        vals = (s.t, s.x, s.y, s.yaw, s.vx, s.vy, s.wz)
        if not all(math.isfinite(v) for v in vals):
            return 'non_finite'
        last = self._odom_last
        if last is not None and s.t <= last.t:
            return 'out_of_order'
        rotated = self.twist_frame.in_odom_frame
        v, lateral = self.twist_frame.body_twist(s)
        w = s.wz
        if self.twist_frame.in_odom_frame:
            self.count('odometry_twist_rotated')
            if not rotated:
                self.warn(s.t, 'the odometry twist is in the odometry frame, not in '
                               'child_frame_id as nav_msgs/Odometry specifies (its poses say '
                               f'so in {self.twist_frame.votes_odom} intervals): rotated into '
                               'base_link by the odometry yaw from now on')
        self._odom_last = s
        if not self.twist_only.settled:
            self.twist_only.sample(s)
            if self.twist_only.twist_only:
                self.input_notes.say('odom', 'odometry fills only its twist (pose all zero while '
                                             'the twist moves): fused from the twist, as always')
        if last is not None:
            dt = s.t - last.t
            c, sn = math.cos(last.yaw), math.sin(last.yaw)
            dx, dy = s.x - last.x, s.y - last.y
            fwd = c * dx + sn * dy
            dyaw = wrap_scalar(s.yaw - last.yaw)
            moved = math.hypot(dx, dy)
            twist_zero = s.vx == 0.0 and s.vy == 0.0 and s.wz == 0.0 and last.vx == 0.0 \
                and last.vy == 0.0 and last.wz == 0.0
            expect = max(math.hypot(s.vx, s.vy), math.hypot(last.vx, last.vy)) * dt
            jump_limit = self.p.max_speed * dt + self.p.reset_jump
            if moved > expect + self.p.reset_jump and (not twist_zero or moved > jump_limit):
                self.count('odom_resets')
                self.warn(s.t, f'odometry pose jumped {moved:.2f} m: reset taken, '
                          'using increments after it')
                if twist_zero:
                    return 'odom_reset'
            elif twist_zero and (moved > 1e-6 or abs(dyaw) > 1e-6) and dt > 0:
                # a driver that fills only the pose: velocity from pose increments
                v, w = fwd / dt, dyaw / dt
                lateral = off_arc(fwd, c * dy - sn * dx, dyaw) / dt
        else:
            self._init_pose(s)
        if max(abs(v), abs(lateral)) > 3.0 * self.p.max_speed:
            return 'speed_out_of_range'
        self.odom_lateral = lateral
        self.wheel_turn = w
        if lateral:
            self.count('odometry_sideways')  # a holonomic robot's: used as an input
        return self._wheel_step(s.t, v, w)

    def _joint_sample(self, s: T.JointStateSample) -> Optional[str]:
        """Check one joint-state message and use it; return a rejection reason or None."""
        tw = wheel_twist(self.p, s, self._joints_last)
        last = self._joints_last
        self._joints_last = s
        if last is not None and s.t <= last.t:
            return 'out_of_order'
        if tw is None:
            return 'missing_wheel_joints'
        if last is None and self.t is None:
            self._init_pose(None)
        v, w = tw
        if not (math.isfinite(v) and math.isfinite(w)):
            return 'non_finite'
        if abs(v) > 3.0 * self.p.max_speed:
            return 'speed_out_of_range'
        self.wheel_turn = w
        return self._wheel_step(s.t, v, w)

    def _lidar_sample(self, s: T.OdomSample) -> None:
        """Feed a lidar odometry pose (m) for the seed's distance accuracy check."""
        if not all(math.isfinite(v) for v in (s.t, s.x, s.y)):
            return
        if self._lidar_last is None:
            self._fused_at_lidar_start = self.path_length
        else:
            self.lidar_distance += math.hypot(s.x - self._lidar_last.x, s.y - self._lidar_last.y)
        self._lidar_last = s

    def _lidar_check(self) -> tuple[float, bool]:
        """Return the seed's (accuracy, valid) of fused vs lidar distance since the first scan."""
        if self._fused_at_lidar_start is None:
            return float('nan'), False
        return lidar_accuracy(self.path_length - self._fused_at_lidar_start, self.lidar_distance)

    # -- to override -----------------------------------------------------------------------
    @abc.abstractmethod
    def _init_pose(self, s: Optional[T.OdomSample]) -> None:
        """Start at the first odometry pose ``s`` (or 0) when ``initial_pose_from_odom``."""

    @abc.abstractmethod
    def _imu_step(self, t: float, gz: float, ax: float, use_acc: bool) -> Optional[str]:
        """Use gyro z (rad/s) and forward specific force (m/s^2); return a rejection or None."""

    @abc.abstractmethod
    def _wheel_step(self, t: float, v: float, w: float) -> Optional[str]:
        """Use the wheel speed (m/s) and yaw rate (rad/s); return a rejection or None."""

    @abc.abstractmethod
    def _output(self) -> Optional[FusionOutput]:
        """Return the current estimate, or None before initialisation."""

    @abc.abstractmethod
    def _estimates(self) -> dict:
        """Return the named estimates of :attr:`FusionResult.estimates`."""

    def _variant_result(self) -> dict:
        """Return the variant's own fields of :class:`FusionResult`."""
        return {}
