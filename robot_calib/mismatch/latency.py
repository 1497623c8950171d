# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The time relation of one sensor pair: a pure delay or a first-order lag, with a robust error.

Every channel of a sensor shares one clock, so the delay is estimated once
per clock group (an IMU's gyro and accelerometer may sit behind different
filters) from all its moving channels, by least squares in time: the
simulated channels are delayed exactly (an FFT phase ramp) by trial delays,
so neither side's noise pulls the estimate, as a regression on the
derivative of a noisy simulation would (errors in variables). Its standard
error is a block jackknife (every block left out in turn), so coloured noise
and unmodelled structure widen it honestly, and the number of blocks that
carry the estimate sets its degrees of freedom: a delay seen in a single
manoeuvre is one observation, not forty.

A first-order lag ``real = sim filtered by 1 / (1 + s tau)`` has the same
low-frequency phase as a delay but also damps fast motion;
:func:`lag_response` gives its exact output so the two can be compared.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Optional

import numpy as np


MIN_BLOCKS = 3
"""Fewest informative blocks behind a delay estimate (a delay seen in one manoeuvre is not)."""


@dataclass
class Delay:
    """
    A delay estimate (s, positive: real lags sim), its jackknife error and the evidence.

    ``blocks`` is the effective number of blocks that carry the estimate
    (``(sum w)^2 / sum w^2`` of their coherent information): the degrees of
    freedom of its error.
    """

    tau: float
    std: float
    blocks: int
    band_hz: tuple
    per_block: np.ndarray = field(default_factory=lambda: np.zeros(0))
    coherence: float = 0.0

    @property
    def z(self) -> float:
        """Return |tau| / std (inf for an exact estimate)."""
        return abs(self.tau) / self.std if self.std > 0 else (math.inf if self.tau else 0.0)


