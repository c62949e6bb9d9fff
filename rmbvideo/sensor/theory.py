"""Dynamic-range theory of paper Sec. 3 (Eqns. 4-8) and supplement Secs. 7-9.

Model (the paper's Eqn. 6): a pixel's threshold ``Q'`` (integer electrons, supplement Eqn. 27) and its
dark electrons per interval ``k`` (Eqn. 16) are drawn once per pixel and then stay fixed; the photo
electrons of each readout interval are Poisson with mean ``lam`` (= alpha*lambda, photo-electrons
per readout interval). Given ``(Q', k)`` the carried charge is a Markov chain (supplement Sec. 8):
from charge ``c`` the next interval ends at ``c + k + Pois(lam)``; level ``H >= 1`` fires when that
reaches ``T_H = ceil(H*Q'/L)`` (Eqn. 2 with integer charge) and resets the charge to zero.
``P(S^L = H)`` is the stationary (renewal, supplement Sec. 9) law, averaged over ``(Q', k)``.

Everything is vectorised over ``lam`` and stable from 1e-6 to 1e6: Poisson terms come from
``scipy.stats.poisson`` log-pmf/cdf/sf, probabilities are sums of non-negative terms, and the
variance is formed around whichever end (0 or L) the mean is closer to.

Calibration: with supplement Sec. 10's Q_r = 105, mu_d = 0.05 and all noise variances 0.005, the split
C = 1.4, V = 75 (threshold spread ~5.3 e-, dominated by C^S*V) and N*Var(S^L) reproduce Table 1 within
0.45 dB in 20 of 21 cells; the paper's L = 7, N = 70 (64.09 dB) is inconsistent with its row (N 30 -> 70
adds ~7.6 dB at every L; this model gives 57.3 dB). DR is the envelope of the SNR >= 1 set.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy import signal, special

from rmbvideo.sensor.lag_sums import covariance_method, covariance_sums
from rmbvideo.sensor.params import SensorParams
from rmbvideo.sensor.poisson_tables import PoissonTables, level_thresholds

# matrix-product multiply-adds a second of the exact variance on one core (the default L = 1 table: 282 s measured)
_EXACT_RATE = 4.1e9
# probability mass below which a threshold/dark value is dropped (the rest is renormalised)
_TAIL_MASS = 1e-12
# nodes of the quadrature over the capacitance deviation C^S (supplement Eqn. 26)
_CAP_NODES = 4001


@dataclass(frozen=True)
class DiscreteLaw:
    """A probability mass function on consecutive integers ``values`` (ascending)."""

    values: np.ndarray  # int64
    probs: np.ndarray   # float64, sums to 1


@dataclass(frozen=True)
class SpikeLaw:
    """Single-interval statistics of S^L at each exposure: pmf, mean, variance, d(mean)/d(lam)."""

    lam: np.ndarray    # (n,) photo-electrons per readout interval
    pmf: np.ndarray    # (n, L+1) P(S^L = H), H = 0..L
    mean: np.ndarray   # (n,) E(S^L)
    var: np.ndarray    # (n,) Var(S^L)
    dmean: np.ndarray  # (n,) dE(S^L)/d lam


@functools.lru_cache(maxsize=64)
def threshold_law(params: SensorParams) -> DiscreteLaw:
    """P(Q_th = Q') for Q_th = round((C + C^S)(V + V^S + V^T0)) (supplement Eqns. 17-27).

    Given C^S = c the threshold is Gaussian in V^S + V^T0, so the integral over the voltage noise is
    an exact normal CDF difference; the remaining integral over c uses a fine trapezoid rule.
    Thresholds below one electron are folded into Q' = 1 (a spike needs at least one electron).
    """
    cap, volt = params.capacitance, params.voltage
    sig_c = params.cap_std
    sig_v = math.hypot(params.reset_v_std, params.temp_v_std)
    if sig_c > 0:
        c = np.linspace(-8.5 * sig_c, 8.5 * sig_c, _CAP_NODES)
        w = np.exp(-0.5 * (c / sig_c) ** 2)
        w[0] *= 0.5
        w[-1] *= 0.5
        w /= w.sum()
    else:
        c, w = np.zeros(1), np.ones(1)
    gain = np.abs(cap + c)
    centre = gain * volt
    spread = gain * sig_v
    lo = math.floor(float(np.min(centre - 9 * spread - 8.5 * sig_c * volt))) - 1
    hi = math.ceil(float(np.max(centre + 9 * spread + 8.5 * sig_c * volt))) + 1
    values = np.arange(lo, hi + 1)
    edges = np.append(values - 0.5, values[-1] + 0.5)
    if sig_v > 0:
        z = (edges[None, :] - centre[:, None]) / np.maximum(spread[:, None], 1e-300)
        cdf = special.ndtr(z)
    else:
        cdf = (edges[None, :] >= centre[:, None]).astype(float)
    probs = w @ np.diff(cdf, axis=1)
    return _fold_and_trim(values, probs, floor=1)


@functools.lru_cache(maxsize=64)
def dark_law(params: SensorParams) -> DiscreteLaw:
    """P(Q_d = k) = P(k - 1/2 <= N(mu_d, sigma_d^2) < k + 1/2) per interval (supplement Eqn. 16).

    Negative counts are not physical; their (tiny) mass is folded into k = 0.
    """
    mu, sig = params.dark_mean, params.dark_std
    if sig <= 0:
        return DiscreteLaw(np.array([max(round(mu), 0)]), np.ones(1))
    lo = math.floor(mu - 40 * sig) - 1
    hi = math.ceil(mu + 40 * sig) + 1
    values = np.arange(lo, hi + 1)
    probs = special.ndtr((values + 0.5 - mu) / sig) - special.ndtr((values - 0.5 - mu) / sig)
    return _fold_and_trim(values, probs, floor=0)


def _fold_and_trim(values: np.ndarray, probs: np.ndarray, floor: int) -> DiscreteLaw:
    probs = np.clip(probs, 0.0, None)
    below = values < floor
    if below.any():
        folded = probs[below].sum()
        values, probs = values[~below], probs[~below].copy()
        if values.size == 0 or values[0] != floor:
            values = np.insert(values, 0, floor)
            probs = np.insert(probs, 0, 0.0)
        probs[0] += folded
    keep = probs > _TAIL_MASS * probs.max()
    idx = np.flatnonzero(keep)
    values, probs = values[idx[0]: idx[-1] + 1], probs[idx[0]: idx[-1] + 1]
    return DiscreteLaw(values.astype(np.int64), probs / probs.sum())


def _green(q: np.ndarray, dq: np.ndarray, one_minus_q0: np.ndarray, size: int
           ) -> tuple[np.ndarray, np.ndarray]:
    """Expected visits g_c of carried charge c (c < size) per cycle started at 0, and d g_c/d lam.

    Forward substitution of g (I - U) = e_0 for the upper-triangular Toeplitz transient matrix U
    (U[c, d] = q[d - c]), a recursive filter an exposure: all terms of g are non-negative, so it is free of
    cancellation; d g solves the same system with g dU on the right.
    """
    n = q.shape[0]
    g = np.zeros((n, size))
    dg = np.zeros((n, size))
    impulse = np.zeros(size)
    impulse[0] = 1.0
    for r in range(n):
        denom = np.concatenate(([one_minus_q0[r]], -q[r, 1:size]))
        g[r] = signal.lfilter([1.0], denom, impulse)
        dg[r] = signal.lfilter([1.0], denom, np.convolve(g[r], dq[r, :size])[:size])
    return g, dg


def _conditional(lam: np.ndarray, q_values: np.ndarray, k: int, level: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For fixed dark count k and each threshold Q': pmf (nQ, n, L+1), mean, deficit L-mean, dmean.

    The stationary law is renewal-reward: P(S=H) = E[#intervals with H per cycle] / E[cycle length].
    """
    t1_max = int(max(level_thresholds(int(q), level)[0] for q in q_values))
    q_max = int(q_values.max())
    tab = PoissonTables(lam, q_max + 2, pad=k + 2)
    n = lam.size
    # increments X = k + Y: q_j = P(X=j), dq_j = d/dlam P(X=j) = pmf_Y(j-k-1) - pmf_Y(j-k)
    j = np.arange(t1_max + 1)
    qx = tab.take("pmf", j - k)
    dqx = tab.take("pmf", j - k - 1) - qx
    if k == 0:
        one_minus_q0 = -np.expm1(-lam)
    else:
        one_minus_q0 = np.ones(n)
    g, dg = _green(qx, dqx, one_minus_q0, t1_max)

    n_q = q_values.size
    pmf = np.zeros((n_q, n, level + 1))
    mean = np.zeros((n_q, n))
    deficit = np.zeros((n_q, n))
    dmean = np.zeros((n_q, n))
    hs = np.arange(level + 1, dtype=float)
    for i, q in enumerate(q_values):
        th = level_thresholds(int(q), level)           # T_1..T_L
        t1 = int(th[0])
        gc, dgc = g[:, :t1], dg[:, :t1]
        cycle = gc.sum(axis=1)
        dcycle = dgc.sum(axis=1)
        c = np.arange(t1)
        # need[h, c] = electrons X must supply from carried charge c to reach T_h
        need = th[:, None] - c[None, :] - k            # (L, t1)
        # expected firings with level >= h per cycle: a cycle always ends in exactly one firing (h = 1); for
        # h >= 2, P(X >= need) = sf_Y(need-1), derivative pmf_Y(need-1) (h = 1's would be computed and unused)
        counts = np.ones((n, level))
        dcounts = np.zeros((n, level))
        if level > 1:
            reach = tab.take("sf", need[1:] - 1)           # (n, L - 1, t1)
            dreach = tab.take("pmf", need[1:] - 1)
            counts[:, 1:] = np.einsum("nc,nhc->nh", gc, reach)
            dcounts[:, 1:] = np.einsum("nc,nhc->nh", dgc, reach) + np.einsum("nc,nhc->nh", gc, dreach)
        p_ge = counts / cycle[:, None]                 # P(S >= h), h = 1..L
        dmean[i] = (dcounts.sum(axis=1) - counts.sum(axis=1) * dcycle / cycle) / cycle
        # non-negative per-level probabilities
        below = tab.run("cdf", t1 - k - 1, t1)         # P(X < T_1 - c): no firing
        pmf[i, :, 0] = np.einsum("nc,nc->n", gc, below) / cycle
        pmf[i, :, level] = p_ge[:, -1]
        for h in range(1, level):
            if th[h] == th[h - 1]:
                continue
            # P(need_h-1 <= X - k < need_h) from the nearer tail: cdf(hi) - cdf(lo) where cdf(hi) <= 1/2, else
            # sf(lo) - sf(hi), so neither difference loses the small ones (the sum of the pmf over the range,
            # width T_{h+1} - T_h terms a pixel, costs that factor more)
            lo, hi = int(th[h - 1]) - k - 1, int(th[h]) - k - 1      # need_h - 1 at c = 0, then one less a charge
            cdf_hi = tab.run("cdf", hi, t1)
            terms = np.where(cdf_hi <= 0.5, cdf_hi - tab.run("cdf", lo, t1),
                             tab.run("sf", lo, t1) - tab.run("sf", hi, t1))
            pmf[i, :, h] = np.einsum("nc,nc->n", gc, np.maximum(terms, 0.0)) / cycle
        mean[i] = p_ge.sum(axis=1)
        deficit[i] = pmf[i] @ (level - hs)
    return pmf, mean, deficit, dmean


def spike_law(lam: np.ndarray, params: SensorParams) -> SpikeLaw:
    """P(S^L = H), E(S^L), Var(S^L) and dE/dlam at each exposure ``lam`` (paper Eqns. 4-7)."""
    return _spike_law_parts(_check_lam(lam), params)[0]


def _check_lam(lam: np.ndarray) -> np.ndarray:
    lam = np.atleast_1d(np.asarray(lam, dtype=float))
    if lam.ndim != 1 or np.any(~np.isfinite(lam)) or np.any(lam <= 0):
        raise ValueError("exposures must be a 1-D array of finite positive values")
    return lam


def _spike_law_parts(lam: np.ndarray, params: SensorParams
                     ) -> tuple[SpikeLaw, list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]]:
    """The mixture law and, per dark count k, (k, weights over Q', conditional means, deficits)."""
    level = params.level
    qlaw, dlaw = threshold_law(params), dark_law(params)
    pmf = np.zeros((lam.size, level + 1))
    mean = np.zeros(lam.size)
    deficit = np.zeros(lam.size)
    dmean = np.zeros(lam.size)
    parts = []
    for k, pk in zip(dlaw.values, dlaw.probs):
        p_c, m_c, d_c, dm_c = _conditional(lam, qlaw.values, int(k), level)
        wts = pk * qlaw.probs
        pmf += np.einsum("q,qnh->nh", wts, p_c)
        mean += wts @ m_c
        deficit += wts @ d_c
        dmean += wts @ dm_c
        parts.append((int(k), wts, m_c, d_c))
    hs = np.arange(level + 1, dtype=float)
    # centred second moment, deviations taken from the nearer end to avoid cancellation
    near_top = mean > 0.5 * level
    dev = np.where(near_top[:, None], (hs - level)[None, :] + deficit[:, None],
                   hs[None, :] - mean[:, None])
    var = np.einsum("nh,nh->n", pmf, dev * dev)
    law = SpikeLaw(lam, pmf, mean, np.clip(var, 0.0, None), dmean)
    return law, parts


