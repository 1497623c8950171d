# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The time relation of one sensor pair: a pure delay or a first-order lag, with a robust error.

Every channel of a sensor shares one clock, so the delay is estimated once
per sensor from all its moving channels. A regression on the derivative of a
noisy simulation (a ground truth differentiated) is biased by that noise
(errors in variables); the phase of the cross-spectrum is not: for
``real(t) = sim(t - tau)`` the cross-spectrum ``C(f) = R(f) S*(f)`` has the
phase ``-2 pi f tau`` whatever the (independent) noise of either side
(Carter 1987, "Coherence and time delay estimation"). The whole-sample part
of the delay comes from the cross-correlation peak; the fraction from a
weighted straight-line fit of the phase through the origin over the band
where the two sides are coherent. Its standard error is a block jackknife
(every block left out in turn), so coloured noise and unmodelled structure
widen it honestly.

A first-order lag ``real = sim filtered by 1 / (1 + s tau)`` has the same
low-frequency phase slope as a delay but also damps fast motion;
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


def _block_spectra(s: np.ndarray, r: np.ndarray, ok: np.ndarray, edges: np.ndarray,
                   nseg: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return per-block cross-spectrum and the two auto-spectra on a common frequency grid.

    Welch segments (half overlap, Hann window) that hold an invalid sample are
    skipped: a gap filled alike on both sides would look like shared motion.
    """
    win = np.hanning(nseg)
    bad = np.concatenate(([0], np.cumsum(~ok)))
    out_c, out_s, out_r = [], [], []
    for a, b in zip(edges[:-1], edges[1:]):
        cs = np.zeros(nseg // 2 + 1, complex)
        ps = np.zeros(nseg // 2 + 1)
        pr = np.zeros(nseg // 2 + 1)
        for i0 in range(a, max(a + 1, b - nseg + 1), max(1, nseg // 2)):
            i1 = i0 + nseg
            if i1 > b:
                break
            if bad[i1] - bad[i0]:
                continue
            xs = s[i0:i1] - s[i0:i1].mean()
            xr = r[i0:i1] - r[i0:i1].mean()
            fs, fr = np.fft.rfft(xs * win), np.fft.rfft(xr * win)
            cs += fr * np.conj(fs)
            ps += (fs * np.conj(fs)).real
            pr += (fr * np.conj(fr)).real
        out_c.append(cs)
        out_s.append(ps)
        out_r.append(pr)
    return np.array(out_c), np.array(out_s), np.array(out_r)


def _phase_slope(c: np.ndarray, ps: np.ndarray, pr: np.ndarray, freq: np.ndarray,
                 min_coh: float) -> tuple[float, float, tuple]:
    """Return (tau s, mean coherence, band) of a weighted phase fit through the origin."""
    coh = np.abs(c) ** 2 / np.maximum(ps * pr, 1e-300)
    use = (coh >= min_coh) & (freq > 0)
    if use.sum() < 3:
        return math.nan, float(np.mean(coh[1:])) if coh.size > 1 else 0.0, (0.0, 0.0)
    # weight: inverse phase variance of a coherent cross-spectrum, ~ coh / (1 - coh)
    w = np.where(use, coh / np.maximum(1.0 - coh, 1e-6), 0.0)
    phi = np.angle(c)
    tau = -float(np.sum(w * freq * phi) / (2.0 * math.pi * np.sum(w * freq ** 2)))
    f_used = freq[use]
    return tau, float(np.mean(coh[use])), (float(f_used.min()), float(f_used.max()))


def shift_frac(x: np.ndarray, k: float) -> np.ndarray:
    """Return ``x`` delayed by ``k`` samples (fractional: an exact FFT phase ramp, zero-padded)."""
    n = x.size
    nfft = 1 << int(math.ceil(math.log2(n + 2 * abs(k) + 16)))
    f = np.fft.rfftfreq(nfft)
    return np.fft.irfft(np.fft.rfft(x, nfft) * np.exp(-2j * math.pi * f * k), nfft)[:n]


def _spectra(sims: list, reals: list, oks: list, k: float, edges: np.ndarray,
             nseg: int) -> tuple:
    """
    Return per-block cross- and auto-spectra of the channels, the real advanced by ``k`` samples.

    Each channel's spectra are divided by its total power so that channels in
    other units (a speed beside a yaw rate) count alike.
    """
    nblk, nf = edges.size - 1, nseg // 2 + 1
    C = np.zeros((nblk, nf), complex)
    PS, PR = np.zeros((nblk, nf)), np.zeros((nblk, nf))
    ki = int(round(k))
    for s, r, ok in zip(sims, reals, oks):
        # first differences whiten the red spectrum of driving signals (steps, ramps), whose
        # leakage through the segment window would otherwise bend the low-frequency phase;
        # a delay survives any linear filter applied to both sides
        sa = np.diff(_prep(s, ok), prepend=0.0)
        ra = np.diff(shift_frac(_prep(r, ok), -k), prepend=0.0)
        both = ok & _shift_int(ok, -ki) & _shift_int(ok, -ki - int(np.sign(k - ki)))
        both &= np.concatenate(([False], both[:-1]))
        c, ps, pr = _block_spectra(sa, ra, both, edges, nseg)
        norm = math.sqrt(max(float(ps.sum()) * float(pr.sum()), 1e-300))
        C += c / norm
        PS += ps / norm
        PR += pr / norm
    return C, PS, PR


def estimate_delay(sims: list, reals: list, oks: list, dt: float, edges: np.ndarray,
                   max_lag_s: float = 0.5, min_coh: float = 0.5) -> Optional[Delay]:
    """
    Return the delay of ``reals`` against ``sims`` shared by all channels, or None.

    The real channels are first advanced by the whole-sample lag, the phase
    slope gives the remainder; a second pass advances them by that estimate
    (an exact fractional shift) and measures what is left, so the windowing
    of the spectral segments cannot shrink the estimate.

    :param sims: simulated channels on a common grid (NaN-free where ``oks``)
    :param reals: real channels on the same grid
    :param oks: valid-sample masks
    :param dt: grid period (s)
    :param edges: block boundaries (sample indices) for the jackknife
    :param max_lag_s: largest delay searched (s)
    :param min_coh: least magnitude-squared coherence of a frequency used in the fit
    """
    if not sims:
        return None
    nblk = edges.size - 1
    shortest = int(np.min(np.diff(edges)))
    nseg = 1 << int(math.floor(math.log2(max(8, min(shortest, int(4.0 / dt))))))
    if shortest < nseg or nblk < 3:
        return None
    freq = np.fft.rfftfreq(nseg, dt)
    k = float(whole_sample_lag(sims, reals, oks, int(max_lag_s / dt)))
    for _ in range(2):
        C, PS, PR = _spectra(sims, reals, oks, k, edges, nseg)
        tot = (C.sum(0), PS.sum(0), PR.sum(0))
        frac, coh, band = _phase_slope(*tot, freq, min_coh)
        if not math.isfinite(frac):
            return None
        k += frac / dt
    loo = []
    for b in range(nblk):
        t_b, _, _ = _phase_slope(tot[0] - C[b], tot[1] - PS[b], tot[2] - PR[b], freq, min_coh)
        loo.append(t_b if math.isfinite(t_b) else frac)
    loo = np.asarray(loo)
    std = float(np.sqrt((nblk - 1) / nblk * np.sum((loo - loo.mean()) ** 2)))
    # how many blocks carry the evidence: a delay seen in one manoeuvre is one observation
    inband = (freq >= band[0]) & (freq <= band[1])
    info = np.sum(np.abs(C[:, inband]) * freq[inband] ** 2, axis=1)
    k_eff = float(info.sum() ** 2 / max(float(np.sum(info ** 2)), 1e-300))
    return Delay(k * dt, std, int(max(1, math.floor(k_eff))), band, loo + (k * dt - frac), coh)


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
