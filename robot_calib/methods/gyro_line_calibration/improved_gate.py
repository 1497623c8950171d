# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Line-to-reference matching of the improved ``gyro_line_calibration`` variant.

A new line (world frame of the estimate) is compared with a reference line by
its innovation ``y = (reference angle - line angle (rad, modulo pi),
reference rho - n . line midpoint (m))``, whose Jacobian with respect to the
state ``[x, y, heading, gyro bias, gyro scale]`` is ``H`` (2 x 5). A
vectorised pre-filter (:func:`prefilter`: angle, overlap along the line,
loose distance) keeps the candidates; :func:`gate` keeps those whose
innovation passes a chi-square gate built from the pose covariance, the
reference's own covariance and the fit noise.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from robot_calib.core.geometry import wrap_half_pi
from robot_calib.core.lines import Line
from robot_calib.methods.gyro_line_calibration.params import ImprovedParams


LOCK_ANGLE = math.radians(30.0)
"""Largest angle (rad) between a line and a reference it lies on (the lock check)."""
LOCK_DISTANCE = 0.3
"""Largest distance (m) of a line's midpoint from a reference it lies on."""


def line_noise_diag(line: Line, ip: ImprovedParams) -> tuple[float, float]:
    """Return the variances (angle rad^2, distance m^2) of a fitted line (independent)."""
    sa = line.angle_sigma() ** 2 + ip.line_angle_sigma ** 2
    sr = line.variance / max(line.n_cells, 1) + ip.line_sigma ** 2
    return sa, sr


def line_noise(line: Line, ip: ImprovedParams) -> np.ndarray:
    """Return the covariance (angle rad^2, distance m^2) of a fitted line."""
    sa, sr = line_noise_diag(line, ip)
    return np.array([[sa, 0.0], [0.0, sr]])


def line_jacobian(line: Line, normal: np.ndarray, position: np.ndarray) -> np.ndarray:
    """
    Return H (2 x 5) of the angle and the distance along ``normal`` of ``line``.

    ``position`` is the robot's (x, y) (m) the line is seen from.
    """
    lever = line.midpoint - position
    H = np.zeros((2, 5))
    H[0, 2] = 1.0
    H[1, 0], H[1, 1] = normal[0], normal[1]
    H[1, 2] = float(normal @ np.array([-lever[1], lever[0]]))
    return H


def line_model(ref: Line, line: Line, position: np.ndarray) -> tuple:
    """
    Return (innovation y, Jacobian H (2 x 5), lever s (m)) of a line against a reference.

    ``position`` is the robot's (x, y) (m); ``s`` is the line midpoint's offset
    along the reference from the reference midpoint.
    """
    n = ref.normal
    m = line.midpoint
    y = np.array([wrap_half_pi(ref.angle - line.angle), ref.rho - float(n @ m)])
    H = line_jacobian(line, n, position)
    s = float(ref.direction @ (m - ref.midpoint))
    return y, H, s


def overlaps(ref: Line, line: Line, margin: float) -> bool:
    """Return True when ``line`` projected on ``ref`` overlaps it within ``margin`` (m)."""
    u = ref.direction
    o = float(u @ ref.p1)
    r1, r2 = 0.0, float(u @ ref.p2) - o
    a, b = sorted((float(u @ line.p1) - o, float(u @ line.p2) - o))
    return b >= r1 - margin and a <= r2 + margin


def ref_arrays(refs: list) -> tuple:
    """Return angle, direction, normal, start offset, extent and rho arrays of references."""
    ang = np.array([r.line.angle for r in refs])
    u = np.column_stack((np.cos(ang), np.sin(ang)))
    nrm = np.column_stack((-u[:, 1], u[:, 0]))
    p1 = np.array([r.line.p1 for r in refs])
    p2 = np.array([r.line.p2 for r in refs])
    o = np.einsum('ij,ij->i', u, p1)
    r2 = np.einsum('ij,ij->i', u, p2) - o
    rho = np.einsum('ij,ij->i', nrm, p1)
    return ang, u, nrm, o, r2, rho