def spike_moments(lam: np.ndarray, params: SensorParams) -> tuple[np.ndarray, np.ndarray]:
    """(E(S^L), Var(S^L)) of one readout interval (Eqns. 4-5), over the pixel population and time."""
    law = spike_law(lam, params)
    return law.mean, law.var


def pixel_spread(lam: np.ndarray, params: SensorParams) -> np.ndarray:
    """Variance across pixels of a pixel's own long-run mean E(S^L | Q', k) (fixed-pattern part)."""
    law, parts = _spike_law_parts(_check_lam(lam), params)
    return _between_pixel_var(law, parts)


def _between_pixel_var(law: SpikeLaw, parts: list) -> np.ndarray:
    level = law.pmf.shape[1] - 1
    near_top = law.mean > 0.5 * level
    out = np.zeros(law.lam.size)
    deficit = law.pmf @ (level - np.arange(level + 1))
    for _, wts, m_c, d_c in parts:
        dev = np.where(near_top[None, :], deficit[None, :] - d_c, m_c - law.mean[None, :])
        out += wts @ (dev * dev)
    return out


def exact_variance_seconds(params: SensorParams, n_values: list[int], search: RangeSearch | None = None) -> float:
    """About how long ``dynamic_range(..., exact=True)`` takes on one core, estimated before any work.

    Every threshold and dark value is a row at each exposure the search visits (its grid and about half as many
    again in refinement and bisection), at the cost of the cheaper exact method; the rate is this project's
    development machine's (the default L = 1 table: 282 s; smaller ones run below the rate, on per-call overheads).
    """
    search = search or RangeSearch()
    qlaw, dlaw = threshold_law(params), dark_law(params)
    exposures = 1.5 * (round(math.log10(search.lam_hi / search.lam_lo) * search.per_decade) + 1)
    horizons = tuple(n_values)
    work = sum(covariance_method(int(level_thresholds(int(q), params.level)[0]), horizons)[1] for q in qlaw.values)
    return exposures * dlaw.values.size * work / _EXACT_RATE


