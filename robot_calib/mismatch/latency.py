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

from robot_calib.mismatch.locate import moving_average


MIN_BLOCKS = 3
"""Fewest informative blocks behind a delay estimate (a delay seen in one manoeuvre is not)."""


@dataclass
class Delay:
    """
    A delay estimate (s, positive: real lags sim), its jackknife error and the evidence.

    ``blocks`` is the effective number of blocks that carry the estimate
    (``(sum w)^2 / sum w^2`` of their coherent information): the degrees of
    freedom of its error. ``at_edge`` is True when the correlation peaked at
    the largest lag searched (the delay may be larger than measured).
    """

    tau: float
    std: float
    blocks: int
    band_hz: tuple
    per_block: np.ndarray = field(default_factory=lambda: np.zeros(0))
    coherence: float = 0.0
    at_edge: bool = False

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


def _signal_width(x: np.ndarray, ok: np.ndarray, most: int = 64) -> int:
    """
    Return the width (samples, odd) of a moving average that keeps motion but not noise.

    The white-noise level comes from the second differences (their MAD,
    ``sigma^2 = var(d2) / 6``); the signal's own second differences over a span
    of ``m`` samples grow as ``m^2`` while the noise in them stays, so the
    width is the smallest ``m`` at which the motion's second differences stand
    ten times above the noise's.
    """
    xs = x[ok]
    if xs.size < 32:
        return 1
    d2 = np.diff(xs, 2)
    noise = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0)
    if noise <= 0:
        return 1
    m = 1
    while m < most:
        span = np.abs(xs[2 * m:] - 2.0 * xs[m:-m] + xs[:-2 * m])
        if float(np.sqrt(np.mean(span ** 2))) > 10.0 * noise * np.sqrt(6.0 / max(m, 1)):
            break
        m *= 2
    return 2 * (m // 2) + 1


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


def shift_frac(x: np.ndarray, k: float) -> np.ndarray:
    """Return ``x`` delayed by ``k`` samples (an exact FFT phase ramp on a mirrored extension)."""
    return Shifter(x).delayed(k)


def fast_len(n: int) -> int:
    """Return the smallest 2^a 3^b 5^c >= ``n`` (a length the FFT handles fast)."""
    best = 1 << int(math.ceil(math.log2(max(n, 1))))
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


class Shifter:
    """
    Exact fractional delays of one channel (its FFT computed once).

    The channel is extended by its mirror image and held at its first value
    up to a fast FFT length, so its periodic extension has no jump that would
    ring into the samples near the ends.
    """

    def __init__(self, x: np.ndarray):
        """Take the FFT of ``x`` extended by its mirror image once."""
        self.n = x.size
        self.nfft = fast_len(2 * self.n)
        ext = np.full(self.nfft, x[0] if x.size else 0.0)
        ext[:self.n] = x
        ext[self.n:2 * self.n] = x[::-1]
        self.spec = np.fft.rfft(ext)
        self.f = np.fft.rfftfreq(self.nfft)

    def delayed(self, k: float, derivative: bool = False) -> np.ndarray:
        """Return the channel delayed by ``k`` samples (or the derivative of that in k)."""
        ramp = np.exp(-2j * math.pi * self.f * k)
        if derivative:
            ramp = ramp * (-2j * math.pi * self.f)
        return np.fft.irfft(self.spec * ramp, self.nfft)[:self.n]


def _cross(shifters: list, rspecs: list, weights: list, ks: np.ndarray) -> np.ndarray:
    """Return ``sum_c w_c sum_t r_c(t) s_c(t - k)`` for each trial delay ``k`` (samples)."""
    out = np.zeros(ks.size)
    for sh, rs, w in zip(shifters, rspecs, weights):
        prod = np.conj(rs) * sh.spec
        fac = np.full(sh.f.size, 2.0)
        fac[0] = 1.0
        if sh.nfft % 2 == 0:
            fac[-1] = 1.0
        ramps = np.exp(-2j * math.pi * np.outer(ks, sh.f))
        out += w * (ramps * (fac * prod)).real.sum(axis=1) / sh.nfft
    return out


def _parabola_max(ks: np.ndarray, y: np.ndarray) -> float:
    """Return the maximiser of a parabola through the highest point of ``y`` and its neighbours."""
    i = int(np.clip(np.argmax(y), 1, ks.size - 2))
    y0, y1, y2 = y[i - 1], y[i], y[i + 1]
    den = y0 - 2.0 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    return float(ks[i] + np.clip(frac, -1.0, 1.0) * (ks[i + 1] - ks[i]))


def estimate_delay(sims: list, reals: list, oks: list, dt: float, edges: np.ndarray,
                   max_lag_s: float = 0.5) -> Optional[Delay]:
    """
    Return the delay of ``reals`` against ``sims`` shared by all channels, or None.

    Least squares in time: the simulated channels are delayed exactly (an
    FFT phase ramp, which keeps their noise as it is, so the noise of neither
    side can pull the estimate). The delay minimises the weighted squared
    residual ``sum_c w_c sum_t (r_c(t) - s_c(t - tau))^2`` over the compared
    samples (each channel weighted by its residual level), found on a grid of
    trial delays around the cross-correlation peak (the correlation less half
    the shifted simulated energy, evaluated in the frequency domain) and
    refined by Gauss-Newton steps. Its error is the block sandwich of the score
    (``sum_b g_b^2 / H^2``, the linearised jackknife), and the blocks that carry
    the curvature ``H`` count as its degrees of freedom.

    :param sims: simulated channels on a common grid (NaN-free where ``oks``)
    :param reals: real channels on the same grid
    :param oks: valid-sample masks
    :param dt: grid period (s)
    :param edges: block boundaries (sample indices) for the error
    :param max_lag_s: largest delay searched (s)
    """
    if not sims or edges.size < 4:
        return None
    k0 = whole_sample_lag(sims, reals, oks, int(max_lag_s / dt))
    # a noisy simulation (a ground truth differentiated) is smoothed, both sides alike, to
    # the band where its motion stands above its noise: the delay survives a filter applied
    # to both, while the noise would otherwise pass for curvature of the fit
    smooth = [moving_average(_gap_filled(_prep(x, ok), ok), _signal_width(x, ok))
              for x, ok in zip(sims, oks)]
    reals = [moving_average(_gap_filled(_prep(r, ok), ok), _signal_width(x, ok))
             for x, r, ok in zip(sims, reals, oks)]
    # the simulated channels are filled across their gaps before they are shifted: an edge
    # made by filling with zeros would ring into the valid samples around it
    shifters = [Shifter(x) for x in smooth]
    valid = []
    for ok in oks:
        v = ok.copy()
        v[:abs(k0) + 8] = False  # samples a shift moves across the ends are not compared
        v[v.size - abs(k0) - 8:] = False
        valid.append(v)
    rs = [np.where(v, _prep(r, ok), 0.0) for r, ok, v in zip(reals, oks, valid)]
    weights = []
    for sh, r, v in zip(shifters, rs, valid):
        e = np.where(v, r - sh.delayed(float(k0)), 0.0)
        weights.append(1.0 / max(float(np.sum(e * e)) / max(int(v.sum()), 1), 1e-300))
    rspecs = [np.fft.rfft(r, sh.nfft) for r, sh in zip(rs, shifters)]
    grid = k0 + np.linspace(-2.0, 2.0, 41)
    # least squares: the correlation less half the simulated energy inside the compared
    # samples, which a shift changes by what it moves across their ends (a drive ending in a
    # fast turn would otherwise pull the correlation's peak to the edge of the grid); the
    # energy is that of the squared channel shifted, exact at whole samples
    squares = [Shifter(x * x) for x in smooth]
    vspecs = [np.fft.rfft(v.astype(float), sh.nfft) for v, sh in zip(valid, squares)]
    k = _parabola_max(grid, _cross(shifters, rspecs, weights, grid)
                      - 0.5 * _cross(squares, vspecs, weights, grid))
    for _ in range(3):  # Gauss-Newton on the squared residual
        g, h = _scores(shifters, rs, valid, weights, k, edges)
        step = float(g.sum() / max(float(h.sum()), 1e-300))
        k += float(np.clip(step, -0.5, 0.5))
        if abs(step) < 1e-4:
            break
    g, h = _scores(shifters, rs, valid, weights, k, edges)
    nblk = g.size
    H = max(float(h.sum()), 1e-300)
    std = float(np.sqrt(np.sum(g * g) * nblk / max(nblk - 1, 1))) / H * dt
    k_eff = float(h.sum() ** 2 / max(float(np.sum(h * h)), 1e-300))
    return Delay(k * dt, std, int(max(1, math.floor(k_eff))), (0.0, 0.5 / dt),
                 at_edge=abs(k0) >= int(max_lag_s / dt))


def _scores(shifters: list, rs: list, valid: list, weights: list, k: float,
            edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Return per block the Gauss-Newton score and curvature of the delay at ``k`` samples.

    With ``e = r - s(t - k)`` and ``d = ds(t - k)/dk``: ``g_b = sum w e d``,
    ``h_b = sum w d^2`` over the block, so one step is ``sum g / sum h``.
    """
    g = np.zeros(edges.size - 1)
    h = np.zeros(edges.size - 1)
    for sh, r, v, w in zip(shifters, rs, valid, weights):
        d = np.where(v, sh.delayed(k, derivative=True), 0.0)
        e = np.where(v, r - sh.delayed(k), 0.0)
        g += w * np.add.reduceat((e * d)[:edges[-1]], edges[:-1])
        h += w * np.add.reduceat((d * d)[:edges[-1]], edges[:-1])
    return g, h


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
    ``drift`` lists ``(start s, end s, Delay or None)`` per part of the run when
    the delay is not one constant (:func:`drift_of`), else it is empty.
    """

    fields: list
    delay: Delay
    groups: dict = field(default_factory=dict)
    consistent: bool = True
    drift: list = field(default_factory=list)


def pool(delays: list) -> Delay:
    """Return the inverse-variance weighted mean of independent delay estimates."""
    w = np.array([1.0 / max(d.std, 1e-12) ** 2 for d in delays])
    tau = float(np.sum(w * [d.tau for d in delays]) / np.sum(w))
    std = float(1.0 / np.sqrt(np.sum(w)))
    band = (min(d.band_hz[0] for d in delays), max(d.band_hz[1] for d in delays))
    return Delay(tau, std, sum(d.blocks for d in delays), band,
                 coherence=float(np.mean([d.coherence for d in delays])),
                 at_edge=any(d.at_edge for d in delays))


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
    drift = drift_of(group_data, dt, edges, alpha, max_lag_s, pooled) if alpha < 1.0 else []
    return [TimeEffect(fields, pooled, groups, consistent, drift)]


PARTS = 3
"""Parts of the run whose delays must agree for one constant delay (:func:`drift_of`)."""


def drift_of(group_data: dict, dt: float, edges: np.ndarray, alpha: float, max_lag_s: float,
             pooled: Delay) -> list:
    """
    Return the delay per part of the run when it is not the constant ``pooled``, else [].

    A latency is one number for the whole run; a clock running at another rate,
    or a closed-loop run that reaches its goals at other times than the
    simulated one, shifts the two time lines by an amount that changes along
    the run, and a constant fitted to it is a confident wrong answer. The run
    is cut into :data:`PARTS` parts (whole blocks), the delay estimated in each
    as over the whole run, and the delay is not constant when either

    - the parts' delays differ beyond their errors (a chi-square test of
      homogeneity at ``alpha``) by more than a quarter of the delay and three
      grid periods (so a delay that is constant up to rounding stays one), or
    - the whole run's delay or a part's lies at the edge of the searched range
      (the time lines are further apart than searched there: no delay is
      measured, and a constant fitted to it says nothing).

    :returns: ``[(start s, end s, Delay or None)]`` from the run's start, or []
    """
    nb = edges.size - 1
    if nb < PARTS * MIN_BLOCKS:
        return []
    cuts = np.linspace(0, nb, PARTS + 1).astype(int)
    parts, at_edge = [], pooled.at_edge
    for p in range(PARTS):
        e = edges[cuts[p]:cuts[p + 1] + 1]
        a, b = int(e[0]), int(e[-1])
        ds = []
        for _, sims, reals, oks in group_data.values():
            # each part on its own samples (as short as the part, so as cheap)
            d = estimate_delay([x[a:b] for x in sims], [r[a:b] for r in reals],
                               [ok[a:b] for ok in oks], dt, e - a, max_lag_s)
            if d is None or not math.isfinite(d.tau):
                continue
            at_edge |= d.at_edge
            if d.std > 0 and math.isfinite(d.std) and d.blocks >= MIN_BLOCKS:
                ds.append(d)
        parts.append((float(e[0] * dt), float(e[-1] * dt), pool(ds) if ds else None))
    if at_edge:
        return parts
    known = [d for _, _, d in parts if d is not None]
    if len(known) < 2:
        return []
    taus = np.array([d.tau for d in known])
    w = np.array([1.0 / d.std ** 2 for d in known])
    mean = float(np.sum(w * taus) / np.sum(w))
    chi2 = float(np.sum(w * (taus - mean) ** 2))
    from scipy import special
    spread = float(taus.max() - taus.min())
    if chi2 > float(special.chdtri(len(known) - 1, alpha)) and \
            spread > max(0.25 * abs(pooled.tau), 3.0 * dt):
        return parts
    return []
