# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Late wheel odometry: use it at the time it describes, publish at its stamp.

Many drivers stamp the wheel odometry when they publish it, a filter or a
polling loop after the wheels turned (about 0.3 s on the robot_localization
Husky bag, found by the yaw-rate calibration of :mod:`.yaw_rate_fit`). A
filter that takes such odometry at its stamp compares it with a gyro 0.3 s
ahead: every change of turn rate fails the gate, and a start from standstill
is still "wheels still" while the gyro already turns, which a zero-velocity
update then reads as gyro bias (a simulated drive 0.3 s late: ATE 0.78 ->
9.96 m). With ``odometry_delay`` = d the odometry stamped t is used as the
motion at t - d, so the filter runs d behind the newest stamp: the IMU is held
for d (a delay line, :class:`DelayLine`) and released in stamp order. Each
estimate is then carried from the filter time to the stamp of the sample
that produced it by integrating the held gyro (less the filter's bias) and
the filter's speed, the standard way to keep a fused pose current over a
measurement delay (e.g. Bar-Shalom et al., *Estimation with Applications to
Tracking and Navigation*, ch. 10 on out-of-sequence measurements, here with a
known constant delay). The carried pose keeps the covariance of the filter
time (0.3 s of gyro adds about 1e-4 rad of heading std).

:class:`DelayedOdometry` is the filter's side of it; with ``odometry_delay_auto``
it also applies, once, the delay the yaw-rate fit finds (:func:`delay_found`).
"""

from __future__ import annotations

from collections import deque
import dataclasses
import math
from typing import Any, Iterator, Optional, Union

from robot_calib.core import types as T
from robot_calib.core.geometry import wrap_scalar
from robot_calib.methods.odometry_fusion.common import FusionOutput, Rejected
from robot_calib.methods.odometry_fusion.yaw_rate_fit import YawRateFit


class DelayLine:
    """IMU samples held until the odometry of their time can have arrived."""

    def __init__(self, delay: float) -> None:
        """Hold for ``delay`` seconds of stamps (> 0)."""
        self.delay = delay
        self.held: deque[T.ImuSample] = deque()
        self.newest = -math.inf
        self.last_imu_t = -math.inf

    def retimed(self, delay: float) -> 'DelayLine':
        """Return a line of another ``delay`` (s) holding what this one holds."""
        line = DelayLine(delay)
        line.held, line.newest, line.last_imu_t = self.held, self.newest, self.last_imu_t
        return line

    def hold(self, s: T.ImuSample) -> bool:
        """Hold one IMU sample; False when it is not newer than the last one held."""
        if s.t <= self.last_imu_t:
            return False
        self.last_imu_t = s.t
        self.held.append(s)
        self.newest = max(self.newest, s.t)
        return True

    def see(self, t: float) -> None:
        """Note the stamp ``t`` (s) of a wheel sample."""
        self.newest = max(self.newest, t)

    def release(self, until: float) -> Iterator[T.ImuSample]:
        """Yield the held samples stamped at or before ``until`` (s), oldest first."""
        held = self.held
        while held and held[0].t <= until:
            yield held.popleft()

    def shifted(self, s: Any) -> Any:
        """Return the wheel sample ``s`` stamped at the time of its motion."""
        return dataclasses.replace(s, t=s.t - self.delay)

    def carry(self, o: FusionOutput, t_to: float, t_from: float, rate: float, bias: float,
              speed: float, lateral: float, gyro_row: Optional[list],
              timeout: float) -> FusionOutput:
        """
        Return the estimate ``o`` of time ``t_from`` carried to ``t_to`` (s).

        Planar dead reckoning over the held gyro: the rate ``rate`` (rad/s, bias included)
        holds until the next held sample, whose z in base_link is ``gyro_row`` times its
        gyro (the mounting's third row; None: no held gyro is used), less ``bias``;
        ``speed`` and the sideways ``lateral`` (m/s) are constant. Steps longer than
        ``timeout`` (s) are not integrated.
        """
        x, y, yaw = o.x, o.y, o.yaw
        w = rate - bias
        tp = t_from
        for s in self.held if gyro_row is not None else ():
            if s.t > t_to:
                break
            x, y, yaw = _step(x, y, yaw, speed, lateral, w, s.t - tp, timeout)
            g = s.gyro
            w = gyro_row[0] * g[0] + gyro_row[1] * g[1] + gyro_row[2] * g[2] - bias
            tp = s.t
        x, y, yaw = _step(x, y, yaw, speed, lateral, w, t_to - tp, timeout)
        return dataclasses.replace(o, t=t_to, x=x, y=y, yaw=wrap_scalar(yaw), w=w)


class DelayedOdometry:
    """
    The improved filter's side of the delay line (a mixin before FusionFilter).

    Expects of the filter: ``p``, ``t``, ``warn``, ``count``,
    ``_imu_invalid`` and ``_carry_inputs()`` (the filter's turn rate, gyro bias, speed
    and the mounting's z row for :meth:`DelayLine.carry`); its ``_start`` calls
    :meth:`_start_delay` and takes its ``yaw_fit`` from :meth:`_new_yaw_fit`.
    """

    def _start_delay(self) -> None:
        """Set the delay line of ``odometry_delay`` (none at 0) and the auto switch's state."""
        d = self.p.odometry_delay
        self._delay = DelayLine(d) if d > 0.0 else None
        self.delay_applied = d
        """The odometry delay (s) applied: configured, or found by the yaw-rate fit."""
        self._delay_switched = False
        self._fit_blocks_seen = 0

    def _new_yaw_fit(self, known_delay: float) -> YawRateFit:
        """Return an empty yaw-rate fit relative to ``known_delay`` (s, the delay applied)."""
        p = self.p
        return YawRateFit(p.yaw_rate_fit_block, p.yaw_rate_fit_min_blocks,
                          p.yaw_rate_fit_max_delay, known_delay)

    def _check_found_delay(self, t: float) -> None:
        """After a yaw-rate fit block closed: apply a delay found (see _apply_found_delay)."""
        if self.yaw_fit.closed_blocks != self._fit_blocks_seen:
            self._fit_blocks_seen = self.yaw_fit.closed_blocks
            self._apply_found_delay(t)

    def update(self, sample: Any) -> Union[FusionOutput, Rejected, None]:
        """Process one sample (see FusionFilter.update), through the delay line when set."""
        line = self._delay
        if line is None:
            return super().update(sample)
        if isinstance(sample, T.ImuSample):
            g, a = sample.gyro, sample.accel
            reason = self._imu_invalid(float(g[0]), float(g[1]), float(g[2]), float(a[0]),
                                       float(a[1]), float(a[2]), sample.t)
            if reason is None and not line.hold(sample):
                reason = 'out_of_order'
            if reason is not None:
                return Rejected(reason)
            out = self._release(line, line.newest - line.delay)
        elif isinstance(sample, (T.OdomSample, T.JointStateSample)):
            line.see(sample.t)
            self._release(line, sample.t - line.delay)
            out = super().update(line.shifted(sample))
        else:
            return super().update(sample)
        if not isinstance(out, FusionOutput) or self.t is None:
            return out
        return line.carry(out, sample.t, self.t, *self._carry_inputs(), self.p.sensor_timeout)

    def _release(self, line: DelayLine, until: float) -> Optional[FusionOutput]:
        """
        Use the held IMU samples up to ``until`` (s); return the last estimate they made.

        Their readings were checked on arrival; one the filter still refuses (older than
        it by more than ``max_lag``) is counted as ``delayed_imu_rejected``.
        """
        out = None
        for s in line.release(until):
            r = super().update(s)
            if isinstance(r, Rejected):
                self.count('delayed_imu_rejected')
            elif r is not None:
                out = r
        return out

    def _apply_found_delay(self, t: float) -> None:
        """
        Apply the odometry delay the yaw-rate fit has found, once (``odometry_delay_auto``).

        From now on the IMU is held for the new delay and the odometry shifted by it; the
        odometry of about the next delay seconds is then older than the filter and dropped
        as stale (counted), while the IMU held in the meantime covers that time. The fit
        starts again relative to the new delay.
        """
        p = self.p
        if not p.odometry_delay_auto or self._delay_switched:
            return
        found = delay_found(self.yaw_fit.result(stale_ok=True), self.delay_applied)
        if found is None or found <= 0.0 or found > 2.0:
            return
        self._delay_switched = True
        self.warn(t, f'the wheel odometry lags the IMU by {found:.2f} s (yaw-rate fit): '
                  f'using it {found:.2f} s before its stamps from now on (set odometry_delay: '
                  f'{found:.2f} to start with it)')
        self._delay = self._delay.retimed(found) if self._delay is not None \
            else DelayLine(found)
        self.delay_applied = found
        self.yaw_fit = self._new_yaw_fit(found)
        self._fit_blocks_seen = 0


def delay_found(fit: dict, configured: float) -> Optional[float]:
    """
    Return the odometry delay (s) a yaw-rate fit has found, when it differs from ``configured``.

    Only from an ``ok`` fit whose delay differs from the configured one (s) by 0.05 s and by
    3 of its standard deviations; None otherwise.
    """
    if fit.get('status') != 'ok' or 'odometry_delay' not in fit:
        return None
    d, sd = fit['odometry_delay'], fit['odometry_delay_std']
    return d if abs(d - configured) >= max(0.05, 3.0 * sd) else None


def _step(x: float, y: float, yaw: float, v: float, vl: float, w: float, dt: float,
          timeout: float) -> tuple[float, float, float]:
    """
    Advance a planar pose over ``dt`` (s).

    Forward speed ``v`` and sideways speed ``vl`` (m/s) in base_link, turn rate ``w`` (rad/s).
    """
    if not 0.0 < dt <= timeout:
        return x, y, yaw
    c, s = math.cos(yaw), math.sin(yaw)
    return x + (v * c - vl * s) * dt, y + (v * s + vl * c) * dt, yaw + w * dt