def sum_moments(lam: np.ndarray, n: int, params: SensorParams, exact: bool = True
                ) -> tuple[np.ndarray, np.ndarray]:
    """(E(S_N^L), Var(S_N^L)) of the sum of ``n`` consecutive readouts.

    ``exact=False``: N*Var(S^L) (independent intervals, the paper's Table 1). ``exact=True``: each
    pixel's temporal variance with the exact correlation of its stationary Markov chain, averaged over
    pixels, plus N*(variance of the pixels' means) -- threshold/dark spread is kept as independent
    per interval exactly as Eqn. 5 does, so N = 1 gives Var(S^L) and Var <= N*Var(S^L) always.
    """
    if n < 1:
        raise ValueError("n must be >= 1")
    lam = _check_lam(lam)
    law, parts = _spike_law_parts(lam, params)
    if not exact or n == 1:
        return n * law.mean, n * law.var
    return n * law.mean, _exact_variances(law, parts, (n,), params)[0]


def _exact_variances(law: SpikeLaw, parts: list, horizons: tuple[int, ...], params: SensorParams) -> np.ndarray:
    """(horizons, exposures): Var(S_N^L) with the exact interval correlation, for each N in ``horizons``."""
    qlaw = threshold_law(params)
    cov = np.zeros((len(horizons), law.lam.size))
    for k, wts, m_c, _ in parts:
        cov += np.einsum("q,hqn->hn", wts, covariance_sums(law.lam, k, qlaw.values, params.level, horizons, m_c))
    var = np.array(horizons, dtype=float)[:, None] * law.var[None, :] + 2.0 * cov
    return np.clip(var, 0.0, None)


