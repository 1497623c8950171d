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


class LowPass:
    """
    A bank of 2nd-order Butterworth low-pass filters (direct form I).

    Direct form I keeps past inputs and outputs as its state, so a new
    sampling period changes the coefficients without a jump. Until
    ``tau`` seconds of samples have been seen, the output is the running mean
    of the inputs (a fast, unbiased start).
    """

    __slots__ = ('n', 'tau', 'coef', 'x1', 'x2', 'y1', 'y2', 'count', 'sum', 'init_n', 'ready')

    def __init__(self, n: int, tau: float, ts: float):
        self.n = n
        self.tau = tau
        self.coef = butter2(tau, ts)
        self.count = 0
        self.sum = [0.0] * n
        self.init_n = max(1, int(round(tau / ts)))
        self.ready = False

    def set_ts(self, ts: float) -> None:
        """Recompute the coefficients for sampling period ``ts`` (s)."""
        self.coef = butter2(self.tau, ts)
        if not self.ready:
            self.init_n = max(1, int(round(self.tau / ts)))

    def fill(self, value: list) -> None:
        """Set the filter to the steady state of a constant input ``value``."""
        self.x1 = list(value)
        self.x2 = list(value)
        self.y1 = list(value)
        self.y2 = list(value)
        self.ready = True

    def __call__(self, x: list) -> list:
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
        x1 = self.x1
        x2 = self.x2
        y1 = self.y1
        y2 = self.y2
        y = [0.0] * n
        for i in range(n):
            xi = x[i]
            yi = b0 * xi + b1 * x1[i] + b2 * x2[i] - a1 * y1[i] - a2 * y2[i]
            x2[i] = x1[i]
            x1[i] = xi
            y2[i] = y1[i]
            y1[i] = yi
            y[i] = yi
        return y


class LowPass3(LowPass):
    """The 3-channel case of :class:`LowPass`, unrolled (it runs several times per sample)."""

    __slots__ = ()

    def __call__(self, x: list) -> list:
        if not self.ready:
            return LowPass.__call__(self, x)
        b0, b1, b2, a1, a2 = self.coef
        x1 = self.x1
        x2 = self.x2
        y1 = self.y1
        y2 = self.y2
        u0, u1, u2 = x[0], x[1], x[2]
        v0 = b0 * u0 + b1 * x1[0] + b2 * x2[0] - a1 * y1[0] - a2 * y2[0]
        v1 = b0 * u1 + b1 * x1[1] + b2 * x2[1] - a1 * y1[1] - a2 * y2[1]
        v2 = b0 * u2 + b1 * x1[2] + b2 * x2[2] - a1 * y1[2] - a2 * y2[2]
        self.x2 = x1
        self.x1 = [u0, u1, u2]
        self.y2 = y1
        self.y1 = [v0, v1, v2]
        return [v0, v1, v2]
