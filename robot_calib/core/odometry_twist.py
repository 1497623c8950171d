# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Which frame a wheel odometry's twist is in, told from the odometry's own poses.

``nav_msgs/Odometry`` specifies the twist in ``child_frame_id`` (base_link).
Several drivers and simulator plugins fill it in the odometry frame instead
(gazebo_ros_diff_drive in its encoder mode, gazebo_ros_p3d, segway_rmp: each a
reported issue of its project). Read as base_link, such a twist turns a
forward drive into a sideways one as the heading turns. The poses tell which
frame it is: over an interval the pose moves ``(dx, dy)`` in the odometry
frame, which is ``R(-yaw_mid) (dx, dy)`` in base_link (``yaw_mid`` the
heading halfway through). Each moving interval in which the two readings
differ by more than ``SEPARATION`` of the speed (the heading more than about
17 deg from the frame's x axis) votes for the frame whose velocity the twist
is clearly nearer; once ``MIN_VOTES`` votes say the odometry frame, ``RATIO``
times as many as say base_link, the twist is rotated into base_link by the
odometry's yaw from then on.
"""

from __future__ import annotations

import math
from typing import Any

SEPARATION = 0.3
"""Least difference of the two readings, relative to the speed, for an interval to vote (-)."""

CLEARLY = 0.5
"""A vote goes to a frame whose velocity error is below this share of the other's (-)."""

MIN_SPEED = 0.05
"""Least speed (m/s) of an interval that votes."""

MIN_VOTES = 10
"""Votes for the odometry frame before the twist is taken as in it."""

RATIO = 4
"""...and at least this many times the votes for base_link."""

SETTLED = 100
"""Votes for base_link after which voting stops while the odometry frame has too few to win."""


class TwistFrame:
    """Votes on the frame of an odometry's twist and returns it in base_link (see module)."""

    def __init__(self) -> None:
        """Start undecided: the twist is taken as base_link until the poses say otherwise."""
        self.votes_base = 0
        self.votes_odom = 0
        self.in_odom_frame = False
        self.settled = False
        """True once the frame is decided (either way): no more votes are taken."""
        self._last: Any = None

    def body_twist(self, s: Any) -> tuple[float, float]:
        """Return the linear twist (m/s, base_link x and y) of odometry sample ``s``."""
        last, self._last = self._last, s
        if last is not None and not self.settled:
            self._vote(last, s)
        if self.in_odom_frame:
            c, sn = math.cos(s.yaw), math.sin(s.yaw)
            return c * s.vx + sn * s.vy, c * s.vy - sn * s.vx
        return s.vx, s.vy

    def _vote(self, a: Any, b: Any) -> None:
        """Compare the interval from sample ``a`` to ``b`` with its twist under both frames."""
        dt = b.t - a.t
        if not 0.0 < dt <= 1.0:
            return
        vx, vy = 0.5 * (a.vx + b.vx), 0.5 * (a.vy + b.vy)
        wx, wy = (b.x - a.x) / dt, (b.y - a.y) / dt
        speed = math.hypot(wx, wy)
        if not (speed > MIN_SPEED and math.hypot(vx, vy) > MIN_SPEED):
            return
        dyaw = math.remainder(b.yaw - a.yaw, math.tau)
        mid = a.yaw + 0.5 * dyaw
        c, sn = math.cos(mid), math.sin(mid)
        bx, by = c * wx + sn * wy, c * wy - sn * wx
        if math.hypot(bx - wx, by - wy) < SEPARATION * speed:
            return
        err_base = math.hypot(vx - bx, vy - by)
        err_odom = math.hypot(vx - wx, vy - wy)
        if err_odom < CLEARLY * err_base:
            self.votes_odom += 1
        elif err_base < CLEARLY * err_odom:
            self.votes_base += 1
        if self.votes_odom >= MIN_VOTES and self.votes_odom >= RATIO * self.votes_base:
            self.in_odom_frame = self.settled = True
        elif self.votes_base >= SETTLED and self.votes_odom * RATIO < self.votes_base:
            self.settled = True
