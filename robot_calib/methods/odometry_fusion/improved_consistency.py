# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Consistency of the improved filter: NIS monitoring and odometry noise adaptation.

:class:`NisMonitor` counts the normalised innovation squared (NIS) of each
odometry update (2 dof when both channels are used) inside or outside its
two-sided 95 % chi-square band; its moving average over ``nis_window``
updates is also compared with the (narrower) band of that average, which
exposes time-correlated innovations.

:class:`NoiseAdapter` (``adaptation: nis``, the default) keeps one bounded
scale factor per odometry channel (speed, yaw rate) that multiplies both that
channel's measurement noise and the process noise feeding it (accelerometer
noise for the speed, gyro noise for the yaw rate). The scale follows a
stochastic approximation of ``E[NIS] = 1`` in log space
(``log s += (dt / adapt_time) * (min(NIS, 3) - 1)``), clamped to
``[adapt_min, adapt_max]``. Why: from a scalar innovation stream only the
total innovation variance is identifiable, not the split between Q and R, so
we adapt the total and keep the nominal split (physically motivated
defaults); the multiplicative update on a positive nominal keeps every
covariance positive definite and bounded by construction, unlike plain
Sage-Husa whose ``C - H P H'`` can go negative; the NIS cap of 3 stops a
slip episode from inflating the noise fast enough to let the slip in; and it
costs a few flops per update where variational-Bayes adaptation iterates
per step. ``adaptation: iae`` is the classic innovation-based adaptive
estimation of R alone (Mohamed & Schwarz 1999, ``R = C - H P H'`` from the
windowed innovation covariance, clipped to the same bounds), kept for
comparison.
"""

from __future__ import annotations

import math
from typing import Optional

from robot_calib.core.chi2 import chi2_ppf
from robot_calib.core.series import Thinned
from robot_calib.methods.odometry_fusion.common import NisStats
from robot_calib.methods.odometry_fusion.params import FusionParams


def nis_band(dof: int, window: int, prob: float = 0.95) -> tuple[float, float]:
    """
    Return the two-sided ``prob`` band of the mean of ``window`` NIS values of ``dof`` dof.

    :param dof: degrees of freedom of one NIS value
    :param window: number of values averaged
    :param prob: band probability
    :return: (low, high) of the average NIS
    """
    n = dof * window
    a = (1.0 - prob) / 2.0
    return float(chi2_ppf(a, n) / window), float(chi2_ppf(1.0 - a, n) / window)


class NisMonitor:
    """NIS of the odometry updates: history, band counts and the moving average."""

    def __init__(self, window: int):
        """Average the NIS over ``window`` updates."""
        self.window = window
        self.history = Thinned()
        """NIS of every update, thinned to a bounded size (plots); ``total`` is exact."""
        self.total = 0.0
        self._win: list[float] = []
        self._dof_win: list[int] = []
        self.average = float('nan')
        self.in_band = 0
        self.checked = 0
        self.window_checked = 0
        self.window_in_band = 0
        self.band_now = (float('nan'), float('nan'))
        self._band: dict = {}

    def record(self, nis: float, dof: int) -> None:
        """Record one update's NIS; count it inside or outside its two-sided 95 % band."""
        self.history.append(nis)
        self.total += nis
        band1 = self._band.get((dof, 1))
        if band1 is None:
            band1 = self._band[(dof, 1)] = nis_band(dof, 1)
        self.checked += 1
        if band1[0] <= nis <= band1[1]:
            self.in_band += 1
        self._win.append(nis)
        self._dof_win.append(dof)
        n = self.window
        if len(self._win) > n:
            del self._win[0]
            del self._dof_win[0]
        if len(self._win) == n:
            total_dof = sum(self._dof_win)
            band = self._band.get(total_dof)
            if band is None:
                lo, hi = nis_band(1, total_dof)
                band = self._band[total_dof] = (lo * total_dof / n, hi * total_dof / n)
            self.average = sum(self._win) / n
            self.window_checked += 1
            if band[0] <= self.average <= band[1]:
                self.window_in_band += 1
            self.band_now = band

    def stats(self) -> NisStats:
        """Return the statistics so far."""
        h = self.history
        return NisStats(updates=h.count, total=self.total,
                        last=h[-1] if h else float('nan'), average=self.average,
                        window=self.window, band=self.band_now, in_band=self.in_band,
                        checked=self.checked, window_in_band=self.window_in_band,
                        window_checked=self.window_checked, history=tuple(h.items),
                        history_stride=h.stride)


class NoiseAdapter:
    """Noise scale of the speed (0) and yaw-rate (1) channels, adapted from the innovations."""

    def __init__(self, params: FusionParams, gate: float):
        """Adapt as ``params`` say; ``gate`` (chi-square, 1 dof) clips outliers (iae)."""
        self.p = params
        self._gate = gate
        self.scales = [1.0, 1.0]
        """The two scales as Python floats (cheaper per use than an array; same arithmetic)."""
        self._c2: Optional[list] = None
        self._c2_t: list = [None, None]

    def reset(self) -> None:
        """Return to the nominal noise (scales 1) and forget the innovation averages."""
        self.scales[0] = self.scales[1] = 1.0
        self._c2 = None

    def adapt(self, i: int, resid: float, s_pred: float, r_nom: float, s_tot: float,
              t: float) -> None:
        """
        Adapt the noise scale of channel ``i`` from its innovation.

        :param resid: innovation
        :param s_pred: its variance due to the state (H P H' plus unadapted terms)
        :param r_nom: nominal measurement variance
        :param s_tot: total innovation variance used in the update
        :param t: time of the update (s)
        """
        p = self.p
        if not p.adaptive:
            return
        if self._c2 is None:
            self._c2 = [None, None]
            self._c2_t = [t, t]
        if self._c2[i] is None:
            self._c2[i] = r_nom + s_pred
            self._c2_t[i] = t
        dt = max(t - self._c2_t[i], 0.0)
        self._c2_t[i] = t
        a = min(1.0, max(dt, 0.001) / p.adapt_time)
        if p.adaptation == 'nis':
            # stochastic approximation of E[NIS] = 1 on log(scale); the NIS is capped at 3
            # so that a slip episode raises the scale by at most exp(2 a) per update
            nis = resid * resid / s_tot
            lam = self.scales[i] * math.exp(a * (min(nis, 3.0) - 1.0))
        else:
            e2 = min(resid * resid, self._gate * s_tot)  # clipped: an outlier cannot dominate
            self._c2[i] += a * (e2 - self._c2[i])
            # IAE: R = C_nu - H P H', as a bounded scale of the nominal (Mohamed & Schwarz 1999)
            lam = (self._c2[i] - s_pred) / r_nom
        self.scales[i] = min(max(lam, p.adapt_min), p.adapt_max)
