# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The streaming estimator both variants are: samples in, a status now and then, a result.

:class:`StreamingCalibrator` implements :class:`robot_calib.core.estimator.Estimator`
around the front end (:class:`~.segmenter.DriveSegmenter`): it takes the lidar
mounting from ``set_mounting``, feeds wheel data and scans, runs the seed's
stage gate (:mod:`.stages`) on the straight stages of a steered drive wheel,
and every ``update_period`` of data time returns a status with the estimate
(re-solved when the data grew by a quarter or 10 segments: O(log n) solves per
drive, together about four times the cost of the final one). ``result()`` solves
once more with all the data. A variant says only how it estimates
(:meth:`StreamingCalibrator._estimate`).
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, Callable, Optional

import numpy as np
from robot_calib.core import frames
from robot_calib.core import types as T
from robot_calib.core.notes import InputNotes
from robot_calib.core.odometry_twist import TwistOnly
from robot_calib.methods.wheel_odometry_calibration.common import (CalibResult,
                                                                   WheelCalibResult,
                                                                   WheelUpdate)
from robot_calib.methods.wheel_odometry_calibration.params import WheelCalibParams
from robot_calib.methods.wheel_odometry_calibration.segmenter import DriveSegmenter, MatchFn
from robot_calib.methods.wheel_odometry_calibration.stages import SeedSteeredCalibrator


ODOM_UNUSED = 'joint_states_preferred'
"""Why odometry samples are turned away while joint states drive the odometry."""
RESOLVE_GROWTH = 1.25
"""A streaming estimate is re-solved when the segments grew by this factor (or by 10)."""


