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

from typing import Optional

import numpy as np

from robot_calib.core.geometry import wrap_half_pi
from robot_calib.core.lines import Line
from robot_calib.methods.gyro_line_calibration.params import ImprovedParams


def line_noise(line: Line, ip: ImprovedParams) -> np.ndarray:
    """Return the covariance (angle rad^2, distance m^2) of a fitted line."""
    sa = line.angle_sigma() ** 2 + ip.line_angle_sigma ** 2
    sr = line.variance / max(line.n_cells, 1) + ip.line_sigma ** 2
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

    Returns the angle errors (rad), distances (m), the candidate mask and the
    references' directions and normals.
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
    ok = (np.abs(err) <= angle_tolerance) & (hi >= -margin) & (lo <= r2[None, :] + margin) \
        & (np.abs(dist) < margin + 1.0)
    return err, dist, ok, u, nrm


def gate(refs: list, line: Line, margin: float, chi2: float, x: np.ndarray, P: np.ndarray,
         R_line: np.ndarray, angle_tolerance: float, pre: Optional[tuple] = None) -> list[tuple]:
    """
    Return the references whose innovation with ``line`` passes the chi-square gate ``chi2``.

    ``x``, ``P`` are the state and its covariance, ``R_line`` the line's noise
    (:func:`line_noise`), ``pre`` this line's row of :func:`prefilter` (computed
    when None). Each entry is ``(nis, reference, y, None, R)`` with ``R`` the
    covariance of ``y`` without the pose part.
    """
    if not refs:
        return []
    if pre is None:
        err, dist, ok, u, nrm = prefilter(refs, [line], margin, angle_tolerance)
        pre = (err[0], dist[0], ok[0], u, nrm)
    err, dist, ok, u, nrm = pre
    out = []
    idx = ok.nonzero()[0]
    if idx.size == 0:
        return out
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = P[:3, :3].tolist()
    mx, my = line.midpoint.tolist()
    x0, x1 = x[:2].tolist()
    lx, ly = mx - x0, my - x1
    rl0, rl1 = float(R_line[0, 0]), float(R_line[1, 1])
    for i, (nx, ny), (ux, uy), y0, y1 in zip(idx.tolist(), nrm[idx].tolist(), u[idx].tolist(),
                                             err[idx].tolist(), dist[idx].tolist()):
        ref = refs[i]  # y0: angle error (rad), y1: rho_ref - n . midpoint (m)
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
            R = np.array([[c00 + rl0, r01],
                          [r01, sl * sl * c00 + 2 * sl * c01 + c11 + rl1]])
            out.append((nis, ref, np.array([y0, y1]), None, R))
    return out
