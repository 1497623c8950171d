# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The drive chain's pieces (:mod:`.drive` fits them): one axis' model and its response.

    u1 = u |u| > band ? u : 0                        drive_deadband (band)
    u2 = u1 (1 - k |omega_sim|)       (forward only) turn_speed_loss (k, s/rad)
    u3 = rate limited u2, |du3/dt| <= limit          drive_rate_limit (limit)
    u4 = u3 (t - d)                                  drive_dead_time (d, s)
    y  = (1 + g) lag(u4, tau)                        drive_lag (tau, s), drive_gain (g)

where the lag is first order, or second order with a damping zeta (``drive_lag``'s
``damping``) and the same mean delay tau.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Optional

import numpy as np
from robot_calib.sim.drive import second_order_coefficients
from scipy.signal import lfilter, lfilter_zi


@dataclass
class AxisModel:
    """One axis: dead time d, lag tau (s), band, rate limit, gain g, k (s/rad), slip (s^2/m)."""

    d: float = 0.0
    tau: float = 0.0
    band: float = 0.0
    limit: float = math.inf
    gain: float = 0.0
    k: float = 0.0
    slip: float = 0.0
    parts: set = field(default_factory=set)
    fixed_gain: bool = False  # g held at 0 (the reduced model of the gain's test)
    zeta: float = 0.0  # damping of a second-order response of mean delay tau (0: first order)


def deadband(u: np.ndarray, band: float) -> np.ndarray:
    """Return ``u`` with values of magnitude <= ``band`` set to zero (contract drive_deadband)."""
    return np.where(np.abs(u) > band, u, 0.0) if band > 0 else u


_LIMITED: dict = {}


def rate_limit(u: np.ndarray, dt: float, limit: float) -> np.ndarray:
    """Return ``u`` changing by at most ``limit`` per second (units of u per s)."""
    if not math.isfinite(limit) or limit <= 0:
        return u
    key = (hash(u.tobytes()), u.shape, float(dt), float(limit))  # the grids ask again
    if key not in _LIMITED:
        if len(_LIMITED) > 512:
            _LIMITED.clear()
        _LIMITED[key] = _rate_limit(u, dt, limit)
    return _LIMITED[key].copy()


def _rate_limit(u: np.ndarray, dt: float, limit: float) -> np.ndarray:
    step = limit * dt
    out = np.empty(u.size)
    y = float(u[0])
    for i, x in enumerate(u.tolist()):
        y += min(max(x - y, -step), step)
        out[i] = y
    return out


def lag(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """Return ``x`` through ``1 / (1 + s tau)``, exact discretisation, at rest on ``x[0]``."""
    if tau <= 0:
        return x
    a = math.exp(-dt / tau)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, axis=0, zi=np.atleast_1d(a * x[0])
                   if x.ndim == 1 else a * x[:1])
    return y


def response(x: np.ndarray, dt: float, tau: float, zeta: float = 0.0) -> np.ndarray:
    """Return ``x`` through the first-order lag ``tau`` (s), or the second order (``zeta`` > 0)."""
    if zeta <= 0 or tau <= 0:
        return lag(x, dt, tau)
    b, a = second_order_coefficients(float(dt), float(tau), float(zeta))
    zi = lfilter_zi(b, a)
    y, _ = lfilter(b, a, x, axis=0, zi=zi * x[0] if x.ndim == 1 else zi[:, None] * x[:1])
    return y


def shift(x: np.ndarray, d: float, dt: float) -> np.ndarray:
    """Return ``x`` delayed by ``d`` s (linear interpolation, held at the start)."""
    if d <= 0:
        return x
    s = d / dt
    i = int(math.floor(s))
    f = s - i

    def late(k: int) -> np.ndarray:
        if k <= 0:
            return x
        k = min(k, x.shape[0])
        return np.concatenate((np.repeat(x[:1], k, axis=0), x[:x.shape[0] - k]), axis=0)
    return late(i) if f == 0.0 else (1.0 - f) * late(i) + f * late(i + 1)


def _filled(x: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x)
    if ok.all() or ok.sum() < 2:
        return np.nan_to_num(x)
    return np.interp(np.arange(x.size), np.flatnonzero(ok), x[ok])


def regressors(u: np.ndarray, wabs: Optional[np.ndarray], dt: float, m: AxisModel,
               coupled: bool, acmd: Optional[np.ndarray] = None) -> np.ndarray:
    """
    Return the response columns: chain(u); forward, chain(u |omega|) and slip.

    The slip column is chain(u) times the commanded acceleration ``acmd``
    through the same dead time and lag (m^2/s^3): wheel slip, fitted with the
    dynamics so that the lag is not biased by it, judged by the amplitude stage.
    """
    u1 = deadband(u, m.band)
    cols = [u1] + ([u1 * wabs] if coupled and wabs is not None else [])
    out = [response(rate_limit(c, dt, m.limit), dt, m.tau, m.zeta) for c in cols]
    if acmd is not None:
        out.append(out[0] * response(acmd, dt, m.tau, m.zeta))
    return shift(np.column_stack(out), m.d, dt)


def predict(u: np.ndarray, wabs: Optional[np.ndarray], dt: float, m: AxisModel,
            gain: bool = True, acmd: Optional[np.ndarray] = None) -> np.ndarray:
    """
    Return the modelled real channel (exact chain, k applied before the rate limit).

    ``gain``: with the steady-state gain and the slip term (False: the dynamics alone).
    """
    u1 = deadband(u, m.band)
    if wabs is not None and m.k:
        u1 = u1 * (1.0 - m.k * wabs)
    y = shift(response(rate_limit(u1, dt, m.limit), dt, m.tau, m.zeta), m.d, dt)
    if not gain:
        return y
    y = (1.0 + m.gain) * y
    if acmd is not None and m.slip:
        y = y + m.slip * shift(response(rate_limit(deadband(u, m.band), dt, m.limit), dt,
                                        m.tau, m.zeta) * response(acmd, dt, m.tau, m.zeta),
                               m.d, dt)
    return y