class StreamingCalibrator(abc.ABC):
    """
    Calibrate wheel odometry (and the lidar pose) from a stream of wheel data and scans.

    :meth:`update` takes ``JointStateSample`` (preferred once the named joints
    appear), ``OdomSample`` and ``ScanSample``; it returns a
    :class:`~.common.WheelUpdate` when the sample was rejected, has something
    to log or brought a status (every ``update_period`` s of data time, unless
    ``periodic`` is False: batch use, where only :meth:`result` counts), else
    None. ``matcher``/``prepare`` replace the scan registration (tests);
    ``max_range`` (m) drops farther beams. :attr:`front` is the segmenting front
    end, :attr:`stage_gate` the seed's stage gate (steered drive wheel, else
    None).
    """

    def __init__(self, params: Optional[WheelCalibParams] = None,
                 matcher: Optional[MatchFn] = None,
                 prepare: Optional[Callable[[np.ndarray], Any]] = None,
                 max_range: float = 30.0, periodic: bool = True):
        """Create an empty estimator (parameters: defaults when None)."""
        self.params = params or WheelCalibParams()
        self.matcher, self.prepare, self.max_range = matcher, prepare, max_range
        self.periodic = periodic
        self._mountings = frames.StaticTree()
        self.input_notes = InputNotes()
        """Standing warnings about the inputs (a frame not in the tree, twist-only odometry)."""
        self.reset()

    def reset(self) -> None:
        """Forget the drive; keep the parameters and the mountings."""
        self.front = DriveSegmenter(self.params, self.matcher, self.prepare, self.max_range)
        self.stage_gate: Optional[SeedSteeredCalibrator] = None
        self._gate_epoch: Optional[int] = None
        self._sensor_frame: Optional[str] = None
        self._upside_down = False
        """The lidar is mounted upside down: its scans are mirrored."""
        self.twist_only = TwistOnly()
        """Tells an odometry that fills only its twist, and integrates its poses then."""
        self.input_notes.say('odom', '')
        self._notes: list[tuple[str, str]] = []
        self._told_problem = ''
        self._told_stride = 1
        self._last_update: Optional[float] = None
        self._n_solved = 0
        self._latest: Optional[CalibResult] = None
        self._final: Optional[tuple[int, WheelCalibResult]] = None
        self._version = 0
        self._sync_stages()

    # -- Estimator protocol ---------------------------------------------------------------
    def set_mounting(self, transform: T.StaticTransform) -> None:
        """
        Take a static transform; ``base_frame`` -> scan frame gives the nominal lidar pose.

        Through any chain of links. The pose is taken while no segment was cut yet
        (at the first scan, or when the transform comes later).
        """
        self._mountings.add(transform)
        self._version += 1
        if self._sensor_frame is not None:
            self._apply_mounting(self._sensor_frame)

    def update(self, sample: Any) -> Optional[WheelUpdate]:
        """Process one wheel or scan sample; return what it produced, or None."""
        if isinstance(sample, T.JointStateSample):
            rejected = self._joint_state(sample)
        elif isinstance(sample, T.OdomSample):
            if not self.twist_only.settled or self.twist_only.twist_only:
                sample = self._twist_only(sample)
            rejected = '' if self.front.add_odom(sample) else ODOM_UNUSED
        elif isinstance(sample, T.ScanSample):
            if self._sensor_frame is None:
                self._sensor_frame = sample.frame_id
                self._apply_mounting(sample.frame_id)
            self.front.add_scan(frames.mirrored(sample) if self._upside_down else sample)
            rejected = ''
        else:
            return None
        self._version += 1
        stride = self.front.stride
        if stride != self._told_stride:
            self._told_stride = stride
            if stride > 1:   # (a new drive type starts over at 1)
                self._notes.append(('info', f'{self.front.segments_cut} segments cut, more '
                                            f'than max_segments ({self.params.max_segments}):'
                                            f' keeping one in {stride}, spread over the drive'))
        self._sync_stages()
        status = None if rejected else self._tick(sample.t)
        if not (rejected or status is not None or self._notes):
            return None
        notes, self._notes = tuple(self._notes), []
        return WheelUpdate(rejected, notes, status)

    @property
    def lidar_frame(self) -> Optional[str]:
        """Return the frame of the scans (None before the first scan)."""
        return self._sensor_frame

    def odometry_refusal(self) -> str:
        """Return why odometry input is unused now (joint states drive the odometry), or ''."""
        return ODOM_UNUSED if self.front.uses_joints else ''

    def result(self) -> WheelCalibResult:
        """Return the result of all the data so far (the open stage closed, final solve)."""
        if self._final is None or self._final[0] != self._version:
            self._final = (self._version, self._stream_result(self._solve(final=True), True))
        return self._final[1]

    # -- internals ------------------------------------------------------------------------
    def _twist_only(self, sample: T.OdomSample) -> T.OdomSample:
        """Return an odometry sample with the poses its twist integrates to when twist-only."""
        was = self.twist_only.twist_only
        sample = self.twist_only.sample(sample)
        if self.twist_only.twist_only and not was:
            self.input_notes.say('odom', self.twist_only.note())
        return sample

    def _apply_mounting(self, frame: str) -> None:
        """Take the nominal lidar pose of scan frame ``frame`` from the tree (the one rule)."""
        if self.front.segments:
            return
        p = self.params
        found = frames.find_mounting(
            self._mountings, frame, p.base_frame, 'lidar', 'the nominal lidar pose parameters '
            f'used (lidar_x {p.lidar_x} m, lidar_y {p.lidar_y} m, lidar_yaw {p.lidar_yaw} rad)')
        self.input_notes.say('lidar', found.note)
        tf = found.transform
        if tf is None:
            return
        x, y, yaw = frames.planar_pose(tf)
        self.front.set_sensor_pose(x, y, yaw)
        self._upside_down = frames.upside_down(tf)
        self._notes.append(('info', f'lidar pose from /tf_static: x {x:.3f} m, y {y:.3f} m, '
                                    f'yaw {yaw:.4f} rad' + (', mounted upside down (scans '
                                                            'mirrored)' if self._upside_down
                                                            else '')))

    def _joint_state(self, js: T.JointStateSample) -> str:
        """Feed joint states; return '' when used, else why not; note the drive found."""
        front = self.front
        decided = front.drive_source
        used = front.add_joint_state(js)
        if front.drive_source != decided:
            self._notes.append(('info', f'drive type {front.drive} told by the '
                                        f'{front.drive_source} ({", ".join(front.drive_joints)})'))
        if front.drive_problem and front.drive_problem != self._told_problem:
            self._told_problem = front.drive_problem
            self._notes.append(('warn', front.drive_problem))
        return '' if used else 'missing_joints'

    def _tick(self, t: float) -> Optional[WheelCalibResult]:
        """Return a status every update_period (s) of data time, re-solved when data grew."""
        if not self.periodic:
            return None
        if self._last_update is None:
            self._last_update = t
        if t - self._last_update < self.params.update_period:
            return None
        self._last_update = t
        n = self.front.segments_cut + self.front.counts['stages']
        grown = max(self._n_solved * RESOLVE_GROWTH, self._n_solved + 10)
        if self._latest is None or n >= grown:
            self._n_solved = n
            self._latest = self._solve(final=False)
        return self._stream_result(self._latest, False)

    def _sync_stages(self) -> None:
        """Feed the stages the front end closed to the seed's gate (new gate for a new drive)."""
        front = self.front
        if self._gate_epoch != front.epoch:
            self._gate_epoch = front.epoch
            self.stage_gate = (SeedSteeredCalibrator(front.params)
                               if front.drive == 'steered_wheel' else None)
            self._on_restart()
        stages = front.take_stages()
        gate = self.stage_gate
        if gate is None:
            return
        if not gate.records:
            gate.params = front.params  # the nominal lidar pose until the first stage
        for stage in stages:
            gate.update(stage)

    def _on_restart(self) -> None:
        """React to a (re)start of the calibration (a new drive type): nothing by default."""

    def _solve(self, final: bool) -> CalibResult:
        """Return the variant's estimate from the data so far (``final``: all of it)."""
        if final:
            self.front.close_stage()
        self._sync_stages()
        res = self._estimate(final, self.front.problems())
        details = {**res.details, 'counts': dict(self.front.counts)}
        if self.stage_gate is not None:
            details['seed_stages_needed'] = self.stage_gate.stages_needed
        return dataclasses.replace(res, details=details)

    @abc.abstractmethod
    def _estimate(self, final: bool, problems: list[str]) -> CalibResult:
        """Return the variant's estimate; ``problems`` are what the input lacked."""

    def _stream_result(self, calib: CalibResult, final: bool) -> WheelCalibResult:
        front, gate = self.front, self.stage_gate
        return WheelCalibResult.of(
            calib, final=final, drive_source=front.drive_source,
            drive_joints=front.drive_joints,
            nominal_lidar_pose=tuple(float(v) for v in front.sensor_pose),
            segments=len(front.segments), counts=dict(front.counts),
            seed_counter=None if gate is None else gate.counter)
