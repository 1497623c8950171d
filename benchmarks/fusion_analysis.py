# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Analysis for the fusion benchmark: GPS metrics, hindsight bounds and what the sensors can tell.

Nothing here is a method: the bounds choose their constants knowing the GPS
answer, so they say how far a causal filter could get with a model of that
shape, and the sensor analyses say which of those constants the robot's own
sensors could have told it.

- :func:`score`: ATE and final error after one SE(2) alignment (no scale).
- :func:`hindsight_bounds`: gyro + wheel-speed dead reckoning with the constant
  gyro bias (and wheel-speed scale) that minimise the ATE against the GPS.
- :func:`standstill_gyro_bias`: what the gyro reads while the wheels are
  exactly still (what a causal filter can learn, and when).
- :func:`accel_speed_events`: for each speed change, the accelerometer's
  velocity change over the wheels' (its median is the wheel-speed scale the
  accelerometer would teach a filter).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from robot_calib.core.geometry import wrap_angle
from scipy.optimize import minimize

EARTH_R = 6378137.0
"""WGS-84 equatorial radius (m)."""


def enu(fixes: list) -> np.ndarray:
    """Return (N, 3) [t, east, north] (s, m, m) of NavSat fixes about the first one."""
    lat0, lon0 = fixes[0].latitude, fixes[0].longitude
    return np.array([[f.t, math.radians(f.longitude - lon0) * EARTH_R * math.cos(
        math.radians(lat0)), math.radians(f.latitude - lat0) * EARTH_R] for f in fixes])


