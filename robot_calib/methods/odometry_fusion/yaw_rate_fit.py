# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The wheel odometry's yaw-rate calibration over a whole recording, with an honest uncertainty.

The improved filter carries the odometry yaw-rate scale ``k_w`` and the yaw
rate per unit speed ``k_v`` as random-walk states so it can follow a change
of surface; as a calibration they are poor: on steady arcs ``k_w w + k_v v``
has two nearly proportional regressors, the pair drifts along that line after
a slip episode, and the adapted noise keeps their reported std small (on
simulated drives the scale wandered to 0.56-0.87 against 1.037, 12-37 std
away). :class:`YawRateFit` estimates the same model as constants instead:

    w_odom = k_w (gz - b_g) + k_v v + c_block                          (1)

over the odometry intervals the filter accepted while moving, where
``c_block`` is a constant per block of ``yaw_rate_fit_block`` seconds: it
absorbs the filter's gyro bias error, which a constant ``k_v v`` would
otherwise take on (``v`` is mostly one sign). Within a block the variables
are centred, so ``k_v`` is learnt only from changes of speed and ``k_w`` from
changes of turn rate.

The gyro is noisy as a regressor: least squares would shrink ``k_w`` by
``var(noise) / var(turn rate)`` (1 % on the simulated drives, 3 std). The
regressor's instrument is therefore the previous interval's gyro average
(instrumental variables, e.g. Wooldridge, *Econometric Analysis of Cross
Section and Panel Data*, ch. 5): its noise is independent of the current
interval's, while the turn rate 20 ms apart is nearly the same, so

    beta = (sum_b Z_b' X_b)^-1 sum_b Z_b' y_b                          (2)

with ``X = [gz - b_g, v]`` and ``Z = [previous gz - b_g, v]``, centred per
block. A block whose residual RMS under (2) exceeds ``OUTLIER_RMS_RATIO``
times the median block's is dropped: slip that passed the filter's gate (the
gyro turning while the wheels say straight) weighs more than all the rest. The
standard deviations come from the delete-one-block jackknife of (2) over the
blocks kept, which holds with time-correlated errors, smaller slip left in and
a model that only roughly fits, where the textbook formula would not. On the
simulated drives (20 x 600 s) the error over the std has an RMS of about 1;
the model leaves out any delay between the odometry and the gyro. With fewer than
``yaw_rate_fit_min_blocks`` blocks nothing is reported (``status``
``too_little_motion``); when the drive does not separate the two terms, the
standard deviations say so and ``status`` is ``uncertain``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

MAX_BLOCKS = 2048
"""Blocks kept (even): on reaching it, neighbouring pairs merge (bounded memory, longer blocks)."""

SCALE_STD_OK = 0.05
"""Largest scale std (-) with which the fit is called ``ok`` rather than ``uncertain``."""

PER_SPEED_STD_OK = 0.02
"""Largest std of the yaw rate per speed (rad/m) for ``ok``."""

OUTLIER_RMS_RATIO = 5.0
"""A block whose residual RMS exceeds the median block's by this factor is dropped (-)."""


class YawRateFit:
    """Streaming block sums of (1) and their jackknife solve (see the module)."""

    def __init__(self, block: float, min_blocks: int) -> None:
        """Fit over blocks of ``block`` seconds; report from ``min_blocks`` blocks on."""
        self.block = block
        self.min_blocks = min_blocks
        self._blocks: list[tuple[float, ...]] = []
        self._merged = 1
        self._index: Optional[int] = None
        self._t0: Optional[float] = None
        self._sums = [0.0] * 14
        self._prev: Optional[float] = None
        self._cache: tuple[int, int, dict] = (-1, -1, {})
        self.samples = 0

    def add(self, t: float, w_odom: float, w_gyro: float, v: float, usable: bool) -> None:
        """
        Add one odometry interval ending at ``t`` (s).

        :param w_odom: the odometry yaw rate (rad/s)
        :param w_gyro: the gyro z less the filter's bias, averaged over the interval (rad/s)
        :param v: the odometry speed (m/s)
        :param usable: whether the filter accepted this yaw rate while moving, with gyro
            samples of its own in the interval; the instrument is the interval before, when
            it was usable too
        """
        z, self._prev = self._prev, (w_gyro if usable else None)
        if not usable or z is None:
            return
        if self._t0 is None:
            self._t0 = t
        index = int((t - self._t0) // (self.block * self._merged))
        if index != self._index:
            self._close()
            self._index = index
        x, y = w_gyro, w_odom
        s = self._sums
        s[0] += 1.0
        s[1] += z
        s[2] += x
        s[3] += v
        s[4] += y
        s[5] += z * x
        s[6] += z * v
        s[7] += v * x
        s[8] += v * v
        s[9] += z * y
        s[10] += v * y
        s[11] += x * x
        s[12] += x * y
        s[13] += y * y
        self.samples += 1

    @staticmethod
    def _centred(sums: list) -> Optional[tuple[float, ...]]:
        """
        Return a block's centred sums (eq. 1's constant), or None below 3 samples.

        Order: n, Z'X (zx, zv, vx, vv), Z'y (zy, vy), and for its residuals xx, xy, yy.
        """
        n, sz, sx, sv, sy, szx, szv, svx, svv, szy, svy, sxx, sxy, syy = sums
        if n < 3:
            return None
        mz, mx, mv, my = sz / n, sx / n, sv / n, sy / n
        return (n, szx - n * mz * mx, szv - n * mz * mv, svx - n * mv * mx, svv - n * mv * mv,
                szy - n * mz * my, svy - n * mv * my, sxx - n * mx * mx, sxy - n * mx * my,
                syy - n * my * my)

    def _close(self) -> None:
        """Store the open block's centred sums; merge pairs of blocks at the cap."""
        row = self._centred(self._sums)
        self._sums = [0.0] * 14
        if row is None:
            return
        self._blocks.append(row)
        if len(self._blocks) >= MAX_BLOCKS:
            b = np.asarray(self._blocks)
            self._blocks = [tuple(r) for r in (b[0::2] + b[1::2]).tolist()]
            self._merged *= 2
            if self._index is not None:
                self._index //= 2

    def result(self, stale_ok: bool = False) -> dict:
        """
        Return the fit: ``status`` and, when it has enough blocks, the estimates with stds.

        With ``stale_ok`` the last fit is returned while no block has closed since it
        (a status at 1 Hz need not refit every second; about 0.2 ms a fit).

        Keys: ``status`` (``ok``, ``uncertain`` or ``too_little_motion``), ``blocks``,
        ``blocks_dropped``, ``block_length`` (s), ``samples``, and with a solution
        ``yaw_rate_scale``, ``yaw_rate_scale_std`` (-), ``yaw_rate_per_speed``,
        ``yaw_rate_per_speed_std`` (rad/m) and their ``correlation``; ``why`` when not ok.
        """
        samples, closed, cached = self._cache
        if samples == self.samples or (stale_ok and closed == len(self._blocks) and cached):
            return dict(cached)
        out = self._fit()
        self._cache = (self.samples, len(self._blocks), out)
        return dict(out)

    def _fit(self) -> dict:
        """Solve eq. (2) over the blocks, drop outlying ones, jackknife (see result)."""
        rows = list(self._blocks)
        last = self._centred(self._sums)
        if last is not None:
            rows.append(last)
        out: dict = {'status': 'too_little_motion', 'blocks': len(rows), 'blocks_dropped': 0,
                     'block_length': self.block * self._merged, 'samples': self.samples}
        if len(rows) < max(self.min_blocks, 3):
            return out
        b = np.asarray(rows)
        beta = _solve(b.sum(axis=0))
        if beta is not None:
            # a block whose residuals are far beyond the others' is slip the gate let in
            # (a turn the wheels did not see), not noise: drop it before the jackknife
            k_w, k_v = beta
            rss = (b[:, 9] - 2.0 * (k_w * b[:, 8] + k_v * b[:, 6])
                   + k_w * k_w * b[:, 7] + 2.0 * k_w * k_v * b[:, 3] + k_v * k_v * b[:, 4])
            ms = np.maximum(rss, 0.0) / b[:, 0]
            keep = ms <= OUTLIER_RMS_RATIO ** 2 * float(np.median(ms))
            out['blocks_dropped'] = int(len(b) - keep.sum())
            b = b[keep]
            out['blocks'] = len(b)
        if len(b) < max(self.min_blocks, 3):
            return out
        total = b.sum(axis=0)
        beta = _solve(total)
        jack = _solve(total - b)
        if beta is None or jack is None:
            out['status'] = 'uncertain'
            out['why'] = 'the turn rate and the speed do not vary independently in this drive'
            return out
        k_w, k_v = beta
        jw, jv = jack
        nb = len(b)
        dw, dv = jw - jw.mean(), jv - jv.mean()
        f = (nb - 1) / nb
        sd_w, sd_v = math.sqrt(f * float(dw @ dw)), math.sqrt(f * float(dv @ dv))
        if not all(math.isfinite(x) for x in (k_w, k_v, sd_w, sd_v)):
            out['status'] = 'uncertain'
            return out
        out.update(yaw_rate_scale=float(k_w), yaw_rate_scale_std=sd_w,
                   yaw_rate_per_speed=float(k_v), yaw_rate_per_speed_std=sd_v,
                   correlation=f * float(dw @ dv) / (sd_w * sd_v) if sd_w * sd_v > 0 else 0.0)
        ok = sd_w <= SCALE_STD_OK and sd_v <= PER_SPEED_STD_OK
        out['status'] = 'ok' if ok else 'uncertain'
        if not ok:
            out['why'] = 'the drive does not separate the scale from the yaw rate per speed'
        return out


def _solve(sums: np.ndarray):
    """
    Solve eq. (2) from summed block rows (one row, or one per row of a 2-D array).

    Return (k_w, k_v) as floats or arrays, or None when a system is singular.
    """
    zx, zv, vx, vv, zy, vy = (sums[..., i] for i in range(1, 7))
    det = zx * vv - zv * vx
    size = np.abs(zx * vv) + np.abs(zv * vx)
    if not np.all(size > 0.0) or np.any(np.abs(det) <= 1e-9 * size):
        return None
    return (vv * zy - zv * vy) / det, (zx * vy - vx * zy) / det
