# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
An independent fit of a drive's response to its velocity commands, to check the analyser.

Written apart from :mod:`robot_calib.mismatch` (no code shared). Per axis the
measured speed is the command delayed by a dead time ``d`` and passed through
a first-order lag ``tau`` with a steady-state gain ``g``; the forward axis
also loses speed in turns (the turn-coupled speed loss ``k``, s/rad):

- turn: ``w(t) = g_w * F_tau_w[c_w(t - d_w)]``
- forward: ``v(t) = g_v * F_tau_v[c_v(t - d_v) * (1 - k |c_w(t - d_v)|)]``

``F_tau`` is the exact discrete first-order lag of a held input, ``y[n+1] =
a y[n] + (1 - a) u[n]``, ``a = exp(-dt / tau)`` (zero-order-hold
discretisation, e.g. Franklin, Powell, Workman, *Digital Control*, ch. 4).
With ``d`` and ``tau`` fixed the model is linear in ``g`` and ``g k`` (the lag is
linear), so the fit is a grid over (``d``, ``tau``) with linear least squares
inside, refined by :func:`scipy.optimize.least_squares` with a soft-L1 loss
(motion-capture outliers). Only samples where the measured speed exists are
used (gaps stay gaps). Standard errors from the refined Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lfilter


@dataclass
class FitParams:
    """Grid and limits of the fit (s)."""

    dead_max: float = 1.0
    dead_step: float = 0.02
    tau_min: float = 0.01
    tau_max: float = 2.0
    tau_points: int = 40
    rate: float = 50.0
    """Hz: the grid the model is evaluated on."""


