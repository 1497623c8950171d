# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A gyro that reads exactly 0 while the wheels turn: a driver that fills no angular velocity.

A real gyro reads exactly 0 only inside a driver's deadband, at rest; an IMU
that publishes its orientation alone leaves the angular velocity at 0 all the
time. :class:`ZeroGyro` counts zero readings only while the wheels turn faster
than :data:`TURN`; after :data:`READINGS` of them in a row spanning at least
:data:`SPAN` (wheel odometry a few tenths of a second late still turns after
the robot stopped in a deadband) the gyro counts as missing until it reads
again. Fusion, loop closure and the gyro line then take the heading from the
wheels, as with no IMU, and add the turn the zeros hid since the wheels began to
turn under them (:attr:`ZeroGyro.hidden_turn`).
"""

from typing import Optional

TURN = 0.05
"""Wheel yaw rate (rad/s) beyond which a zero gyro reading counts."""

READINGS = 20
"""Zero readings in a row, while the wheels turn, after which the gyro is missing..."""

SPAN = 0.5
"""...when they span at least this long (s)."""


class ZeroGyro:
    """Counts zero gyro readings while the wheels turn (see the module)."""

    def __init__(self) -> None:
        """Start with the gyro present."""
        self.missing = False
        self._run = 0
        self._last_t: Optional[float] = None
        self.since: Optional[float] = None
        """Time (s) of the first zero reading while the wheels turned (None after a reading)."""
        self.hidden_turn = 0.0
        """The wheels' turn (rad) from then on, which the zeros hid."""

    def zero(self, t: float, wheel_turn: float) -> bool:
        """
        Take a reading of exactly 0 at ``t`` (s) while the wheels turn at ``wheel_turn`` (rad/s).

        Return True when the gyro is missing: since an earlier reading, or from this
        one (then :attr:`missing` just turned True).
        """
        if self.missing:
            return True
        if self._run and 0.0 < t - self._last_t <= SPAN:
            self.hidden_turn += wheel_turn * (t - self._last_t)
        self._last_t = t
        if abs(wheel_turn) <= TURN:
            return False
        if not self._run:
            self.since = t
        self._run += 1
        self.missing = self._run >= READINGS and t - self.since >= SPAN
        return self.missing

    def reading(self) -> bool:
        """Take a non-zero reading; return True when the gyro was missing until now."""
        was = self.missing
        self._run = 0
        self.since = None
        self.hidden_turn = 0.0
        self.missing = False
        return was