def prefilter(refs: list, lines: list[Line], margin: float, angle_tolerance: float,
              arrays: Optional[tuple] = None) -> tuple:
    """
    Vectorised (lines x references) pre-filter: angle, overlap, distance (loose).

    Returns the angle errors (rad), distances (m), the candidate mask (each a
    list of rows, one per line, one entry per reference) and the references'
    directions and normals (lists of pairs), as Python lists for :func:`gate`,
    then whether each line lies on a reference (:data:`LOCK_ANGLE`,
    :data:`LOCK_DISTANCE`, its midpoint along it), whatever the tolerances.
    """
    ang, u, nrm, o, r2, rho = arrays if arrays is not None else ref_arrays(refs)
    la = np.array([ln.angle for ln in lines])
    lp1 = np.array([ln.p1 for ln in lines])
    lp2 = np.array([ln.p2 for ln in lines])
    err = wrap_half_pi(ang[None, :] - la[:, None])
    a1 = lp1 @ u.T - o[None, :]
    a2 = lp2 @ u.T - o[None, :]
    lo, hi = np.minimum(a1, a2), np.maximum(a1, a2)
    dist = rho[None, :] - (0.5 * (lp1 + lp2)) @ nrm.T
    abs_err, abs_dist = np.abs(err), np.abs(dist)
    ok = (abs_err <= angle_tolerance) & (hi >= -margin) & (lo <= r2[None, :] + margin) \
        & (abs_dist < margin + 1.0)
    along = 0.5 * (a1 + a2)  # the midpoint's offset along the reference
    on = (abs_err <= LOCK_ANGLE) & (along >= 0.0) & (along <= r2[None, :]) \
        & (abs_dist <= LOCK_DISTANCE)
    return err.tolist(), dist.tolist(), ok.tolist(), u.tolist(), nrm.tolist(), \
        on.any(axis=1).tolist()


def gate_state(x: np.ndarray, P: np.ndarray) -> tuple:
    """Return what :func:`gate` reads of the state ``x`` and covariance ``P``, as floats."""
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = P[:3, :3].tolist()
    x0, x1 = x[:2].tolist()
    return p00, p01, p02, p11, p12, p22, x0, x1


def gate(refs: list, line: Line, margin: float, chi2: float, state: tuple,
         noise: tuple[float, float], angle_tolerance: float,
         pre: Optional[tuple] = None) -> list[tuple]:
    """
    Return the references whose innovation with ``line`` passes the chi-square gate ``chi2``.

    ``state`` is :func:`gate_state` of the state and its covariance, ``noise``
    the line's :func:`line_noise_diag`, ``pre`` this line's row of
    :func:`prefilter` (computed when None). Each entry is ``(nis, reference,
    y, None, R)`` with ``y`` the innovation (angle rad, distance m) and ``R``
    its covariance without the pose part (rows of a 2 x 2 matrix), as tuples.
    """
    if not refs:
        return []
    if pre is None:
        err, dist, ok, u, nrm, _ = prefilter(refs, [line], margin, angle_tolerance)
        pre = (err[0], dist[0], ok[0], u, nrm)
    err, dist, ok, u, nrm = pre
    out = []
    if not any(ok):
        return out
    p00, p01, p02, p11, p12, p22, x0, x1 = state
    mx, my = line.midpoint.tolist()
    lx, ly = mx - x0, my - x1
    rl0, rl1 = noise
    for i, cand in enumerate(ok):
        if not cand:
            continue
        ref = refs[i]
        (nx, ny), (ux, uy) = nrm[i], u[i]
        y0, y1 = err[i], dist[i]  # angle error (rad), rho_ref - n . midpoint (m)
        h12 = nx * -ly + ny * lx
        rmx, rmy = ref.line.midpoint.tolist()
        sl = ux * (mx - rmx) + uy * (my - rmy)
        (c00, c01), (_, c11) = ref.cov.tolist()
        # S = H P H^T + A C A^T + R_line, H = [[0, 0, 1], [nx, ny, h12]], A = [[1, 0], [s, 1]]
        s00 = p22 + c00 + rl0
        s01 = nx * p02 + ny * p12 + h12 * p22 + sl * c00 + c01
        s11 = (nx * nx * p00 + 2 * nx * ny * p01 + ny * ny * p11 + 2 * nx * h12 * p02
               + 2 * ny * h12 * p12 + h12 * h12 * p22
               + sl * sl * c00 + 2 * sl * c01 + c11 + rl1)
        det = s00 * s11 - s01 * s01
        if not det > 0.0:
            continue
        nis = (s11 * y0 * y0 - 2.0 * s01 * y0 * y1 + s00 * y1 * y1) / det
        if nis <= chi2:
            r01 = sl * c00 + c01
            R = ((c00 + rl0, r01), (r01, sl * sl * c00 + 2 * sl * c01 + c11 + rl1))
            out.append((nis, ref, (y0, y1), None, R))
    return out