def _prep(x: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Return ``x`` with its mean over ``ok`` removed and zeros where not ``ok``."""
    if not ok.any():
        return np.zeros_like(x)
    return np.where(ok, x - float(np.mean(x[ok])), 0.0)


def _gap_filled(x: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Return ``x`` with the samples outside ``ok`` interpolated linearly (held at the ends)."""
    if ok.all() or ok.sum() < 2:
        return x
    return np.interp(np.arange(x.size), np.flatnonzero(ok), x[ok])


def whole_sample_lag(sims: list, reals: list, oks: list, max_lag: int) -> int:
    """Return the lag (samples, positive: real lags) of the summed normalised cross-correlation."""
    n = sims[0].size
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    acc = np.zeros(nfft)
    for s, r, ok in zip(sims, reals, oks):
        a, b = _prep(s, ok), _prep(r, ok)
        na, nb = float(np.sqrt(np.sum(a * a))), float(np.sqrt(np.sum(b * b)))
        if na <= 0 or nb <= 0:
            continue
        acc += np.fft.irfft(np.fft.rfft(b, nfft) * np.conj(np.fft.rfft(a, nfft)), nfft) / (na * nb)
    m = int(min(max_lag, nfft // 4))
    lags = np.concatenate((np.arange(0, m + 1), np.arange(-m, 0)))
    vals = np.concatenate((acc[:m + 1], acc[nfft - m:]))
    return int(lags[int(np.argmax(vals))])


def _shift_int(x: np.ndarray, k: int) -> np.ndarray:
    """Return ``x`` delayed by ``k`` samples (``y[i] = x[i - k]``), zero-padded."""
    if k == 0:
        return x
    y = np.zeros_like(x)
    if k > 0:
        y[k:] = x[:-k]
    else:
        y[:k] = x[-k:]
    return y


def shift_frac(x: np.ndarray, k: float) -> np.ndarray:
    """Return ``x`` delayed by ``k`` samples (fractional: an exact FFT phase ramp, zero-padded)."""
    n = x.size
    nfft = 1 << int(math.ceil(math.log2(n + 2 * abs(k) + 16)))
    f = np.fft.rfftfreq(nfft)
    return np.fft.irfft(np.fft.rfft(x, nfft) * np.exp(-2j * math.pi * f * k), nfft)[:n]


class _Shifter:
    """
    Exact fractional delays of one channel (its FFT computed once).

    The channel is extended by its mirror image, so its periodic extension
    has no jump at the ends that would ring into the samples near them.
    """

    def __init__(self, x: np.ndarray):
        """Take the FFT of ``x`` and its mirror image once."""
        self.n = x.size
        ext = np.concatenate((x, x[::-1]))
        self.nfft = ext.size
        self.spec = np.fft.rfft(ext)
        self.f = np.fft.rfftfreq(self.nfft)

    def delayed(self, k: float) -> np.ndarray:
        """Return the channel delayed by ``k`` samples."""
        return np.fft.irfft(self.spec * np.exp(-2j * math.pi * self.f * k), self.nfft)[:self.n]


def _block_chi2(shifters: list, reals: list, oks: list, ks: np.ndarray,
                edges: np.ndarray) -> np.ndarray:
    """Return the (len(ks), blocks) weighted squared residual of ``real - sim delayed by k``."""
    out = np.zeros((ks.size, edges.size - 1))
    margin = int(math.ceil(float(np.max(np.abs(ks))))) + 4
    for sh, r, ok in zip(shifters, reals, oks):
        valid = ok.copy()
        valid[:margin] = False  # no sample the padding of the shift reaches
        valid[sh.n - margin:] = False
        base = np.where(valid, r - sh.delayed(float(np.round(np.median(ks)))), 0.0)
        w = 1.0 / max(float(np.mean(base[valid] ** 2)) if valid.any() else 0.0, 1e-300)
        for i, k in enumerate(ks):
            e = np.where(valid, r - sh.delayed(float(k)), 0.0)
            out[i] += w * np.add.reduceat(e[:edges[-1]] ** 2, edges[:-1])
    return out


def _parabola_min(ks: np.ndarray, chi: np.ndarray) -> float:
    """Return the minimiser of a parabola through the lowest point of ``chi`` and its neighbours."""
    i = int(np.clip(np.argmin(chi), 1, ks.size - 2))
    y0, y1, y2 = chi[i - 1], chi[i], chi[i + 1]
    den = y0 - 2.0 * y1 + y2
    h = ks[i + 1] - ks[i]
    frac = 0.5 * (y0 - y2) / den if den > 0 else 0.0
    return float(ks[i] + np.clip(frac, -1.0, 1.0) * h)


def estimate_delay(sims: list, reals: list, oks: list, dt: float, edges: np.ndarray,
                   max_lag_s: float = 0.5) -> Optional[Delay]:
    """
    Return the delay of ``reals`` against ``sims`` shared by all channels, or None.

    Least squares in time: the simulated channels are delayed exactly (an
    FFT phase ramp, which keeps their noise as it is, so the noise of neither
    side can pull the estimate) by trial delays around the cross-correlation
    peak, and the sum of squared differences (each channel weighted by its
    residual level) is minimised, coarse then fine, with a parabola through
    the best three. Every block is left out in turn for the jackknife error.

    :param sims: simulated channels on a common grid (NaN-free where ``oks``)
    :param reals: real channels on the same grid
    :param oks: valid-sample masks
    :param dt: grid period (s)
    :param edges: block boundaries (sample indices) for the jackknife
    :param max_lag_s: largest delay searched (s)
    """
    if not sims or edges.size < 4:
        return None
    k0 = whole_sample_lag(sims, reals, oks, int(max_lag_s / dt))
    # first differences of both sides (a delay survives any filter applied to both): the
    # timing lives in the changes, while slow errors of a reference would only blur it
    # the simulated channels are filled across their gaps before they are shifted: an edge
    # made by filling with zeros would ring into the valid samples around it
    shifters = [_Shifter(_gap_filled(_prep(x, ok), ok)) for x, ok in zip(sims, oks)]
    rs = [_prep(r, ok) for r, ok in zip(reals, oks)]
    coarse = k0 + np.linspace(-2.0, 2.0, 17)
    k1 = _parabola_min(coarse, _block_chi2(shifters, rs, oks, coarse, edges).sum(axis=1))
    fine = k1 + np.linspace(-0.5, 0.5, 11)
    chi = _block_chi2(shifters, rs, oks, fine, edges)
    tot = chi.sum(axis=1)
    k = _parabola_min(fine, tot)
    nblk = edges.size - 1
    loo = np.array([_parabola_min(fine, tot - chi[:, b]) for b in range(nblk)])
    std = float(np.sqrt((nblk - 1) / nblk * np.sum((loo - loo.mean()) ** 2))) * dt
    # how many blocks carry the evidence: the curvature each block adds at the minimum
    i = int(np.clip(np.argmin(tot), 1, fine.size - 2))
    curv = np.maximum(chi[i - 1] - 2.0 * chi[i] + chi[i + 1], 0.0)
    k_eff = float(curv.sum() ** 2 / max(float(np.sum(curv ** 2)), 1e-300))
    return Delay(k * dt, std, int(max(1, math.floor(k_eff))), (0.0, 0.5 / dt),
                 loo * dt)


def lag_response(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """
    Return ``x`` through a first-order lag ``1 / (1 + s tau)`` (exact discretisation).

    ``y[k] = a y[k-1] + (1 - a) x[k]``, ``a = exp(-dt / tau)``, started at rest
    on ``x[0]``; computed as an FFT convolution with the truncated impulse
    response (to ``1e-9`` of its peak).
    """
    if tau <= 0:
        return x.copy()
    a = math.exp(-dt / tau)
    m = int(min(x.size, math.ceil(math.log(1e-9) / math.log(a)) + 1)) if a > 0 else 1
    h = (1.0 - a) * a ** np.arange(m)
    n = x.size
    nfft = 1 << int(math.ceil(math.log2(n + m)))
    x0 = x - x[0]
    y = np.fft.irfft(np.fft.rfft(x0, nfft) * np.fft.rfft(h, nfft), nfft)[:n]
    return y + x[0]


def field_groups(msgtype: str, fields: list) -> list:
    """
    Return the fields of a topic grouped by the clock they may have of their own.

    An IMU's gyro and accelerometer often sit behind different digital
    filters, so each gets its own group; every other message is one group.
    """
    prefixes = ('angular_velocity.', 'linear_acceleration.')
    groups = [[f for f in fields if f.startswith(p)] for p in prefixes]
    rest = [f for f in fields if not f.startswith(prefixes)]
    return [g for g in groups + [rest] if g]


def t_quantile(alpha: float, dof: int) -> float:
    """Return the two-sided ``1 - alpha`` quantile of Student's t with ``dof`` degrees (>= 1)."""
    from scipy import special
    return float(special.stdtrit(max(int(dof), 1), 1.0 - alpha / 2.0))


@dataclass
class TimeEffect:
    """
    The delay of a sensor: its fields, the pooled estimate and the estimate per clock group.

    ``groups`` maps each group's fields (a tuple) to its own :class:`Delay`;
    ``consistent`` is False when the groups differ beyond their errors (e.g.
    an IMU whose gyro and accelerometer sit behind different filters).
    """

    fields: list
    delay: Delay
    groups: dict = field(default_factory=dict)
    consistent: bool = True


def pool(delays: list) -> Delay:
    """Return the inverse-variance weighted mean of independent delay estimates."""
    w = np.array([1.0 / max(d.std, 1e-12) ** 2 for d in delays])
    tau = float(np.sum(w * [d.tau for d in delays]) / np.sum(w))
    std = float(1.0 / np.sqrt(np.sum(w)))
    band = (min(d.band_hz[0] for d in delays), max(d.band_hz[1] for d in delays))
    return Delay(tau, std, sum(d.blocks for d in delays), band,
                 coherence=float(np.mean([d.coherence for d in delays])))


def delays_of(group_data: dict, dt: float, edges: np.ndarray, alpha: float,
              max_lag_s: float) -> list:
    """
    Return the sensor's delay as a one-element list when it is significant, else [].

    Each clock group (see :func:`field_groups`) is estimated on its own; the
    sensor's delay is their inverse-variance mean. Groups that differ beyond
    their errors (a chi-square test of homogeneity at ``alpha``) are kept in
    ``groups`` with ``consistent = False``, so the analysis can shift each by
    its own delay and say so.

    :param group_data: {group name: (fields, sims, reals, oks)} of the moving fields
    :param dt: grid period (s)
    :param edges: jackknife blocks
    :param alpha: false-alarm probability of each test
    :param max_lag_s: largest delay searched (s)
    """
    groups = {}
    for fields, sims, reals, oks in group_data.values():
        d = estimate_delay(sims, reals, oks, dt, edges, max_lag_s)
        # a jackknife over fewer than MIN_BLOCKS informative blocks says nothing of the error
        if d is not None and d.std > 0 and math.isfinite(d.std) and d.blocks >= MIN_BLOCKS:
            groups[tuple(fields)] = d
    if not groups:
        return []
    ds = list(groups.values())
    pooled = pool(ds)
    chi2 = sum((d.tau - pooled.tau) ** 2 / d.std ** 2 for d in ds)
    from scipy import special
    consistent = len(ds) < 2 or chi2 <= float(special.chdtri(len(ds) - 1, alpha))
    fields = [f for g in groups for f in g]
    if pooled.z <= t_quantile(alpha, pooled.blocks - 1):
        return []
    return [TimeEffect(fields, pooled, groups, consistent)]