def snr(lam: np.ndarray, n: int, params: SensorParams, exact: bool = False) -> np.ndarray:
    """SNR_lam(S_N^L) = lam / sigma * d mu / d lam with mu, sigma of S_N^L (paper Sec. 3.2).

    Where the variance vanishes (deep saturation, or a perfectly flat step) the SNR is 0: the
    readout no longer distinguishes exposures there.
    """
    return snr_curves(lam, (n,), params, exact)[0]


def snr_curves(lam: np.ndarray, n_values: tuple[int, ...], params: SensorParams, exact: bool = False) -> np.ndarray:
    """(len(n_values), exposures): ``snr`` for every N at once (the exact variance serves all N from one pass)."""
    lam = _check_lam(lam)
    law, parts = _spike_law_parts(lam, params)
    ns = np.array(n_values, dtype=float)[:, None]
    var = ns * law.var[None, :]
    if exact and max(n_values) > 1:
        var = np.where(ns > 1, _exact_variances(law, parts, tuple(n_values), params), var)
    slope = ns * (lam * law.dmean)[None, :]
    ok = (var > 0) & (slope > 0)
    return np.where(ok, slope / np.sqrt(np.where(ok, var, 1.0)), 0.0)


@dataclass(frozen=True)
class DynamicRange:
    """Dynamic range of S_N^L: 20*log10(lam_max/lam_min) of the exposures with SNR >= 1.

    With several disjoint SNR >= 1 pieces (flat steps of E(S^L) at small N), lam_min is the lowest
    and lam_max the highest exposure with SNR >= 1 (the envelope; this reproduces Table 1, e.g.
    L = 1, 3 at N = 1); ``pieces`` lists every piece so the gaps are visible.
    """

    level: int
    n: int
    dr_db: float
    lam_min: float
    lam_max: float
    pieces: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class RangeSearch:
    """Exposure range and resolution of the SNR >= 1 search (photo-electrons per readout)."""

    lam_lo: float = 1e-6
    lam_hi: float = 1e6
    per_decade: int = 48          # initial log grid
    refine_rounds: int = 6        # adaptive subdivision rounds around extrema and steep parts
    bisect_steps: int = 24        # at most this many bisection steps on each bracketed crossing (in log lam) ...
    bisect_tolerance: float = 1e-6  # ... stopping once every bracket is narrower (in log lam: 1e-5 dB of range)


