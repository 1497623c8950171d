# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A topic's residual problem: residuals, masks, noise levels; held-out chunks.

Shared by the time stage (:mod:`.timing`) and the effect selection
(:mod:`.analysis`).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from robot_calib.mismatch import select as S
from robot_calib.mismatch.channels import PairedTopic
from robot_calib.mismatch.locate import noise_level


def noise_floor(res: np.ndarray, m: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Return the smallest noise level used (noiseless data): keeps chi2 well conditioned."""
    scale = max(float(np.sqrt(np.mean(b[m] ** 2))), float(np.sqrt(np.mean(a[m] ** 2))))
    return max(1e-3 * float(np.sqrt(np.mean(res[m] ** 2))), 1e-9 * scale, 1e-12)


def channel_noise(a: np.ndarray, b: np.ndarray, m: np.ndarray, dt: float,
                  smooth: float) -> tuple[np.ndarray, float, float]:
    """
    Return the residual ``b - a`` (0 outside ``m``), its noise level and its variance inflation.

    The noise level of :func:`noise_level` (``smooth``: the moving average
    removed first, s), never below :func:`noise_floor`; ``dt``: grid period (s).
    """
    res = np.where(m, b - a, 0.0)
    s, ph = noise_level(res, m, dt, smooth)
    return res, max(s, noise_floor(res, m, a, b)), ph


def make_problem(pt: PairedTopic, smooth: float,
                 not_judged: Optional[list]) -> Optional[S.Problem]:
    """
    Return the residual problem of a paired topic, or None when no channel can be judged.

    Channels with too few overlapping samples, or a real channel that is
    constant while the simulated one varies, go into ``not_judged`` (when given).
    """
    fields, r, mask, sigma, phi = [], {}, {}, {}, {}
    for f in pt.sim:
        a, b = pt.sim[f], pt.real[f]
        m = np.isfinite(a) & np.isfinite(b)
        ch = f'{pt.name}.{f}'
        if m.sum() < 20:
            if not_judged is not None:
                not_judged.append({'channel': ch, 'reason': 'empty: no overlapping samples'})
            continue
        if np.ptp(b[m]) == 0 and np.ptp(a[m]) > 0:
            if not_judged is not None:
                not_judged.append({'channel': ch, 'reason': 'the real channel is constant while '
                                   'the simulated one varies (a stuck or unfilled field)'})
            continue
        res, s, ph = channel_noise(a, b, m, pt.dt, smooth)
        fields.append(f)
        r[f], mask[f], sigma[f], phi[f] = res, m, s, ph
    if not fields:
        return None
    return S.Problem(pt, fields, r, mask, sigma, phi, pt.t.size)


def rmse(x: np.ndarray, m: np.ndarray) -> Optional[float]:
    return float(np.sqrt(np.mean(x[m] ** 2))) if m.any() else None


def held_mask(n: int, chunks: int) -> np.ndarray:
    chunk = max(1, n // chunks)
    return ((np.arange(n) // chunk) % 3) == 2
