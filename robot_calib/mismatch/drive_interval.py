# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Standard deviations of the drive chain's parts: a block jackknife of the final fit.

The fitted samples are cut into ``J`` contiguous groups of equal count; the
chain (:func:`robot_calib.mismatch.drive.fit_axis`, the same named parts) is
fitted again ``J`` times, each time without one group, and each value's
standard deviation is the delete-a-group jackknife's (Efron and Stein 1981;
Kunsch 1989 for blocks of a dependent series):

    std = sqrt((J - 1) / J * sum_j (theta_j - mean_j theta_j)^2)

Contiguous groups keep the residuals' correlation in time (a lag's misfit
after each step) inside a group, so the spread is not that of independent
samples. The model is run over the whole time line each time; only the
samples the fit weighs change. The jackknife sees the noise, not the
approximation of the fit itself (block averages of the time line): that
part, measured on synthetic drives at up to 100 jackknife stds, is added
as a systematic part (:data:`COARSER`), so the std is an honest interval
rather than the precision of a biased estimate.
"""

from __future__ import annotations

from dataclasses import fields, is_dataclass
import math
from typing import Any, Callable, Optional

import numpy as np

MIN_GROUPS = 3
"""Fewest groups of a jackknife (fewer: no interval)."""
COARSER = 2
"""
The block averaging's error, in the std beside the jackknife's spread.

The chain runs on block means (``dt`` apart) and takes a block's mean
command as held over the block: the response comes out about half a block
late, which :func:`~robot_calib.mismatch.drive.analyse_drive` corrects by
reading the commands' block means that much later (d + tau of a known chain
of 0.35 s read 0.386 s on blocks of 5 samples before the correction); a
product (the turn speed loss's u |omega|) is taken of means, and a rate
limit acts on steps already smoothed by the block. Each value's systematic
part, added to the jackknife's spread in quadrature, is the larger of two
changes of it: in the final fit with the inputs read a further quarter block
later (the correction's own error), and in the final fit on blocks
``COARSER`` times longer, corrected alike (these errors grow with the block,
so that change is about their size or more).
"""


def groups(ok: np.ndarray, count: int) -> list:
    """Return ``count`` bool masks: the ``ok`` samples in contiguous groups of equal count."""
    idx = np.flatnonzero(ok)
    out = []
    for part in np.array_split(idx, count):
        g = np.zeros(ok.size, bool)
        g[part] = True
        out.append(g)
    return out


def jackknife_std(thetas: np.ndarray) -> np.ndarray:
    """Return the jackknife std of the rows ``thetas`` (one per left-out group), per column."""
    th = np.asarray(thetas, float)
    j = th.shape[0]
    return np.sqrt((j - 1) / j * np.sum((th - th.mean(axis=0)) ** 2, axis=0))


def block_jackknife(fit: Callable[[np.ndarray], Any], ok: np.ndarray,
                    count: int) -> Optional[dict]:
    """
    Return {field: std} of the float fields of the dataclass ``fit`` returns, or None.

    ``fit(w)`` fits on the samples ``w`` (bool) and returns a dataclass (an
    :class:`~robot_calib.mismatch.drive.AxisModel`); it is called once per
    group with that group left out of ``ok``. A field whose std is not finite
    or not positive (a value off its range in a refit, a grid value that never
    moves) is NaN: no interval can be given for it. None with fewer than
    :data:`MIN_GROUPS` groups or fewer ``ok`` samples than 10 per group.
    """
    if count < MIN_GROUPS or int(ok.sum()) < 10 * count:
        return None
    reps = [fit(ok & ~g) for g in groups(ok, count)]
    if not reps or not is_dataclass(reps[0]):
        return None
    out = {}
    for f in fields(reps[0]):
        vals = [getattr(r, f.name) for r in reps]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
            continue
        sd = float(jackknife_std(np.array(vals, float)[:, None])[0]) \
            if all(math.isfinite(v) for v in vals) else math.nan
        out[f.name] = sd if math.isfinite(sd) and sd > 0 else math.nan
    return out


def with_std(val: float, sd: float, scale: float = 1.0) -> str:
    """
    Return ``val`` times ``scale`` as text: ``'0.253 +- 0.031'``, or ``'0.253'`` without a std.

    The std to two significant digits and the value to the same decimal place;
    without a finite, positive ``sd`` the value to three significant digits
    (whole above 100).
    """
    v = val * scale
    if sd is None or not math.isfinite(sd) or sd <= 0:
        return f'{v:.3g}' if abs(v) < 100 else f'{v:.0f}'
    s = sd * scale
    places = max(0, 1 - math.floor(math.log10(s)))
    return f'{v:.{places}f} +- {s:.{places}f}'


def axis_std(u: np.ndarray, wabs: Optional[np.ndarray], y: np.ndarray, ok: np.ndarray,
             dt: float, acmd: Optional[np.ndarray], prm, m) -> Optional[dict]:
    """
    Return {field: std} of the drive model ``m`` of one axis (its units), or None.

    The block jackknife of :func:`~robot_calib.mismatch.drive.fit_axis` with
    ``m``'s named parts, refined as the final fit is, on the samples ``ok``
    (``prm.drive_jackknife_groups`` groups); arguments as ``fit_axis`` takes
    them, on the analyser's grid of block means ``dt`` (s) apart. With the
    block averaging's own error in quadrature (:data:`COARSER`).
    """
    from robot_calib.mismatch import drive as D  # drive calls this module

    if not m.parts:
        return None

    def fit(u, wabs, y, w, dt, acmd):
        return D.fit_axis(u, wabs, y, w, dt, prm.drive_max_dead_time, m.parts, refine=True,
                          acmd=acmd)

    sd = block_jackknife(lambda w: fit(u, wabs, y, w, dt, acmd), ok, prm.drive_jackknife_groups)
    if sd is None:
        return None
    half = fit(*(x if x is None else D.shift(x, 0.25 * dt, dt) for x in (u, wabs)), y, ok, dt,
               None if acmd is None else D.shift(acmd, 0.25 * dt, dt))
    n = u.size // COARSER
    late = 0.5 * (COARSER - 1) * dt  # the coarser blocks' own half-block correction
    a, b, d = (None if x is None else D.shift(D._blocks(x, COARSER, n), late, COARSER * dt)
               for x in (u, wabs, acmd))
    c = D._blocks(y, COARSER, n)
    w = D._blocks(ok.astype(float), COARSER, n) == 1.0
    coarse = fit(a, b, c, w, COARSER * dt, d) if w.sum() >= 100 else half
    out = {}
    with np.errstate(invalid='ignore'):
        for k, v in sd.items():
            sys_k = np.maximum(abs(getattr(half, k) - getattr(m, k)),
                               abs(getattr(coarse, k) - getattr(m, k)))
            out[k] = float(np.hypot(v, sys_k)) if np.isfinite(sys_k) else math.nan
    return out
