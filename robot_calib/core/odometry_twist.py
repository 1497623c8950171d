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

An odometry that fills only its twist (pose and quaternion all zero) is told
and given the poses its twist integrates to by :class:`TwistOnly`, the same in
every node that reads odometry poses.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

from robot_calib.core.kinematics import arc_pose_scalar

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


TWIST_ONLY_SAMPLES = 5
"""Moving samples in a row with the pose exactly zero that mean the pose is not filled..."""

TWIST_ONLY_MOTION = 0.05
"""...while their twist, integrated, moved at least this far (m) or turned this much (rad)."""

TWIST_MOVING = 0.01
"""A sample moves when its speed exceeds this (m/s) or its yaw rate this (rad/s)."""

TWIST_MAX_DT = 1.0
"""Longest interval (s) integrated between two odometry samples (a longer one is a gap)."""


class TwistOnly:
    """
    Tells an odometry that fills only its twist and gives it the poses the twist integrates to.

    Some drivers publish ``nav_msgs/Odometry`` with the twist alone: the pose
    and its quaternion stay all zero (or identity). Fusion uses the twist and
    is not misled; a method that reads the poses would see a robot standing
    still at the origin. The twist (base_link, ``child_frame_id`` as specified)
    is integrated from the first sample on, arc by arc (trapezoid of the speeds,
    no integration across a gap longer than :data:`TWIST_MAX_DT`). Once
    :data:`TWIST_ONLY_SAMPLES` moving samples (beyond :data:`TWIST_MOVING`) kept
    the pose exactly zero while the twist moved :data:`TWIST_ONLY_MOTION`, with no
    sample of an exactly zero twist between them, the odometry is taken
    as twist-only for good and :meth:`sample` returns it with the integrated
    pose (the motion before the decision included). A pose that is not exactly
    zero once settles it the other way: samples then pass unchanged, so an
    odometry that fills its pose costs one comparison per sample.
    """

    def __init__(self) -> None:
        """Start undecided."""
        self.twist_only = False
        """True once the odometry is known to fill only its twist."""
        self.settled = False
        """True once decided (either way)."""
        self.detected_t: Optional[float] = None
        """Time (s) of the sample that decided twist-only."""
        self.gaps = 0
        """Intervals longer than :data:`TWIST_MAX_DT` not integrated."""
        self._pose = (0.0, 0.0, 0.0)
        self._last: Any = None
        self._run = 0
        self._moved = 0.0
        self._turned = 0.0

    def sample(self, s: Any) -> Any:
        """Return odometry sample ``s``, with the integrated pose once it is twist-only."""
        if self.settled and not self.twist_only:
            return s
        last, self._last = self._last, s
        if last is not None:
            self._integrate(last, s)
        if not self.settled:
            if s.x != 0.0 or s.y != 0.0 or s.yaw != 0.0:
                self.settled = True
                self._last = None
                return s
            if s.vx == 0.0 and s.vy == 0.0 and s.wz == 0.0:
                self._run, self._moved, self._turned = 0, 0.0, 0.0
                return s
            if math.hypot(s.vx, s.vy) <= TWIST_MOVING and abs(s.wz) <= TWIST_MOVING:
                return s     # a twist this small may be a driver's noise at rest
            self._run += 1
            if self._run < TWIST_ONLY_SAMPLES or max(self._moved, self._turned) \
                    < TWIST_ONLY_MOTION:
                return s
            self.twist_only = self.settled = True
            self.detected_t = s.t
        x, y, yaw = self._pose
        return dataclasses.replace(s, x=x, y=y, yaw=yaw, orientation_norm=1.0)

    def _integrate(self, a: Any, b: Any) -> None:
        """Add the arc the twist of samples ``a`` and ``b`` drove between them."""
        dt = b.t - a.t
        if not 0.0 < dt <= TWIST_MAX_DT:
            if dt > 0.0:
                self.gaps += 1
            return
        ds = 0.5 * (a.vx + b.vx) * dt
        dl = 0.5 * (a.vy + b.vy) * dt
        dth = 0.5 * (a.wz + b.wz) * dt
        fx, fy, _ = arc_pose_scalar(ds, dth)
        half = 0.5 * dth
        fx -= math.sin(half) * dl
        fy += math.cos(half) * dl
        x, y, yaw = self._pose
        c, sn = math.cos(yaw), math.sin(yaw)
        self._pose = (x + c * fx - sn * fy, y + sn * fx + c * fy,
                      math.remainder(yaw + dth, math.tau))
        if self._run:
            self._moved += math.hypot(fx, fy)
            self._turned += abs(dth)

    def note(self) -> str:
        """Return what a summary says of it ('' unless twist-only)."""
        if not self.twist_only:
            return ''
        return (f'odometry fills only its twist (pose all zero while the twist moves, decided at '
                f't = {self.detected_t:.3f} s): poses integrated from the twist')