def align(t: np.ndarray, xy: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, float]:
    """
    Align an estimate (interpolated at ``ref[:, 0]``) to ``ref[:, 1:3]`` with one SE(2).

    :return: (errors m at each reference sample, rotation rad of the alignment)
    """
    est = np.column_stack([np.interp(ref[:, 0], t, xy[:, 0]), np.interp(ref[:, 0], t, xy[:, 1])])
    a = est - est.mean(0)
    b = ref[:, 1:3] - ref[:, 1:3].mean(0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rot = vt.T @ d @ u.T
    err = np.linalg.norm(a @ rot.T - b, axis=1)
    return err, math.atan2(rot[1, 0], rot[0, 0])


def score(t, xy, yaw, ref) -> dict:
    """Return ATE (m), final error (m), final heading error (rad, when ref has yaw)."""
    err, rot = align(np.asarray(t), np.asarray(xy), ref)
    out = {'ate': float(np.sqrt(np.mean(err ** 2))), 'final': float(err[-1]),
           'end_from_start': float(np.hypot(*(np.asarray(xy)[-1] - np.asarray(xy)[0])))}
    if ref.shape[1] > 3:
        out['heading'] = abs(wrap_angle(float(yaw[-1]) + rot - float(ref[-1, 3])))
    return out


def dead_reckoning(gyro: np.ndarray, wheels: np.ndarray, bias: float, scale: float = 1.0,
                   bias_until: float = -math.inf) -> dict:
    """
    Return the track of gyro heading + wheel-speed dead reckoning.

    :param gyro: (N, 2) [t s, yaw rate rad/s in base_link]
    :param wheels: (M, 2) [t s, forward speed m/s]
    :param bias: gyro bias subtracted (rad/s), from ``bias_until`` (s) on (0 before)
    :param scale: wheel-speed scale (true speed / wheel speed)
    :return: trajectory arrays t, xy, yaw at the wheel stamps
    """
    b = np.where(gyro[:, 0] >= bias_until, bias, 0.0)
    th = np.concatenate([[0.0], np.cumsum(np.diff(gyro[:, 0]) * (gyro[:-1, 1] - b[:-1]))])
    yaw = np.interp(wheels[:, 0], gyro[:, 0], th)
    step = np.diff(wheels[:, 0]) * wheels[:-1, 1] * scale
    xy = np.column_stack([np.concatenate([[0.0], np.cumsum(step * np.cos(yaw[:-1]))]),
                          np.concatenate([[0.0], np.cumsum(step * np.sin(yaw[:-1]))])])
    return {'t': wheels[:, 0], 'xy': xy, 'yaw': yaw}


def _best_bias(cost: Callable[[float], float], span: float = 0.005) -> float:
    """Return the bias (rad/s) minimising ``cost``: a grid over +-span, then refined."""
    grid = np.linspace(-span, span, 201)
    b0 = float(grid[int(np.argmin([cost(b) for b in grid]))])
    res = minimize(lambda p: cost(float(p[0])), [b0], method='Nelder-Mead',
                   options={'xatol': 1e-7, 'fatol': 1e-6})
    return float(res.x[0])


def hindsight_bounds(gyro: np.ndarray, wheels: np.ndarray, ref: np.ndarray) -> dict:
    """
    Return the dead-reckoning bounds that choose their constants knowing the answer.

    ``bias``: the constant gyro bias minimising the ATE against ``ref``;
    ``bias_scale``: the gyro bias and the wheel-speed scale together. Each is a dict
    with ``ate``, ``final`` (m), ``bias`` (rad/s) and ``scale``.
    """
    def ate(b: float, k: float = 1.0) -> float:
        return score(**dead_reckoning(gyro, wheels, b, k), ref=ref)['ate']

    b1 = _best_bias(ate)
    res = minimize(lambda p: ate(float(p[0]), float(p[1])), [b1, 1.0], method='Nelder-Mead',
                   options={'xatol': 1e-7, 'fatol': 1e-6, 'maxiter': 2000})
    b2, k2 = (float(v) for v in res.x)
    out = {}
    for name, b, k in (('bias', b1, 1.0), ('bias_scale', b2, k2)):
        sc = score(**dead_reckoning(gyro, wheels, b, k), ref=ref)
        out[name] = {'ate': sc['ate'], 'final': sc['final'], 'bias': b, 'scale': k}
    return out


def standstill_gyro_bias(gyro: np.ndarray, wheels: np.ndarray, still_speed: float = 1e-3,
                         margin: float = 0.5) -> tuple[float, float, float, float]:
    """
    Return (mean gyro rad/s, its standard error, first still time s, still time s).

    The wheels are still where both speed and yaw rate are below ``still_speed``
    (``wheels`` columns: t, v, w); ``margin`` (s) is dropped at both ends of each
    still period. NaNs when the wheels are never still that long.
    """
    still = (np.abs(wheels[:, 1]) < still_speed) & (np.abs(wheels[:, 2]) < still_speed)
    mask = np.zeros(len(gyro), bool)
    first, total = math.nan, 0.0
    i = 0
    while i < len(still):
        if not still[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(still) and still[j + 1]:
            j += 1
        ta, tb = wheels[i, 0] + margin, wheels[j, 0] - margin
        if tb > ta:
            mask |= (gyro[:, 0] > ta) & (gyro[:, 0] < tb)
            first = ta if math.isnan(first) else first
            total += tb - ta
        i = j + 1
    if mask.sum() < 10:
        return math.nan, math.nan, math.nan, 0.0
    z = gyro[mask, 1]
    return float(z.mean()), float(z.std() / math.sqrt(len(z))), first, total


def accel_speed_events(accel: np.ndarray, wheels: np.ndarray, min_dv: float = 0.3,
                       min_accel: float = 0.1, pad: float = 2.0) -> list:
    """
    Return per speed change (start s, duration s, wheel dv m/s, accel dv / wheel dv, shift).

    A speed change is where the wheel speed (5-sample mean) changes faster than
    ``min_accel`` (m/s^2), joined across pauses under 10 samples and widened to
    where it changes slower than a quarter of that, by at least ``min_dv``. The
    accelerometer's dv integrates its forward specific force (``accel`` columns:
    t, m/s^2) minus a baseline interpolated between its means over ``pad`` (s)
    before and after: bias, mounting tilt and slope, taken as linear across the
    event; ``shift`` (m/s^2) is the baseline after minus before.
    A scale learnt from the accelerometer is, at best, the median of these ratios.
    """
    t, v = wheels[:, 0], wheels[:, 1]
    smooth = np.convolve(v, np.ones(5) / 5, mode='same')
    rate = np.abs(np.gradient(smooth, t))
    changing, settling = rate > min_accel, rate > min_accel / 4
    events, i = [], 0
    while i < len(t):
        if not changing[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(t) and changing[j + 1:j + 11].any():
            j += 1
        while i > 0 and settling[i - 1]:  # out to where the speed has settled
            i -= 1
        while j + 1 < len(t) and settling[j + 1]:
            j += 1
        ta, tb = t[i] - 0.3, t[j] + 0.3
        dv = float(np.interp(tb, t, v) - np.interp(ta, t, v))
        before = (accel[:, 0] > ta - pad) & (accel[:, 0] < ta)
        after = (accel[:, 0] > tb) & (accel[:, 0] < tb + pad)
        inside = (accel[:, 0] >= ta) & (accel[:, 0] <= tb)
        if abs(dv) >= min_dv and before.sum() >= 5 and after.sum() >= 5:
            ends = [accel[before, 1].mean(), accel[after, 1].mean()]
            base = np.interp(accel[inside, 0], [ta, tb], ends)
            dv_acc = float(np.trapezoid(accel[inside, 1] - base, accel[inside, 0]))
            events.append((float(ta), float(tb - ta), dv, dv_acc / dv, ends[1] - ends[0]))
        i = j + 1
    return events


def gps_wander(ref: np.ndarray, wheels: np.ndarray, window: float = 4.0) -> float:
    """
    Return the RMS difference (m) of GPS displacement and wheel distance over windows.

    Only windows of straight driving (``wheels`` columns t, v, w; |w| < 0.02 rad/s).
    """
    t = wheels[:, 0]
    dist = np.concatenate([[0.0], np.cumsum(np.abs(wheels[:-1, 1]) * np.diff(t))])
    diffs = []
    for t0 in np.arange(ref[0, 0], ref[-1, 0] - window, window):
        a, b = np.searchsorted(ref[:, 0], [t0, t0 + window])
        if b - a < 5:
            continue
        w = np.interp([t0, t0 + window], t, dist)
        m = (t >= t0) & (t < t0 + window)
        if m.any() and np.abs(wheels[m, 2]).max() < 0.02:
            diffs.append(np.hypot(*(ref[b - 1, 1:3] - ref[a, 1:3])) - (w[1] - w[0]))
    return float(np.sqrt(np.mean(np.square(diffs)))) if diffs else float('nan')