def dynamic_range(params: SensorParams, n_values: list[int], exact: bool = False,
                  search: RangeSearch = RangeSearch()) -> list[DynamicRange]:
    """Dynamic range of S_N^L for each N in ``n_values`` (paper Table 1 row for ``params.level``).

    The SNR >= 1 set is located on a log grid that is adaptively refined where SNR changes fast or
    has a local extremum near the threshold (so narrow pieces and narrow gaps are not missed); every
    crossing is then bisected, every N together. With independent intervals SNR_N = sqrt(N) * SNR_1, so all N share
    one curve (cut at 1/sqrt(N)); the exact variance has one curve per N, all N computed in one pass an exposure.
    """
    decades = math.log10(search.lam_hi / search.lam_lo)
    grid = np.logspace(math.log10(search.lam_lo), math.log10(search.lam_hi),
                       int(round(decades * search.per_decade)) + 1)
    if not exact:
        def curves(x: np.ndarray) -> np.ndarray:
            return np.broadcast_to(snr(x, 1, params), (len(n_values), x.size))
        cuts = [1.0 / math.sqrt(n) for n in n_values]
    else:
        def curves(x: np.ndarray) -> np.ndarray:
            return snr_curves(x, tuple(n_values), params, exact=True)
        cuts = [1.0] * len(n_values)
    pieces = _pieces_above(grid, curves, cuts, search)
    out = []
    for n, piece in zip(n_values, pieces):
        if not piece:
            out.append(DynamicRange(params.level, n, 0.0, math.nan, math.nan, ()))
            continue
        lam_min, lam_max = piece[0][0], piece[-1][1]
        out.append(DynamicRange(params.level, n, 20.0 * math.log10(lam_max / lam_min),
                                lam_min, lam_max, tuple(piece)))
    return out


