# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A gyro that reads exactly 0 while the wheels turn: a driver that fills no angular velocity.

A real gyro reads exactly 0 only inside a driver's deadband, at rest; an IMU
that publishes its orientation alone leaves the angular velocity at 0 all the
time. :class:`ZeroGyro` counts zero readings only while the wheels turn faster
than :data:`TURN`; after :data:`READINGS` of them in a row the gyro counts as
missing until it reads again. Fusion and loop closure then take the heading
from the wheels, as with no IMU.
"""

TURN = 0.05
"""Wheel yaw rate (rad/s) beyond which a zero gyro reading counts."""

READINGS = 20
"""Zero readings in a row, while the wheels turn, after which the gyro is missing."""


class ZeroGyro:
    """Counts zero gyro readings while the wheels turn (see the module)."""

    def __init__(self) -> None:
        """Start with the gyro present."""
        self.missing = False
        self._run = 0

    def zero(self, wheel_turn: float) -> bool:
        """
        Take a reading of exactly 0 while the wheels turn at ``wheel_turn`` (rad/s).

        Return True when the gyro is missing: since an earlier reading, or from this
        one (then :attr:`missing` just turned True).
        """
        if self.missing:
            return True
        if abs(wheel_turn) <= TURN:
            return False
        self._run += 1
        self.missing = self._run >= READINGS
        return self.missing

    def reading(self) -> bool:
        """Take a non-zero reading; return True when the gyro was missing until now."""
        was = self.missing
        self._run = 0
        self.missing = False
        return was
