# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The incidence angle of each lidar beam on the surface it hits, from the scan alone."""

from __future__ import annotations

import numpy as np


def incidence(ranges: np.ndarray, angles: np.ndarray, span: int = 1,
              tol: float = 0.03) -> np.ndarray:
    """
    Return the incidence angle (rad, 0: along the surface normal) of each beam (S, B).

    The surface's local direction is taken from the hit points of the
    neighbouring beam on the side whose range differs less (an edge has a
    jump on one side only); beams without a finite neighbour get 0. With
    ``span`` k > 1 the direction is the chord to the k-th beam on that side
    when the beams up to it are finite (a range noise of sigma turns a chord of
    length L by about sigma / L: k times less) and the beams between lie within
    ``tol`` (m) of it (one surface), else to the neighbour.
    """
    with np.errstate(invalid='ignore'):  # inf - inf, inf * 0: no neighbour, caught below
        px, py = ranges * np.cos(angles), ranges * np.sin(angles)
        inf = np.full(ranges.shape[:-1] + (1,), np.inf)
        dr_prev = np.abs(np.concatenate((inf, np.diff(ranges, axis=-1)), axis=-1))
        dr_next = np.abs(np.concatenate((np.diff(ranges, axis=-1), inf), axis=-1))
        use_next = ~(dr_prev <= dr_next)
        tx = np.where(use_next, np.roll(px, -1, axis=-1) - px, px - np.roll(px, 1, axis=-1))
        ty = np.where(use_next, np.roll(py, -1, axis=-1) - py, py - np.roll(py, 1, axis=-1))
        ok_n = ok_p = np.isfinite(ranges)
        for k in range(2, span + 1):
            ok_n = ok_n & np.isfinite(np.roll(ranges, 1 - k, axis=-1))
            ok_p = ok_p & np.isfinite(np.roll(ranges, k - 1, axis=-1))
        if span > 1:
            kx = np.where(use_next, np.roll(px, -span, axis=-1) - px,
                          px - np.roll(px, span, axis=-1))
            ky = np.where(use_next, np.roll(py, -span, axis=-1) - py,
                          py - np.roll(py, span, axis=-1))
            far = np.where(use_next, ok_n & np.isfinite(np.roll(ranges, -span, axis=-1)),
                           ok_p & np.isfinite(np.roll(ranges, span, axis=-1)))
            kn = np.hypot(kx, ky)
            for j in range(1, span):  # the points between within tol of the chord: one surface
                mx = np.where(use_next, np.roll(px, -j, axis=-1) - px,
                              np.roll(px, j, axis=-1) - px)
                my = np.where(use_next, np.roll(py, -j, axis=-1) - py,
                              np.roll(py, j, axis=-1) - py)
                far &= np.abs(mx * ky - my * kx) <= tol * kn
            tx, ty = np.where(far, kx, tx), np.where(far, ky, ty)
        tn = np.hypot(tx, ty)
        # |sin| of the angle between beam and surface = cos(incidence)
        cos_inc = np.abs(np.cos(angles) * ty - np.sin(angles) * tx) / tn
    out = np.arccos(np.clip(cos_inc, 0.0, 1.0))
    return np.where(np.isfinite(out) & (np.minimum(dr_prev, dr_next) < np.inf), out, 0.0)
