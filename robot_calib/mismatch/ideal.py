# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Ideal sensors from a ground-truth motion: what a perfect IMU would have read.

A user with motion capture compares the real sensor with what it should
have read. The truth is orientations ``q`` (sensor to world, ENU, z up) and,
where known, positions ``p`` (m); the ideal IMU is

- gyro: the body rate, from the rotation between the orientations ``h``
  samples before and after each sample over their time difference
  (``log(q_(k-h)^-1 q_(k+h)) / (t_(k+h) - t_(k-h))``, a central difference on
  SO(3)); it equals the mean of the true rate over ``[t - h dt, t + h dt]``, a
  box kernel of half width ``h dt``;
- accelerometer: the specific force ``R^T (p'' + g)`` with ``p''`` the second
  difference of positions over ``+-h`` samples, which equals the true
  acceleration averaged with a triangle of half width ``h dt``
  (``g = (0, 0, 9.80665)`` m/s^2; without positions, gravity only).

Differentiating optical data amplifies its noise, so ``h`` is chosen from the
data: the smallest one whose derived signal has a noise (measured from its
own sample-to-sample differences) below ``rel_noise`` of its RMS, at most
``max_half_s``. The kernel each channel went through is returned, so the real
sensor can be compared through the same one (:func:`robot_calib.mismatch.
channels.kernel_weights`). Samples whose truth is lost (NaN), and those whose
window reaches a lost sample, are NaN. Nothing is differentiated across a gap
in the stamps (a step longer than :data:`GAP_FACTOR` times the median step: a
tracking loss, or poses dropped as invalid): each stretch between gaps is
derived on its own and the ``h`` samples at its ends are NaN.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np
from robot_calib.core.constants import GRAVITY
from robot_calib.core.geometry import quat_multiply


GAP_FACTOR = 1.5
"""A step between stamps longer than this many median steps is a gap (one sample missing)."""


def segments(t: np.ndarray) -> list[slice]:
    """Return the stretches of ``t`` (s) between gaps (see :data:`GAP_FACTOR`), in order."""
    n = t.size
    if n < 3:
        return [slice(0, n)]
    dt = np.diff(t)
    cuts = np.flatnonzero(dt > GAP_FACTOR * float(np.median(dt))) + 1
    bounds = [0, *cuts.tolist(), n]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def per_segment(derive: Callable[..., np.ndarray], t: np.ndarray, *arrays: Optional[np.ndarray],
                parts: Optional[list] = None) -> np.ndarray:
    """
    Return ``derive(t, *arrays)`` computed on each stretch between gaps on its own.

    ``derive`` returns (n, k) rows for n stamps; a single stretch is derived
    whole (exactly ``derive(t, *arrays)``). None arrays pass as None.
    """
    parts = segments(t) if parts is None else parts
    if len(parts) == 1:
        return derive(t, *arrays)
    pieces = [derive(t[s], *(a[s] if a is not None else None for a in arrays)) for s in parts]
    return np.concatenate(pieces, axis=0)


