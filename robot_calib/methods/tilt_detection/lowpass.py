# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Second-order Butterworth low-pass filters on Python floats (the improved variant's filters).

Direct form I, with coefficients that follow a changing sampling period and a
running-mean start (see :class:`LowPass`).
"""

from __future__ import annotations

import math


def butter2(tau: float, ts: float) -> tuple:
    """
    Return (b0, b1, b2, a1, a2) of a 2nd-order Butterworth low-pass, fc = sqrt(2)/(2 pi tau).

    Bilinear transform with pre-warping (Laidig & Seel 2023 choose the cut-off
    this way so that the filter's step response has time constant ``tau``).
    """
    fc = math.sqrt(2.0) / (2.0 * math.pi * tau)
    c = math.tan(math.pi * min(fc * ts, 0.49))
    d = c * c + math.sqrt(2.0) * c + 1.0
    b0 = c * c / d
    return (b0, 2.0 * b0, b0, 2.0 * (c * c - 1.0) / d, (1.0 - math.sqrt(2.0) * c + c * c) / d)


class _Butterworth2Bank:
    """What both filter banks share: coefficients, the period and the running-mean start."""

    __slots__ = ('n', 'tau', 'coef', 'count', 'init_n', 'ready')

    def __init__(self, n: int, tau: float, ts: float):
        """Create ``n`` channels with time constant ``tau`` (s) at sampling period ``ts`` (s)."""
        self.n = n
        self.tau = tau
        self.coef = butter2(tau, ts)
        self.count = 0
        self.init_n = max(1, int(round(tau / ts)))
        self.ready = False

    def set_ts(self, ts: float) -> None:
        """Recompute the coefficients for sampling period ``ts`` (s)."""
        self.coef = butter2(self.tau, ts)
        if not self.ready:
            self.init_n = max(1, int(round(self.tau / ts)))


class LowPass(_Butterworth2Bank):
    """
    A bank of 2nd-order Butterworth low-pass filters (direct form I).

    Direct form I keeps past inputs and outputs as its state, so a new
    sampling period changes the coefficients without a jump. Until
    ``tau`` seconds of samples have been seen, the output is the running mean
    of the inputs (a fast, unbiased start).
    """

    __slots__ = ('x1', 'x2', 'y1', 'y2', 'sum')

    def __init__(self, n: int, tau: float, ts: float):
        """Create ``n`` channels with time constant ``tau`` (s) at sampling period ``ts`` (s)."""
        super().__init__(n, tau, ts)
        self.sum = [0.0] * n

    def fill(self, value: list) -> None:
        """Set the filter to the steady state of a constant input ``value``."""
        self.x1 = list(value)
        self.x2 = list(value)
        self.y1 = list(value)
        self.y2 = list(value)
        self.ready = True

    def __call__(self, x: list) -> list:
        """Filter one input ``x`` (n values); return the output as a new list."""
        n = self.n
        if not self.ready:
            self.count += 1
            s = self.sum
            for i in range(n):
                s[i] += x[i]
            mean = [v / self.count for v in s]
            if self.count >= self.init_n:
                self.x1 = list(mean)
                self.x2 = list(mean)
                self.y1 = list(mean)
                self.y2 = list(mean)
                self.ready = True
            return mean
        b0, b1, b2, a1, a2 = self.coef
        y = [b0 * xi + b1 * u1 + b2 * u2 - a1 * v1 - a2 * v2
             for xi, u1, u2, v1, v2 in zip(x, self.x1, self.x2, self.y1, self.y2)]
        self.x2 = self.x1
        self.x1 = list(x[:n])
        self.y2 = self.y1
        self.y1 = y
        return list(y)


class LowPass3(_Butterworth2Bank):
    """
    The 3-channel case of :class:`LowPass` on scalar state (it runs several times per sample).

    Same filter and start as :class:`LowPass`, term for term (the same results
    to the bit); :meth:`step` takes and returns three floats without lists.
    """

    __slots__ = ('s0', 's1', 's2', 'x10', 'x11', 'x12', 'x20', 'x21', 'x22',
                 'y10', 'y11', 'y12', 'y20', 'y21', 'y22')

    def __init__(self, n: int, tau: float, ts: float):
        """Create the bank (``n`` must be 3) with time constant ``tau`` (s), period ``ts`` (s)."""
        if n != 3:
            raise ValueError('LowPass3 filters exactly 3 channels')
        super().__init__(3, tau, ts)
        self.s0 = self.s1 = self.s2 = 0.0

    def fill(self, value: list) -> None:
        """Set the filter to the steady state of a constant input ``value``."""
        v0, v1, v2 = value
        self.x10 = self.x20 = self.y10 = self.y20 = v0
        self.x11 = self.x21 = self.y11 = self.y21 = v1
        self.x12 = self.x22 = self.y12 = self.y22 = v2
        self.ready = True

    def __call__(self, x: list) -> list:
        """Filter one input ``x`` (3 values); return the output as a list."""
        return list(self.step(x[0], x[1], x[2]))

    def step(self, u0: float, u1: float, u2: float) -> tuple:
        """Filter one input (three floats); return the output (three floats)."""
        if not self.ready:
            self.count += 1
            self.s0 += u0
            self.s1 += u1
            self.s2 += u2
            c = self.count
            mean = (self.s0 / c, self.s1 / c, self.s2 / c)
            if c >= self.init_n:
                self.fill(mean)
            return mean
        b0, b1, b2, a1, a2 = self.coef
        x10, x11, x12 = self.x10, self.x11, self.x12
        y10, y11, y12 = self.y10, self.y11, self.y12
        v0 = b0 * u0 + b1 * x10 + b2 * self.x20 - a1 * y10 - a2 * self.y20
        v1 = b0 * u1 + b1 * x11 + b2 * self.x21 - a1 * y11 - a2 * self.y21
        v2 = b0 * u2 + b1 * x12 + b2 * self.x22 - a1 * y12 - a2 * self.y22
        self.x20, self.x21, self.x22 = x10, x11, x12
        self.x10, self.x11, self.x12 = u0, u1, u2
        self.y20, self.y21, self.y22 = y10, y11, y12
        self.y10, self.y11, self.y12 = v0, v1, v2
        return v0, v1, v2
