# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Locate a mismatch: the noise floor of a residual, where it stops being noise, and windows.

- :func:`noise_level`: standard deviation (channel units) of the part of a
  residual faster than a few seconds (the residual minus its moving average),
  and the variance-inflation factor ``phi = 1 + 2 sum_k rho_k`` of that
  part's autocorrelation (phi = 1 for white noise), so that coloured noise
  does not pass for signal (effective samples = n / phi).
- :func:`active_windows`: block-wise chi-square of the residual against the
  noise level with a one-dimensional change-point segmentation (binary
  segmentation on the block means), returning the time windows where the
  residual is beyond noise.
- :func:`scan_window`: the window [i0, i1) that maximises the chi-square an
  effect with regressors X explains when it acts only there (cumulative sums,
  all block pairs, then sample-level refinement of both edges).
"""

from __future__ import annotations

from typing import Optional

import numpy as np


def moving_average(x: np.ndarray, width: int) -> np.ndarray:
    """
    Return the centred moving average of ``x`` over ``width`` samples, along axis 0.

    The one moving average of the analyser (edges shrink: a window cut by an
    end averages the samples it still holds). An even ``width`` takes one
    sample more before than after; a ``width`` of 1 or less returns a copy.
    Columns of a 2-D ``x`` are averaged independently.
    """
    width = max(1, int(width))
    if width == 1 or x.size == 0:
        return x.copy()
    c = np.concatenate((np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)))
    n = x.shape[0]
    i = np.arange(n)
    lo = np.clip(i - width // 2, 0, n)
    hi = np.clip(i + (width - width // 2), 0, n)
    return (c[hi] - c[lo]) / (hi - lo).reshape((n,) + (1,) * (x.ndim - 1))


def noise_level(r: np.ndarray, mask: np.ndarray, dt: float,
                smooth: float = 2.0) -> tuple[float, float]:
    """
    Return (sigma, phi): the fast noise level of a residual and its variance inflation.

    :param r: residual real - sim (channel units), NaN-free where ``mask``
    :param mask: valid samples
    :param dt: sample period (s)
    :param smooth: moving-average width (s) removed before measuring
    """
    x = r[mask]
    if x.size < 10:
        return float('nan'), 1.0
    w = max(3, int(round(smooth / max(dt, 1e-9))))
    w = min(w, max(3, x.size // 4))
    e = x - moving_average(x, w)
    # robust scale (bursts of unmodelled structure do not inflate it), floored at 0.3 std
    sd = float(np.std(e))
    mad = 1.4826 * float(np.median(np.abs(e - np.median(e))))
    sigma = max(mad, 0.3 * sd) * float(np.sqrt(w / max(w - 1.0, 1.0)))
    if sigma <= 0:
        return 0.0, 1.0
    n = e.size
    kmax = min(n // 4, 400)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(e - e.mean(), nfft)
    ac = np.fft.irfft(f * np.conj(f), nfft)[:kmax + 1]
    rho = ac / ac[0]
    phi = 1.0
    for k in range(1, kmax + 1):
        if rho[k] < 0.02:
            break
        phi += 2.0 * rho[k] * (1.0 - k / n)
    return sigma, float(np.clip(phi, 1.0, 200.0))


def _segments(z: np.ndarray, thr: float, min_len: int) -> list:
    """Binary segmentation of block statistics ``z`` on a mean shift (CUSUM), recursively."""
    out = []
    stack = [(0, z.size)]
    while stack:
        a, b = stack.pop()
        seg = z[a:b]
        if seg.size < 2 * min_len:
            out.append((a, b))
            continue
        c = np.cumsum(seg - seg.mean())
        k = np.arange(1, seg.size)
        stat = np.abs(c[:-1]) / np.sqrt(k * (seg.size - k) / seg.size)
        stat[:min_len - 1] = 0
        stat[seg.size - min_len:] = 0
        j = int(np.argmax(stat))
        # noise scale from first differences: level shifts do not inflate it
        sd = max(1.4826 * float(np.median(np.abs(np.diff(seg)))) / np.sqrt(2.0), 1e-12)
        if stat[j] / sd > thr:
            stack.append((a, a + j + 1))
            stack.append((a + j + 1, b))
        else:
            out.append((a, b))
    return sorted(out)


def active_windows(t: np.ndarray, r: np.ndarray, mask: np.ndarray, sigma: float, phi: float,
                   block: float = 2.0, z_thr: float = 5.0) -> list:
    """
    Return the time windows [[t0, t1], ...] (s) where the residual is beyond noise.

    Blocks of ``block`` s get a statistic ``z = (sum r^2 / sigma^2 - m) / sqrt(2 m phi)``
    (m samples); change points split the block sequence where its mean
    shifts, and a segment is active when its mean z exceeds ``z_thr``.
    """
    if sigma <= 0 or not np.isfinite(sigma) or t.size < 4:
        return []
    dt = float(np.median(np.diff(t)))
    nb = max(1, int(round(block / max(dt, 1e-9))))
    nblk = t.size // nb
    if nblk < 1:
        return []
    rr = np.where(mask, r, 0.0)[:nblk * nb].reshape(nblk, nb)
    mm = mask[:nblk * nb].reshape(nblk, nb).sum(axis=1)
    chi = (rr ** 2).sum(axis=1) / sigma ** 2
    z = (chi - mm) / np.sqrt(2.0 * np.maximum(mm, 1) * phi)
    out = []
    for a, b in _segments(z, 4.0, 2):
        zz = z[a:b].sum() / np.sqrt(b - a)
        if zz > z_thr:
            t0, t1 = float(t[a * nb]), float(t[min(b * nb, t.size) - 1])
            if out and abs(out[-1][1] - t0) <= 2 * block:
                out[-1][1] = t1
            else:
                out.append([t0, t1])
    return out


def _gram(xs: list, es: list, ws: list) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample normal-equation terms summed over channels: G (n, p, p) and h (n, p)."""
    n, p = xs[0].shape
    G = np.zeros((n, p, p))
    h = np.zeros((n, p))
    for X, e, w in zip(xs, es, ws):
        G += w * X[:, :, None] * X[:, None, :]
        h += w * X * e[:, None]
    return G, h