def _pieces_above(grid: np.ndarray, func, cuts: list[float], search: RangeSearch
                  ) -> list[list[tuple[float, float]]]:
    """For each curve j of ``func`` (x -> (len(cuts), x.size)), the exposure intervals where it is >= cuts[j]."""
    x, y = np.log(grid), np.array(func(grid))
    band_lo, band_hi = 0.25 * min(cuts), 4.0 * max(cuts)
    for _ in range(search.refine_rounds):
        ly = np.clip(np.log(np.maximum(y, 1e-300)), -12.0, 12.0)
        steep = (np.abs(np.diff(ly, axis=1)) > 0.25).any(axis=0)
        mid_y = y[:, 1:-1]
        extremum = ((mid_y >= y[:, :-2]) & (mid_y >= y[:, 2:])) | ((mid_y <= y[:, :-2]) & (mid_y <= y[:, 2:]))
        near = np.zeros(x.size, bool)
        near[1:-1] = (extremum & (mid_y > band_lo) & (mid_y < band_hi)).any(axis=0)
        split = steep | near[:-1] | near[1:]
        if not split.any():
            break
        mids = 0.5 * (x[:-1] + x[1:])[split]
        order = np.argsort(np.concatenate([x, mids]))
        y = np.concatenate([y, func(np.exp(mids))], axis=1)[:, order]
        x = np.concatenate([x, mids])[order]
    # bracket every crossing of every cut, then bisect all brackets together
    lo_l, hi_l, cut_l, owner, rising_l = [], [], [], [], []
    for j, c in enumerate(cuts):
        above = y[j] >= c
        change = np.flatnonzero(above[:-1] != above[1:])
        lo_l.append(x[change])
        hi_l.append(x[change + 1])
        cut_l.append(np.full(change.size, c))
        owner.append(np.full(change.size, j))
        rising_l.append(~above[change])
    lo, hi = np.concatenate(lo_l), np.concatenate(hi_l)
    cut, who, rising = np.concatenate(cut_l), np.concatenate(owner), np.concatenate(rising_l)
    if lo.size:
        for _ in range(search.bisect_steps):
            if float(np.max(hi - lo)) < search.bisect_tolerance:
                break
            mid = 0.5 * (lo + hi)
            up = np.asarray(func(np.exp(mid)))[who, np.arange(mid.size)] >= cut
            go_right = up != rising
            lo = np.where(go_right, mid, lo)
            hi = np.where(go_right, hi, mid)
    cross = np.exp(0.5 * (lo + hi))
    result = []
    for j, c in enumerate(cuts):
        pieces = []
        start = math.exp(x[0]) if y[j, 0] >= c else None
        sel = np.flatnonzero(who == j)
        for i in sel[np.argsort(cross[sel])]:
            if rising[i]:
                start = float(cross[i])
            elif start is not None:
                pieces.append((start, float(cross[i])))
                start = None
        if start is not None:
            pieces.append((start, math.exp(x[-1])))
        result.append(pieces)
    return result


# Paper Table 1 (dB): rows L, columns N.
PAPER_TABLE1_N: tuple[int, ...] = (1, 10, 30, 70, 1000, 10000, 20000)
PAPER_TABLE1: dict[int, tuple[float, ...]] = {
    1: (9.07, 22.70, 32.73, 40.33, 63.84, 84.25, 90.38),
    3: (13.91, 32.32, 42.35, 49.95, 73.48, 93.80, 99.91),
    7: (21.79, 39.79, 49.83, 64.09, 80.83, 101.70, 107.71),
}