def held(t_cmd: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Return the command held from each stamp until the next (zero before the first)."""
    idx = np.searchsorted(t_cmd, t, side='right') - 1
    return np.where(idx >= 0, x[np.clip(idx, 0, None)], 0.0)


def lag(u: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """Return a held input ``u`` passed through a first-order filter of time constant ``tau`` s."""
    if tau <= 1e-6:
        return u.copy()
    a = np.exp(-dt / tau)
    y = lfilter([0.0, 1.0 - a], [1.0, -a], u, zi=[a * u[0]])[0]
    return y


def _regressors(axis: str, t_cmd, v_cmd, w_cmd, grid, d):
    cv, cw = held(t_cmd, v_cmd, grid - d), held(t_cmd, w_cmd, grid - d)
    if axis == 'turn':
        return [cw]
    return [cv, cv * np.abs(cw)]


def _predict(axis, t_cmd, v_cmd, w_cmd, grid, t_meas, d, tau, coef, dt):
    regs = _regressors(axis, t_cmd, v_cmd, w_cmd, grid, d)
    y = sum(c * np.interp(t_meas, grid, lag(r, dt, tau)) for c, r in zip(coef, regs))
    return y


def fit_axis(axis: str, t_cmd: np.ndarray, v_cmd: np.ndarray, w_cmd: np.ndarray,
             t_meas: np.ndarray, y_meas: np.ndarray,
             prm: Optional[FitParams] = None) -> dict:
    """
    Fit one axis (``'forward'`` or ``'turn'``); return d, tau (s), gain, k (s/rad), errors.

    ``t_meas``, ``y_meas``: the measured speed (m/s or rad/s), NaN or absent
    where there is none.
    """
    prm = prm or FitParams()
    ok = np.isfinite(y_meas)
    tm, ym = t_meas[ok], y_meas[ok]
    dt = 1.0 / prm.rate
    grid = np.arange(tm[0] - 2.0, tm[-1] + dt, dt)
    best = (np.inf, 0.0, 0.0, None)
    taus = np.geomspace(prm.tau_min, prm.tau_max, prm.tau_points)
    for d in np.arange(0.0, prm.dead_max + 1e-9, prm.dead_step):
        regs = _regressors(axis, t_cmd, v_cmd, w_cmd, grid, d)
        for tau in taus:
            a = np.column_stack([np.interp(tm, grid, lag(r, dt, tau)) for r in regs])
            coef, *_ = np.linalg.lstsq(a, ym, rcond=None)
            sse = float(np.sum((ym - a @ coef) ** 2))
            if sse < best[0]:
                best = (sse, d, tau, coef)

    def resid(p):
        return _predict(axis, t_cmd, v_cmd, w_cmd, grid, tm, p[0], p[1], p[2:], dt) - ym

    x0 = np.concatenate(([best[1], best[2]], best[3]))
    lo = np.concatenate(([0.0, 1e-3], np.full(len(best[3]), -np.inf)))
    hi = np.concatenate(([prm.dead_max + 0.5, prm.tau_max * 2], np.full(len(best[3]), np.inf)))
    sol = least_squares(resid, np.clip(x0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi),
                        loss='soft_l1', f_scale=float(np.std(ym - ym.mean()) * 0.2 + 1e-6),
                        diff_step=1e-3)
    p = sol.x
    r = resid(p)
    dof = max(1, r.size - p.size)
    try:
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * float(np.sum(r ** 2)) / dof
        err = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        err = np.full(p.size, np.nan)
    out = {'dead_time': float(p[0]), 'tau': float(p[1]), 'gain': float(p[2]),
           'dead_time_se': float(err[0]), 'tau_se': float(err[1]), 'gain_se': float(err[2]),
           'rms': float(np.sqrt(np.mean(r ** 2))), 'samples': int(tm.size)}
    if axis == 'forward':
        k = -p[3] / p[2] if p[2] != 0 else float('nan')
        out['k'] = float(k)
        # delta method for k = -b / a
        if np.all(np.isfinite(err)):
            jk = np.array([p[3] / p[2] ** 2, -1.0 / p[2]])
            out['k_se'] = float(np.sqrt(jk @ cov[2:4, 2:4] @ jk))
    return out


def steady_ratios(t_cmd: np.ndarray, v_cmd: np.ndarray, w_cmd: np.ndarray, t: np.ndarray,
                  v: np.ndarray, w: np.ndarray, settle: float = 1.0) -> dict:
    """
    Return median measured/commanded ratios where the command has been steady ``settle`` s.

    ``straight``: forward speed where the turn command is below 0.01 rad/s and
    the speed command above 0.05 m/s; ``turn``: turn rate where the turn
    command exceeds 0.05 rad/s (model-free check of the steady-state gains).
    """
    idx = np.searchsorted(t_cmd, t, side='right') - 1
    ok = idx >= 0
    i = np.clip(idx, 0, None)
    change = np.concatenate(([True], (np.diff(v_cmd) != 0) | (np.diff(w_cmd) != 0)))
    last = np.maximum.accumulate(np.where(change, np.arange(t_cmd.size), 0))
    since = t - t_cmd[last[i]]
    ok &= since >= settle
    cv, cw = v_cmd[i], w_cmd[i]
    st = ok & (np.abs(cw) < 0.01) & (cv > 0.05) & np.isfinite(v)
    tn = ok & (np.abs(cw) > 0.05) & np.isfinite(w)
    return {'straight': float(np.median(v[st] / cv[st])) if st.any() else float('nan'),
            'straight_samples': int(st.sum()),
            'turn': float(np.median(w[tn] / cw[tn])) if tn.any() else float('nan'),
            'turn_samples': int(tn.sum())}


def fit_pair(pair, prm: Optional[FitParams] = None) -> dict:
    """Fit both axes of a :class:`drive_pairs.DrivePair` with commands; return {axis: fit}."""
    c, r = pair.cmd, pair.real
    return {'forward': fit_axis('forward', c['t'], c['v'], c['w'], r['t'], r['v'], prm),
            'turn': fit_axis('turn', c['t'], c['v'], c['w'], r['t'], r['w'], prm),
            'steady': steady_ratios(c['t'], c['v'], c['w'], r['t'], r['v'], r['w'])}


def main() -> None:
    """Print the fit of every MR.CLAM pair."""
    import drive_pairs as D
    for p in D.mrclam_pairs():
        f = fit_pair(p)
        fw, tn = f['forward'], f['turn']
        print(f'{p.name}: forward d {fw["dead_time"]:.3f} tau {fw["tau"]:.3f} '
              f'gain {fw["gain"]:.3f} k {fw["k"]:.2f}+-{fw.get("k_se", np.nan):.2f} | '
              f'turn d {tn["dead_time"]:.3f} tau {tn["tau"]:.3f} gain {tn["gain"]:.3f} | '
              f'steady straight {f["steady"]["straight"]:.3f} turn {f["steady"]["turn"]:.3f}')


if __name__ == '__main__':
    main()