def _dchi(CG: np.ndarray, Ch: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    A = CG[b] - CG[a]
    h = Ch[b] - Ch[a]
    p = h.shape[-1]
    # ridge relative to the whole recording: a window without excitation explains nothing
    eps = 1e-9 * float(np.trace(CG[-1] - CG[0])) / p + 1e-300
    A = A + np.eye(p) * eps
    try:
        sol = np.linalg.solve(A, h[..., None])[..., 0]
    except np.linalg.LinAlgError:
        sol = np.einsum('...ij,...j->...i', np.linalg.pinv(A), h)
    out = np.einsum('...i,...i->...', h, sol)
    return np.where(np.isfinite(out), out, 0.0)


def _move_edges(CG: np.ndarray, Ch: np.ndarray, a0: int, b0: int, n: int, reach: int,
                stride: int, min_len: int) -> tuple[int, int]:
    """Move the start, then the end of window [a0, b0) within +-reach samples to the best fit."""
    cand = np.arange(max(0, a0 - reach), min(n, a0 + reach) + 1, stride)
    cand = cand[b0 - cand >= min_len]
    if cand.size:
        a0 = int(cand[int(np.argmax(_dchi(CG, Ch, cand, np.full(cand.size, b0))))])
    cand = np.arange(max(0, b0 - reach), min(n, b0 + reach) + 1, stride)
    cand = cand[cand - a0 >= min_len]
    if cand.size:
        b0 = int(cand[int(np.argmax(_dchi(CG, Ch, np.full(cand.size, a0), cand)))])
    return a0, b0


def scan_window(xs: list, es: list, ws: list, min_len: int,
                n_blocks: int = 160) -> Optional[tuple]:
    """
    Return ``(i0, i1, dchi2)``: the window that best explains ``es`` with regressors ``xs``.

    :param xs: per channel (n, p) regressors (already zero where invalid)
    :param es: per channel current residual (n,), zero where invalid
    :param ws: per channel weight 1 / (sigma^2 phi)
    :param min_len: shortest window (samples)
    :param n_blocks: coarse grid size for the exhaustive pair search
    """
    n = xs[0].shape[0]
    if n < 2 * min_len or n < 8:
        return None
    G, h = _gram(xs, es, ws)
    CG = np.concatenate((np.zeros((1,) + G.shape[1:]), np.cumsum(G, axis=0)))
    Ch = np.concatenate((np.zeros((1, h.shape[1])), np.cumsum(h, axis=0)))
    nb = int(min(n_blocks, max(4, n // max(1, min_len // 2))))
    edges = np.unique(np.linspace(0, n, nb + 1).astype(int))
    ia, ib = np.triu_indices(edges.size, k=1)
    a, b = edges[ia], edges[ib]
    ok = (b - a) >= min_len
    a, b = a[ok], b[ok]
    if a.size == 0:
        return None
    d = _dchi(CG, Ch, a, b)
    k = int(np.argmax(d))
    a0, b0 = int(a[k]), int(b[k])
    step = max(1, int(np.ceil(n / nb)))
    for _ in range(3):
        a0, b0 = _move_edges(CG, Ch, a0, b0, n, 2 * step, max(1, step // 16), min_len)
        step = max(1, step // 8)
        if step == 1:
            a0, b0 = _move_edges(CG, Ch, a0, b0, n, 8, 1, min_len)
            break
    best = float(_dchi(CG, Ch, np.array([a0]), np.array([b0]))[0])
    return a0, b0, best


def local_weights(e: np.ndarray, mask: np.ndarray, dt: float, smooth: float = 2.0,
                  local_s: float = 2.0, clip: float = 100.0) -> np.ndarray:
    """
    Return each sample's relative weight ``v_typ / v_i`` from the local noise variance.

    Real residuals are often louder while moving (vibration, a ground truth
    differentiated) than at rest; weighting each sample by the inverse of its
    local noise variance (weighted least squares for heteroscedastic noise)
    lets the quiet stretches carry what they measure best. ``v_i`` is the
    variance of the fast part of ``e`` (``e`` minus its ``smooth``-second moving
    average) over ``local_s`` seconds around sample ``i``; ``v_typ`` its median.
    Weights are clipped to ``[1 / clip, clip]`` and are 0 where ``mask`` is False.

    :param e: residual after the effects found so far (channel units)
    :param mask: valid samples
    :param dt: sample period (s)
    """
    valid = mask.astype(float)
    x = np.where(mask, e, 0.0)
    w = max(3, int(round(smooth / max(dt, 1e-9))))
    level = moving_average(x, w) / np.maximum(moving_average(valid, w), 1e-9)
    fast = np.where(mask, e - level, 0.0)
    wl = max(3, int(round(local_s / max(dt, 1e-9))))
    v = moving_average(fast * fast, wl) / np.maximum(moving_average(valid, wl), 1e-9)
    if not mask.any():
        return valid
    typ = float(np.median(v[mask]))
    if typ <= 0:
        return valid
    h = typ / np.maximum(v, typ / clip)
    return np.clip(h, 1.0 / clip, clip) * valid
