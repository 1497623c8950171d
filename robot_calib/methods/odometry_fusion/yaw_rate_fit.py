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
a model that only roughly fits, where the textbook formula would not.

Wheel odometry is often late against the IMU (a controller's filtering, a
driver's polling: about 0.3 s on the robot_localization Husky bag), and a
late odometry regressed on the current gyro reads as a smaller scale (1.001
instead of 1.037 on a simulated drive 0.45 s late). The fit therefore also
searches the delay: the regressor of lag ``k`` is the gyro of ``k`` odometry
intervals earlier (later when k < 0; its instrument the interval before), the
sums of every lag within ``yaw_rate_fit_max_delay`` either side of the delay
the filter already takes out (``odometry_delay``) are kept per block, and the
lag whose solution leaves the smallest residual over the recording is chosen.
The lags are compared over the same intervals, those that pass the filter's
gate at some lag; the fit at the lag chosen then takes those that pass the
gate at that lag (the gate where odometry and gyro are aligned). The
jackknife repeats the choice with each block left out, so the stds include
the uncertainty of the delay. On the simulated drives (20 x 600 s) the error
over the std has an RMS of about 1. With fewer than
``yaw_rate_fit_min_blocks`` blocks nothing is reported (``status``
``too_little_motion``); when the drive does not separate the two terms, or the
delay is at the edge of those searched, the standard deviations or ``why`` say
so and ``status`` is ``uncertain``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

MAX_BLOCKS = 512
"""Blocks kept (even): on reaching it, neighbouring pairs merge (bounded memory, longer blocks)."""

MAX_LAGS = 64
"""Most odometry intervals of delay searched, whatever the odometry rate (-)."""

SCALE_STD_OK = 0.05
"""Largest scale std (-) with which the fit is called ``ok`` rather than ``uncertain``."""

PER_SPEED_STD_OK = 0.02
"""Largest std of the yaw rate per speed (rad/m) for ``ok``."""

OUTLIER_RMS_RATIO = 5.0
"""A block whose residual RMS exceeds the median block's by this factor is dropped (-)."""

GAP_INTERVALS = 5.0
"""An odometry interval this many times the block's median breaks the lagged gyro (-)."""

# columns of a block's centred sums for one lag: n, Z'X (zx, zv, vx, vv), Z'y (zy, vy),
# and for the residuals xx, xy, yy
N, ZX, ZV, VX, VV, ZY, VY, XX, XY, YY = range(10)
SEARCH, FIT = 0, 1
"""A block's two sets of sums: for choosing the lag, and for the fit at the lag chosen."""


class YawRateFit:
    """Streaming per-lag block sums of (1) and their jackknife solve (see the module)."""

    def __init__(self, block: float, min_blocks: int, max_delay: float = 0.0,
                 known_delay: float = 0.0) -> None:
        """
        Fit over blocks of ``block`` seconds; report from ``min_blocks`` blocks on.

        ``max_delay`` (s): delays are searched that far either side of ``known_delay`` (s,
        the delay the filter already takes out; the one reported is the sum); the lag
        count follows from the first block's median odometry interval.
        """
        self.block = block
        self.min_blocks = min_blocks
        self.max_delay = max_delay
        self.known_delay = known_delay
        self.lags: Optional[int] = None
        self._blocks: list[np.ndarray] = []
        self._intervals: list[float] = []
        self._merged = 1
        self._index: Optional[int] = None
        self._t0: Optional[float] = None
        self._open: list[tuple] = []  # (t, w_odom, gyro, v, usable, k_w, k_v, bound) rows
        self._tail = np.zeros(0)
        self._tail_t = np.zeros(0)
        self._cache: tuple[int, int, dict] = (-1, -1, {})
        self.samples = 0

    @property
    def closed_blocks(self) -> int:
        """Return how many blocks have closed (a result may change only when this does)."""
        return len(self._blocks)

    def add(self, t: float, w_odom: float, w_gyro: float, v: float, usable: bool,
            fresh: bool = True, gate: Optional[tuple[float, float, float]] = None) -> None:
        """
        Add one odometry interval ending at ``t`` (s).

        :param w_odom: the odometry yaw rate (rad/s)
        :param w_gyro: the gyro z less the filter's bias, averaged over the interval (rad/s)
        :param v: the odometry speed (m/s)
        :param usable: whether the interval may enter the fit (moving, not rejected)
        :param fresh: whether gyro samples arrived in the interval (else its gyro is unknown,
            as a regressor of a later interval too)
        :param gate: the filter's yaw-rate test (k_w, k_v, bound in rad/s), passed at a lag
            when ``|w_odom - k_w gyro - k_v v| <= bound`` with the gyro of that lag: the lag
            is chosen over the intervals that pass at some lag (a late odometry fails at lag
            0 whenever the turn rate changes, and leaving those out would hide the delay),
            the fit at the lag chosen uses those that pass there (slip stays out)
        """
        if self._t0 is None:
            self._t0 = t
        index = int((t - self._t0) // (self.block * self._merged))
        if index != self._index:
            self._close()
            self._index = index
        k_w, k_v, b = gate if gate is not None else (0.0, 0.0, math.inf)
        self._open.append((t, w_odom, w_gyro if fresh else math.nan, v, usable, k_w, k_v, b))
        self.samples += usable

    def _table(self) -> np.ndarray:
        """Return the open rows as an array (n, 8), columns as in ``_open``."""
        return np.array(self._open, dtype=float).reshape(-1, 8)

    def _lag_count(self, times: np.ndarray) -> Optional[int]:
        """
        Return L, the lags searched each way, or None before 10 intervals.

        Fixed once, from the median odometry interval of the first 10 or more ``times`` (s).
        """
        if self.lags is None:
            if len(times) < 10:
                return None
            dt = self._median_interval(times)
            if self.max_delay <= 0.0 or not dt > 0.0:
                self.lags = 0
            else:
                self.lags = min(int(math.ceil(self.max_delay / dt)), MAX_LAGS)
        return self.lags

    @staticmethod
    def _median_interval(times: np.ndarray) -> float:
        """Return the median interval (s) of a block's stamps, or nan below 2 of them."""
        return float(np.median(np.diff(times))) if len(times) > 1 else math.nan

    def _rows(self, table: np.ndarray) -> tuple[Optional[np.ndarray], int]:
        """
        Return the sums of the open rows ``table``, (2, 2 L + 1, 10) or None, and rows summed.

        Column ``c`` is lag ``k = c - L``: x is the gyro ``k`` intervals before the
        odometry (after it when k < 0), z the one before x; the first index is SEARCH or
        FIT (see the module). Only the rows whose gyro ``L`` intervals ahead has arrived are
        summed; a lag with fewer than 3 samples contributes a zero row.
        """
        times, y, g, vs, ok, gk_w, gk_v, bound = table.T
        lags = self._lag_count(times)
        if lags is None:
            return None, 0
        m = len(times) - lags
        if m <= 0 or ok[:m].sum() < 3:
            return None, max(m, 0)
        width = 2 * lags + 2
        ctx = lags + 1
        tail_g = np.concatenate((np.full(ctx, math.nan), self._tail))[-ctx:]
        tail_t = np.concatenate((np.full(ctx, math.nan), self._tail_t))[-ctx:]
        g_ext = np.concatenate((tail_g, g))
        t_ext = np.concatenate((tail_t, times))
        windows = sliding_window_view(g_ext, width)[:m]
        x = windows[:, width - 1:0:-1]           # column c: gyro of lag c - L
        z = windows[:, width - 2::-1]
        y_a, v_a = y[:m], vs[:m]
        res = np.abs(y_a[:, None] - gk_w[:m, None] * x - (gk_v[:m] * v_a)[:, None])
        with np.errstate(invalid='ignore'):
            passed = res <= bound[:m, None]
            dt = np.diff(t_ext)
            gaps = np.flatnonzero(dt > GAP_INTERVALS * max(float(np.nanmedian(dt)), 1e-6)) + 1
        usable = (ok[:m] > 0.0)[:, None] & np.isfinite(x) & np.isfinite(z)
        if len(gaps):
            # no lag pairs an odometry and a gyro across a gap in the odometry
            row = (ctx + np.arange(m))[:, None]
            k = np.arange(-lags, lags + 1)[None, :]
            lo, hi = np.minimum(row, row - k - 1), np.maximum(row, row - k)
            for e in gaps.tolist():
                usable &= ~((lo < e) & (e <= hi))
        # SEARCH: the intervals that pass the gate at some lag, the same at every lag, so
        # the residuals of the lags compare; FIT: those that pass at each lag itself
        out = np.stack((_centred_sums(usable & passed.any(axis=1)[:, None], x, z, y_a, v_a),
                        _centred_sums(usable & passed, x, z, y_a, v_a)))
        return (out if out[FIT, :, N].any() else None), m

    def _close(self) -> None:
        """
        Store the open rows' sums as a block; merge pairs at the cap.

        The last L rows wait for the gyro after them and join the next block.
        """
        if not self._open:
            return
        table = self._table()
        row, used = self._rows(table)
        if used <= 0:
            return
        interval = self._median_interval(table[:, 0])
        keep = MAX_LAGS + 1
        self._tail = np.concatenate((self._tail, table[:used, 2]))[-keep:]
        self._tail_t = np.concatenate((self._tail_t, table[:used, 0]))[-keep:]
        del self._open[:used]
        if row is None:
            return
        self._blocks.append(row)
        self._intervals.append(interval)
        if len(self._blocks) >= MAX_BLOCKS:
            b = np.asarray(self._blocks)
            self._blocks = list(b[0::2] + b[1::2])
            iv = np.asarray(self._intervals)
            self._intervals = list(np.nanmean(np.column_stack((iv[0::2], iv[1::2])), axis=1))
            self._merged *= 2
            if self._index is not None:
                self._index //= 2

    def result(self, stale_ok: bool = False) -> dict:
        """
        Return the fit: ``status`` and, when it has enough blocks, the estimates with stds.

        With ``stale_ok`` the last fit is returned while no block has closed since it
        (a status at 1 Hz need not refit every second: with the delay search a fit takes
        1-15 ms, growing with the blocks and the lags).

        Keys: ``status`` (``ok``, ``uncertain`` or ``too_little_motion``), ``blocks``,
        ``blocks_dropped``, ``block_length`` (s), ``samples``, and with a solution
        ``yaw_rate_scale``, ``yaw_rate_scale_std`` (-), ``yaw_rate_per_speed``,
        ``yaw_rate_per_speed_std`` (rad/m), their ``correlation``, ``odometry_delay`` and
        ``odometry_delay_std`` (s, the odometry behind the gyro; negative: ahead of it) and
        ``delays_searched`` (s, from, to); ``why`` when not ok.
        """
        samples, closed, cached = self._cache
        if samples == self.samples or (stale_ok and closed == len(self._blocks) and cached):
            return dict(cached)
        out = self._fit()
        self._cache = (self.samples, len(self._blocks), out)
        return dict(out)

    def _fit(self) -> dict:
        """Choose the lag, solve eq. (2), drop outlying blocks, jackknife (see result)."""
        rows = list(self._blocks)
        table = self._table()
        last, _ = self._rows(table)
        if last is not None:
            rows.append(last)
        out: dict = {'status': 'too_little_motion', 'blocks': len(rows), 'blocks_dropped': 0,
                     'block_length': self.block * self._merged, 'samples': self.samples}
        need = max(self.min_blocks, 3)
        if len(rows) < need:
            return out
        b = np.asarray(rows)                    # (blocks, SEARCH/FIT, 2 L + 1, 10)
        lag = _best_lag(b[:, SEARCH].sum(axis=0))
        beta = _solve(b[:, FIT, lag].sum(axis=0)) if lag is not None else None
        if beta is not None:
            # a block whose residuals are far beyond the others' is slip the gate let in
            # (a turn the wheels did not see), not noise: drop it before the jackknife
            bl = b[:, FIT, lag, :]
            ms = _rss(bl, *beta) / np.maximum(bl[:, N], 1.0)
            keep = (ms <= OUTLIER_RMS_RATIO ** 2 * float(np.median(ms))) & (bl[:, N] > 0)
            out['blocks_dropped'] = int(len(b) - keep.sum())
            b = b[keep]
            out['blocks'] = len(b)
        if len(b) < need:
            return out
        total = b.sum(axis=0)
        lag = _best_lag(total[SEARCH])
        jack_lags = _best_lag(total[None, SEARCH] - b[:, SEARCH])
        fit = _solve(total[FIT, lag]) if lag is not None else None
        jack = _solve((total[None, FIT] - b[:, FIT])[np.arange(len(b)), jack_lags]) \
            if jack_lags is not None else None
        if fit is None or jack is None:
            out['status'] = 'uncertain'
            out['why'] = 'the turn rate and the speed do not vary independently in this drive'
            return out
        k_w, k_v = fit
        jw, jv = jack
        nb = len(b)
        dw, dv = jw - jw.mean(), jv - jv.mean()
        f = (nb - 1) / nb
        sd_w, sd_v = math.sqrt(f * float(dw @ dw)), math.sqrt(f * float(dv @ dv))
        interval = float(np.nanmedian(self._intervals)) if self._intervals else math.nan
        if not math.isfinite(interval):
            interval = self._median_interval(table[:, 0])
        # the delay's std: the jackknife of the chosen lag and its rounding to an interval
        dl = jack_lags - jack_lags.mean()
        if not all(math.isfinite(x) for x in (k_w, k_v, sd_w, sd_v)):
            out['status'] = 'uncertain'
            return out
        lags = self.lags or 0
        reach = (self.known_delay - lags * interval, self.known_delay + lags * interval)
        out.update(yaw_rate_scale=float(k_w), yaw_rate_scale_std=sd_w,
                   yaw_rate_per_speed=float(k_v), yaw_rate_per_speed_std=sd_v,
                   correlation=f * float(dw @ dv) / (sd_w * sd_v) if sd_w * sd_v > 0 else 0.0,
                   odometry_delay=self.known_delay + (lag - lags) * interval,
                   odometry_delay_std=math.sqrt(f * float(dl @ dl) + 1.0 / 12.0) * interval,
                   delays_searched=reach)
        ok = sd_w <= SCALE_STD_OK and sd_v <= PER_SPEED_STD_OK
        out['status'] = 'ok' if ok else 'uncertain'
        if not ok:
            out['why'] = 'the drive does not separate the scale from the yaw rate per speed'
        elif lags and lag in (0, 2 * lags):
            out['status'] = 'uncertain'
            out['why'] = (f'the odometry delay is at the edge of those searched ({reach[0]:.2f} '
                          f'to {reach[1]:.2f} s) or beyond')
        return out


def _centred_sums(mask: np.ndarray, x: np.ndarray, z: np.ndarray, y: np.ndarray,
                  v: np.ndarray) -> np.ndarray:
    """
    Return the centred sums per lag (columns of ``x`` and ``z``) over ``mask``, (lags, 10).

    A lag with fewer than 3 samples gets a zero row.
    """
    x = np.where(mask, x, 0.0)
    z = np.where(mask, z, 0.0)
    yy = np.where(mask, y[:, None], 0.0)
    vv = np.where(mask, v[:, None], 0.0)
    cnt = mask.sum(axis=0).astype(float)
    safe = np.maximum(cnt, 1.0)
    mz, mx, mv, my = (a.sum(axis=0) / safe for a in (z, x, vv, yy))

    def centred(a, b, ma, mb):
        return (a * b).sum(axis=0) - cnt * ma * mb

    out = np.column_stack((cnt, centred(z, x, mz, mx), centred(z, vv, mz, mv),
                           centred(vv, x, mv, mx), centred(vv, vv, mv, mv),
                           centred(z, yy, mz, my), centred(vv, yy, mv, my),
                           centred(x, x, mx, mx), centred(x, yy, mx, my),
                           centred(yy, yy, my, my)))
    out[cnt < 3] = 0.0
    return out


def _rss(rows: np.ndarray, k_w, k_v) -> np.ndarray:
    """Return the residual sum of squares of eq. (1) from centred sums at (k_w, k_v)."""
    return np.maximum(rows[..., YY] - 2.0 * (k_w * rows[..., XY] + k_v * rows[..., VY])
                      + k_w * k_w * rows[..., XX] + 2.0 * k_w * k_v * rows[..., VX]
                      + k_v * k_v * rows[..., VV], 0.0)


def _best_lag(totals: np.ndarray):
    """
    Return the lag whose solution of eq. (2) leaves the least residual per sample.

    ``totals`` holds summed rows per lag, shape (lags + 1, 10), or a stack of them
    (then one lag per stack entry, as an array). None when a system is singular.
    """
    zx, zv, vx, vv, zy, vy = (totals[..., i] for i in (ZX, ZV, VX, VV, ZY, VY))
    det = zx * vv - zv * vx
    solvable = np.abs(det) > 1e-9 * (np.abs(zx * vv) + np.abs(zv * vx))
    det = np.where(solvable, det, 1.0)
    ms = _rss(totals, (vv * zy - zv * vy) / det, (zx * vy - vx * zy) / det)
    ms = np.where(solvable, ms / np.maximum(totals[..., N], 1.0), np.inf)
    if not np.all(np.isfinite(ms.min(axis=-1))):
        return None
    return np.argmin(ms, axis=-1) if ms.ndim > 1 else int(np.argmin(ms))


def _solve(sums: np.ndarray):
    """
    Solve eq. (2) from summed block rows (one row, or one per row of an array).

    Return (k_w, k_v) as floats or arrays, or None when a system is singular.
    """
    zx, zv, vx, vv, zy, vy = (sums[..., i] for i in (ZX, ZV, VX, VV, ZY, VY))
    det = zx * vv - zv * vx
    size = np.abs(zx * vv) + np.abs(zv * vx)
    if not np.all(size > 0.0) or np.any(np.abs(det) <= 1e-9 * size):
        return None
    return (vv * zy - zv * vy) / det, (zx * vy - vx * zy) / det