def quat_products(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the Hamilton products a[i] * b[i] of quaternion rows (n, 4, [w x y z])."""
    return quat_multiply(a.T, b.T).T


def body_rate(t: np.ndarray, q: np.ndarray, h: int) -> np.ndarray:
    """Return the body rate (n, 3) rad/s from orientations ``q`` (n, 4, [w x y z]) over +-h."""
    n = t.size
    out = np.full((n, 3), np.nan)
    if n <= 2 * h:
        return out
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    dq = quat_products(qn[:-2 * h] * np.array([1.0, -1.0, -1.0, -1.0]), qn[2 * h:])
    dq *= np.sign(dq[:, :1] + 1e-300)
    vn = np.linalg.norm(dq[:, 1:], axis=1)
    ang = 2.0 * np.arctan2(vn, dq[:, 0])
    with np.errstate(invalid='ignore', divide='ignore'):
        axis = dq[:, 1:] / np.where(vn > 0, vn, 1.0)[:, None]
    out[h:n - h] = axis * (ang / (t[2 * h:] - t[:-2 * h]))[:, None]
    return out


def specific_force(t: np.ndarray, q: np.ndarray, p: Optional[np.ndarray], h: int,
                   g: float = GRAVITY) -> np.ndarray:
    """Return ``R^T (p'' + g)`` (n, 3) m/s^2, ``p''`` over +-h samples (gravity only without p)."""
    n = t.size
    acc = np.zeros((n, 3))
    if p is not None:
        acc = np.full((n, 3), np.nan)
        if n > 2 * h:
            span = 0.5 * (t[2 * h:] - t[:-2 * h])
            acc[h:n - h] = (p[2 * h:] - 2.0 * p[h:n - h] + p[:-2 * h]) / (span ** 2)[:, None]
    acc = acc + np.array([0.0, 0.0, g])
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    # rows of R^T are the world axes in the sensor frame
    r = np.stack((np.column_stack((1 - 2 * (y * y + z * z), 2 * (x * y + w * z),
                                   2 * (x * z - w * y))),
                  np.column_stack((2 * (x * y - w * z), 1 - 2 * (x * x + z * z),
                                   2 * (y * z + w * x))),
                  np.column_stack((2 * (x * z + w * y), 2 * (y * z - w * x),
                                   1 - 2 * (x * x + y * y)))), axis=1)
    return np.einsum('nij,nj->ni', r, acc)


def _noise_ratio(x: np.ndarray) -> float:
    """Return the white-noise level of ``x`` (robust, from second differences) over its RMS."""
    ok = np.all(np.isfinite(x), axis=1)
    xs = x[ok]
    if xs.shape[0] < 32:
        return np.inf
    d = np.diff(xs, 2, axis=0)
    noise = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(6.0)
    rms = np.sqrt(np.mean((xs - xs.mean(axis=0)) ** 2, axis=0))
    return float(np.max(noise / np.maximum(rms, 1e-12)))


def choose_half(derive, t: np.ndarray, rel_noise: float, max_half_s: float) -> int:
    """
    Return the smallest half width ``h`` (samples) whose derived signal is quiet enough.

    :param derive: ``h -> (n, 3)`` derived signal
    :param rel_noise: largest noise as a fraction of the signal's RMS
    :param max_half_s: largest half width (s)
    """
    dt = float(np.median(np.diff(t)))
    most = max(1, int(max_half_s / dt))
    h = 1
    while h < most and _noise_ratio(derive(h)) > rel_noise:
        h = min(most, 2 * h if h > 2 else h + 1)
    return h


def ideal_imu(t: np.ndarray, q: np.ndarray, p: Optional[np.ndarray] = None, g: float = GRAVITY,
              rel_noise: float = 0.02, max_half_s: float = 0.1) -> dict:
    """
    Return the ideal IMU of a ground-truth motion and the kernel of each of its channels.

    :param t: times (s)
    :param q: (n, 4) orientations ``[w x y z]`` of the sensor frame in the world (ENU)
    :param p: (n, 3) positions (m) of the sensor in the world, or None (gravity only)
    :param g: gravity (m/s^2)
    :param rel_noise: largest noise of a derived channel, as a fraction of its RMS
    :param max_half_s: largest half width of a differentiation window (s)
    :returns: ``{'gyro': (n, 3), 'accel': (n, 3), 'kernels': {'gyro': ('box', s),
        'accel': ('tri', s) or None}, 'half': {'gyro': h, 'accel': h}}``
    """
    t = np.asarray(t, float)
    parts = segments(t)

    def rate(h: int) -> np.ndarray:
        return per_segment(lambda ts, qs: body_rate(ts, qs, h), t, q, parts=parts)

    def force(h: int) -> np.ndarray:
        return per_segment(lambda ts, qs, ps: specific_force(ts, qs, ps, h, g), t, q, p,
                           parts=parts)
    hg = choose_half(rate, t, rel_noise, max_half_s)
    dt = float(np.median(np.diff(t)))
    gyro = rate(hg)
    if p is not None:
        ha = choose_half(force, t, rel_noise, max_half_s)
        accel = force(ha)
        acc_kernel = ('tri', ha * dt)
    else:
        ha = 0
        accel = specific_force(t, q, None, 1, g)
        acc_kernel = None
    return {'gyro': gyro, 'accel': accel,
            'kernels': {'gyro': ('box', hg * dt), 'accel': acc_kernel},
            'half': {'gyro': hg, 'accel': ha}}
