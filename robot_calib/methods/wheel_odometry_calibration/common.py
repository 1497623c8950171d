# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What both variants of ``wheel_odometry_calibration`` share: the result dataclasses.

:class:`CalibResult` is one calibration (estimates, standard deviations, a
verdict), as the solvers return it; :class:`WheelCalibResult` adds what a
streaming estimator knows about the drive so far (its ``result()``);
:class:`WheelUpdate` is what one sample produced (its ``update()``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
import math
from typing import Any, Optional

from robot_calib.methods.wheel_odometry_calibration.params import keys_of


@dataclass(frozen=True)
class CalibResult:
    """A calibration result: estimates, standard deviations, segments used and a verdict."""

    drive_type: str
    values: dict
    stds: dict
    segments_used: int
    verdict: str
    details: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        """Return True when the verdict is 'converged'."""
        return self.verdict == 'converged'

    def to_dict(self) -> dict[str, Any]:
        """Return the flat result mapping of the contract, in contract order (SI units)."""
        out: dict[str, Any] = {'drive_type': self.drive_type}
        for key in keys_of(self.drive_type):
            out[key] = float(self.values.get(key, math.nan))
            out[key + '_std'] = float(self.stds.get(key, math.nan))
        out['segments_used'] = int(self.segments_used)
        out['verdict'] = self.verdict
        return out

    def to_yaml(self) -> str:
        """Return the result as the contract's flat YAML text, with a commented header."""
        lines = ['# wheel_odometry_calibration result (SI units: m, rad); each estimate has a',
                 '# _std twin (one standard deviation, .nan = not estimated by this mode).',
                 '# steering_offset: true wheel angle = steering_scale * reading + offset,',
                 '# counter-clockwise positive seen from above.']
        for key, value in self.to_dict().items():
            if isinstance(value, float):
                text = '.nan' if math.isnan(value) else repr(value)
            elif isinstance(value, int):
                text = str(value)
            else:
                text = _yaml_str(str(value))
            lines.append(f'{key}: {text}')
        return '\n'.join(lines) + '\n'


def _yaml_str(text: str) -> str:
    """Quote a YAML string value safely (single quotes, doubled inside)."""
    return "'" + text.replace("'", "''") + "'"


@dataclass(frozen=True)
class WheelCalibResult(CalibResult):
    """
    A streaming estimator's result: the calibration and what the drive gave so far.

    ``final`` is True for the result of all the data (the last stage closed,
    key frames deskewed again with the estimate). ``nominal_lidar_pose`` is the
    lidar pose (x m, y m, yaw rad) the key frames were deskewed and guessed
    with (the mounting from ``set_mounting``, else the parameters).
    ``counts`` are the front end's counters (wheel samples, scans, matches,
    stages...), ``segments`` the segments cut so far, ``seed_counter`` the
    seed's consecutive-stage counter (steered drive wheel, else None).
    """

    final: bool = False
    drive_source: str = 'undecided'
    drive_joints: tuple = ()
    nominal_lidar_pose: tuple = (math.nan, math.nan, math.nan)
    segments: int = 0
    counts: dict = field(default_factory=dict)
    seed_counter: Optional[int] = None

    @classmethod
    def of(cls, calib: CalibResult, **extra: Any) -> 'WheelCalibResult':
        """Return ``calib`` with the streaming fields ``extra``."""
        return cls(**{f.name: getattr(calib, f.name) for f in fields(CalibResult)}, **extra)


@dataclass(frozen=True)
class WheelUpdate:
    """
    What one sample produced (returned by ``update`` when there is something).

    ``rejected`` says why the sample was not used ('' when it was);
    ``notes`` are (level, message) pairs worth logging ('info', 'warn');
    ``status`` is the result, every ``update_period`` of data time.
    """

    rejected: str = ''
    notes: tuple = ()
    status: Optional[WheelCalibResult] = None
