# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Seed 003 on straight stages (steered drive wheel): the offset gate and the stage counter.

Per stage the scene rotation (scan match of the stage's first and last scan)
equals the odometry rotation, which gives the stage's steering zero offset;
the stage's offset is compared with the compensation the stage was driven
(or, offline, integrated) with; when the difference is below
``seed.offset_threshold`` the stage's (scene displacement, odometry
displacement) is cached and a counter incremented, else both are cleared;
every stage uses the previous stage's solved offset as its compensation; when
the counter reaches ``seed.consecutive_stages`` the compensation in effect is
the calibrated offset, and the wheel radius is the average over the cached
stages of the radius solving ``R_ext * scene_displacement =
odometry_displacement``. The text is silent on what "the offset is below a
threshold" compares; here it is the stage's offset minus the compensation it
used (the part of the offset the stage still sees), which is what makes the
iteration converge.

Shared by both variants: the seed variant's estimate of a steered drive wheel,
and the seed's progress (counter, stages needed) the improved variant reports
beside its own estimate.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import math
from typing import Iterable, Optional

import numpy as np
from robot_calib.core import kinematics as K
from robot_calib.core.kinematics import Segment
from robot_calib.methods.wheel_odometry_calibration.common import CalibResult
from robot_calib.methods.wheel_odometry_calibration.params import STEER_KEYS, WheelCalibParams


@dataclass
class StageRecord:
    """What the seed logic did with one stage."""

    index: int
    compensation: float
    offset: float
    residual: float
    accepted: bool
    counter: int
    radius: float
    t1: float = math.nan


class SeedSteeredCalibrator:
    """
    Seed 003 (steered drive wheel): stage-by-stage zero offset, then the wheel radius.

    Feed straight stages with :meth:`update` (streaming) or all at once with
    :meth:`run`. The wheel base and steering scale are taken as nominal (the
    seed does not estimate them); the extrinsic ``R_ext`` is the nominal lidar
    yaw.
    """

    def __init__(self, params: Optional[WheelCalibParams] = None):
        """Start with the nominal offset as the first compensation."""
        self.params = params or WheelCalibParams(drive_type='steered_wheel', mode='seed')
        self.compensation = self.params.steering_offset
        self.counter = 0
        self.candidates: list[tuple[np.ndarray, np.ndarray]] = []
        self.records: list[StageRecord] = []
        self.offset: Optional[float] = None
        self.radius: Optional[float] = None
        self.stages_needed: Optional[int] = None
        self._final: tuple = ([], [])

    def stage_offset(self, seg: Segment) -> float:
        """
        Solve "scene rotation = odometry rotation" for the stage's zero offset (rad).

        ``sum_j r dphi_j sin(scale reading_j + c) / L = scene_rotation``
        (kinematics of :mod:`robot_calib.core.kinematics`) solved for ``c`` by
        Newton's method from the constant-reading closed form.
        """
        p = self.params
        dphi, reading = seg.steps[:, 0], seg.steps[:, 1]
        travel = p.wheel_radius * float(np.sum(dphi))
        scene = float(seg.sensor_motion[2])
        if abs(travel) < 1e-9:
            return math.nan
        s = np.clip(p.wheel_base * scene / travel, -1.0, 1.0)
        mean_reading = float(np.sum(dphi * reading) / np.sum(dphi))
        c = math.asin(s) - p.steering_scale * mean_reading  # seed 003: scene = odometry rotation
        for _ in range(20):
            ang = p.steering_scale * reading + c
            f = p.wheel_radius * np.sum(dphi * np.sin(ang)) / p.wheel_base - scene
            df = p.wheel_radius * np.sum(dphi * np.cos(ang)) / p.wheel_base
            if abs(df) < 1e-12:
                break
            step = f / df
            c -= step
            if abs(step) < 1e-12:
                break
        return float(c)

    def update(self, seg: Segment) -> StageRecord:
        """Process one straight stage; return what the gate and counter did."""
        p = self.params
        comp = self.compensation
        off = self.stage_offset(seg)
        resid = off - comp if math.isfinite(off) else math.inf
        accepted = abs(resid) < p.seed.offset_threshold
        radius = math.nan
        if accepted:
            d_odo = K.integrate_steps(
                K.arc_pose(*K.steered_arc(seg.steps[None, :, 0], seg.steps[None, :, 1],
                                          p.wheel_radius, p.wheel_base, comp,
                                          p.steering_scale)))[0] / p.wheel_radius
            c, s = math.cos(p.lidar_yaw), math.sin(p.lidar_yaw)
            d_scene = np.array([c * seg.sensor_motion[0] - s * seg.sensor_motion[1],
                                s * seg.sensor_motion[0] + c * seg.sensor_motion[1]])
            self.candidates.append((d_scene, d_odo[:2]))
            self.counter += 1
            # seed 003: R_ext * scene_displacement = odometry_displacement (radius r)
            g = d_odo[:2]
            radius = float(d_scene @ g / max(g @ g, 1e-12))
        else:
            self.candidates.clear()
            self.counter = 0
        rec = StageRecord(len(self.records), comp, off, resid, accepted, self.counter, radius,
                          float(seg.t1))
        self.records.append(rec)
        if self.offset is None and self.counter >= p.seed.consecutive_stages:
            self.offset = comp
            radii = [float(ds @ g / max(g @ g, 1e-12)) for ds, g in self.candidates]
            self.radius = float(np.mean(radii))
            self.stages_needed = len(self.records)
            self._final = (radii, [r.offset for r in self.records[-len(radii):]])
        if math.isfinite(off):
            self.compensation = off  # next stage compensates with this stage's offset
        return rec

    def run(self, stages: Iterable[Segment]) -> CalibResult:
        """Process all stages (stops updating once converged) and return the result."""
        for seg in stages:
            if self.offset is not None:
                break
            self.update(seg)
        return self.result()

    def result(self, extra_problems: Iterable[str] = ()) -> CalibResult:
        """Return the seed result so far (nominal values where the seed has none)."""
        p = self.params
        nominal = p.nominal()
        values = {k: nominal[k] for k in STEER_KEYS}
        stds = {k: math.nan for k in STEER_KEYS}
        problems = list(extra_problems)
        if self.offset is not None:
            values['steering_offset'] = self.offset
            values['wheel_radius'] = self.radius
            radii, offs = self._final
            n = len(radii)
            if n > 1:
                stds['wheel_radius'] = float(np.std(radii, ddof=1) / math.sqrt(n))
                # the offset is one stage's solution (the compensation in effect): its
                # spread over the consistent stages, not divided by sqrt(n)
                stds['steering_offset'] = float(np.std(offs, ddof=1))
            verdict = 'converged' if not problems else '; '.join(problems)
        else:
            n_stages = len(self.records)
            if n_stages == 0:
                problems.append('drive more straight segments (no straight stage found)')
            else:
                problems.append(
                    f'drive more straight segments ({n_stages} stages, {self.counter} '
                    f'consecutive consistent, need {p.seed.consecutive_stages})')
            verdict = '; '.join(problems)
            verdict = verdict[0].upper() + verdict[1:]
        used = len(self._final[0]) if self.offset is not None else 0
        details = {'stages': [dataclasses.asdict(r) for r in self.records],
                   'stages_needed': self.stages_needed}
        return CalibResult('steered_wheel', values, stds, used, verdict, details)
