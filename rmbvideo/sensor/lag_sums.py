"""Exact lag sums sum_{j=1}^{n-1} (n-j) Cov(S_0, S_j) of a pixel's carried-charge chain (supplement Sec. 8).

The interval correlation that carried charge causes makes Var(S_N) smaller than N Var(S); ``theory.sum_moments``
adds these sums to N Var(S). Two exact ways, the cheaper taken: binary powers of the chain, or a renewal equation
over the charge's jumps.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal, special

from rmbvideo.sensor.poisson_tables import PoissonTables, at_least, level_thresholds


def covariance_sums(lam: np.ndarray, k: int, q_values: np.ndarray, level: int, horizons: tuple[int, ...],
                     means: np.ndarray) -> np.ndarray:
    """(horizons, thresholds Q', exposures): sum_{j=1}^{n-1} (n-j) Cov(S_0, S_j) of the stationary chain, each n.

    After any spike the charge is zero, so Cov(S_0, S_j) = mu * (e_0 P^{j-1} r - mu) with r(c) the expected readout
    from charge c (supplement Sec. 8). Two exact ways to the sum, the cheaper one taken: binary powers of P (T_1^3 a
    squaring, ~log2 n squarings an n; ``_power_sums``) or one renewal pass serving every n (T_1 a jump, up to the
    largest n; ``_renewal_sums``). Exposures go in batches that hold ``_CHAIN_BYTES`` of chain matrices.
    """
    out = np.zeros((len(horizons), q_values.size, lam.size))
    if max(horizons) <= 1:
        return out
    t1s = np.array([int(level_thresholds(int(q), level)[0]) for q in q_values])
    t_max = int(t1s.max())
    tab = PoissonTables(lam, int(q_values.max()) + 2, pad=k + 2)
    renewal, _ = covariance_method(t_max, horizons)
    copies = 2 if renewal else max(horizons).bit_length() + 2   # the visits and a Toeplitz, or P^(2^l) for each l
    chunk = max(1, _CHAIN_BYTES // (8 * copies * t_max ** 2))
    for lo in range(0, lam.size, chunk):
        part = slice(lo, min(lo + chunk, lam.size))
        sums = _renewal_sums if renewal else _power_sums
        out[:, :, part] = sums(tab, part, k, q_values, t1s, level, horizons, means[:, part])
    return out


# memory for the chain matrices of one batch of exposures (T_1^2 floats an exposure, a few of them)
_CHAIN_BYTES = 64 << 20
# one multiply-add of the renewal's filter costs about this many of a matrix product's (one core: the renewal is the
# faster at L = 1 (T_1 ~ 105; 4.7 vs 5.6 minutes for the default table), the powers at L = 3 (T_1 ~ 35))
_FILTER_COST = 4.0


def covariance_method(t_max: int, horizons: tuple[int, ...]) -> tuple[bool, float]:
    """(renewal is the cheaper, its work) for one threshold and exposure, in a matrix product's multiply-adds."""
    powers = max(horizons).bit_length() * t_max ** 3 + 4 * sum(math.log2(n) for n in horizons) * t_max ** 2
    renewal = _FILTER_COST * t_max * max(horizons) + t_max ** 2
    return renewal < powers, min(renewal, powers)


def _power_sums(tab: PoissonTables, part: slice, k: int, q_values: np.ndarray, t1s: np.ndarray, level: int,
                horizons: tuple[int, ...], means: np.ndarray) -> np.ndarray:
    """``covariance_sums`` for the exposures ``part`` by binary powers of P, shared by every n and every threshold
    with the same T_1: W_m v = sum_{i<m} (m - i) P^i v is built from segments of length 2^l, with U_a = sum_{i<a} P^i v
    (a segment a put before a sum b: W_{a+b} = W_a + b U_a + P^a W_b), so only the squarings are matrix products."""
    lags = [n - 1 for n in horizons]
    top = max(lags).bit_length()
    out = np.zeros((len(horizons), q_values.size, part.stop - part.start))

    def apply(matrix: np.ndarray, vec: np.ndarray) -> np.ndarray:
        return np.einsum("nij,nj->ni", matrix, vec)

    for t1 in np.unique(t1s):
        c = np.arange(int(t1))
        chain = tab.take("pmf", np.maximum(c[None, :] - c[:, None] - k, -1), part)   # c -> c + X (pmf 0 below 0)
        chain[:, :, 0] += at_least(tab, part, t1 - c - k)   # c -> c + X, or a firing and the reset to 0
        powers = [chain]                                        # P^(2^l)
        for _ in range(1, top):
            powers.append(powers[-1] @ powers[-1])
        for i in np.flatnonzero(t1s == t1):
            th = level_thresholds(int(q_values[i]), level)
            vec = at_least(tab, part, th[:, None] - c[None, :] - k).sum(axis=1) - means[i][:, None]
            seg_u, seg_w = [vec], [vec]                         # U and W of length 2^l
            for lvl in range(1, top):
                size, p_a = 1 << (lvl - 1), powers[lvl - 1]
                seg_w.append(seg_w[-1] + size * seg_u[-1] + apply(p_a, seg_w[-1]))
                seg_u.append(seg_u[-1] + apply(p_a, seg_u[-1]))
            for h, m in enumerate(lags):
                if m < 1:
                    continue
                w, done = np.zeros_like(vec), 0
                for lvl in range(top):
                    if m >> lvl & 1:
                        w = seg_w[lvl] + done * seg_u[lvl] + apply(powers[lvl], w)
                        done += 1 << lvl
                out[h, i] = means[i] * w[:, 0]
    return out


def _renewal_sums(tab: PoissonTables, part: slice, k: int, q_values: np.ndarray, t1s: np.ndarray, level: int,
                  horizons: tuple[int, ...], means: np.ndarray) -> np.ndarray:
    """``covariance_sums`` for the exposures ``part`` by a renewal equation over the jumps of the charge.

    An interval moves the charge with probability p = P(X >= 1) whatever the charge, so P = (1 - p) I + p J, with J
    the chain of the jumps alone, and P^m is a binomial mixture of the powers of J. A cycle of J (0 back to 0) takes
    at most T_1 jumps, so e_0 J^j r obeys a renewal equation of order T_1, solved once up to the largest n.
    """
    lam = tab.lam[part]
    moves = -np.expm1(-lam) if k == 0 else np.ones(lam.size)       # p = P(X >= 1)
    n_lam, t_max = moves.size, int(t1s.max())
    weights = [_binomial_lag_weights(moves, n - 2) for n in horizons]
    span = max(w.shape[1] for w in weights)
    spans = np.max([w.shape[1] - np.argmax(w[:, ::-1] > 0, axis=1) for w in weights], axis=0)  # each exposure's own
    jumps = min(t_max, span)                           # only the first ``span`` jumps enter any lag sum
    # the jump law P(X = j | X >= 1), j < T_1max, and visits[:, t, c] = P(charge c after t jumps, no firing yet)
    # (the largest threshold's serve every smaller one: charges below T_1 are reached only from below T_1)
    jump = np.arange(t_max)
    step = np.where(jump >= 1, tab.take("pmf", np.maximum(jump - k, -1), part), 0.0)
    step /= moves[:, None]
    toeplitz = np.zeros((n_lam, t_max, t_max))
    for c in range(t_max):
        toeplitz[:, c, c:] = step[:, : t_max - c]
    visits = np.zeros((n_lam, jumps, t_max))
    visits[:, 0, 0] = 1.0
    for t in range(1, jumps):
        visits[:, t] = np.matmul(visits[:, t - 1, None, :], toeplitz)[:, 0]
    del toeplitz
    out = np.zeros((len(horizons), q_values.size, n_lam))
    for i, q in enumerate(q_values):
        th = level_thresholds(int(q), level)
        t1 = int(t1s[i])
        c = np.arange(t1)
        fire_from = at_least(tab, part, t1 - c - k) / moves[:, None]                   # P(c + X >= T_1 | X >= 1)
        reward = at_least(tab, part, th[:, None] - c[None, :] - k).sum(axis=1) / moves[:, None]  # E(S | c, X >= 1)
        reach = visits[:, :t1, :t1]
        fire = np.einsum("ntc,nc->nt", reach, fire_from)              # first firing at jump t + 1
        gain = np.einsum("ntc,nc->nt", reach, reward)                 # y_j: its readout, if at jump j + 1
        waiting = np.cumsum(fire[:, ::-1], axis=1)[:, ::-1]           # P(no firing in the first j jumps), when whole
        if jumps >= t1:   # the whole cycle is here: its own mean readout a jump, so that d decays to 0, not to rounding
            rate = gain.sum(axis=1) / waiting.sum(axis=1)
        else:
            rate = means[i] / moves
            waiting = 1.0 - np.cumsum(np.concatenate((np.zeros((n_lam, 1)), fire[:, :-1]), axis=1), axis=1)
        excess = np.zeros((n_lam, max(span, t1)))
        excess[:, : fire.shape[1]] = gain - rate[:, None] * waiting
        dev = np.zeros_like(excess)
        for r in range(n_lam):
            # d_j = e_j + sum_t f_t d_{j-t}, with e_j = y_j - mu/p P(tau > j): d_j = e_0 J^j r - mu/p
            dev[r, : spans[r]] = _renewal(fire[r], excess[r, : spans[r]])
        for h, w in enumerate(weights):
            out[h, i] = means[i] * moves * np.einsum("nj,nj->n", w, dev[:, : w.shape[1]])
    return out


def _renewal(fire: np.ndarray, excess: np.ndarray) -> np.ndarray:
    """d_j = e_j + sum_{t=1}^{T} f_t d_{j-t}, j = 0..len(e)-1, a filter run in stretches of doubling length.

    Past the first T jumps e = 0 and d_j is an average of the T values before it (sum f = 1), so once T in a row
    are below ``tol`` every later one is, and the rest are left zero (their share of any lag sum is below tol * sum K).
    """
    order = fire.size
    denom = np.concatenate(([1.0], -fire))
    tol = 1e-18 * float(np.abs(excess[:order]).max(initial=0.0))
    out = np.zeros(excess.size)
    state = np.zeros(order)
    pos, stretch = 0, max(4 * order, 256)
    while pos < excess.size:
        end = min(excess.size, pos + stretch)
        out[pos:end], state = signal.lfilter([1.0], denom, excess[pos:end], zi=state)
        pos, stretch = end, 2 * stretch
        if pos >= order and float(np.abs(out[pos - order: pos]).max()) <= tol:
            break
    return out


def _binomial_lag_weights(moves: np.ndarray, horizon: int) -> np.ndarray:
    """K_j = sum_{m=j}^{M} (M + 1 - m) P(Bin(m, p) = j), j = 0.., the weight of jump count j in the lag sum up to M.

    With T the trial of the (j+1)-th success, K_j = ((M + 2) P(T <= M + 1) - E[T; T <= M + 1]) / p, two binomial
    tails; weights below 1e-30 of K_0 are zero, and the columns past every exposure's last weight are dropped.
    """
    if horizon < 0:
        return np.zeros((moves.size, 1))
    j = np.arange(horizon + 1)[None, :]
    p = moves[:, None]
    first = special.bdtrc(j, horizon + 1, p)          # P(Bin(M + 1, p) >= j + 1)
    second = special.bdtrc(j + 1, horizon + 2, p)     # P(Bin(M + 2, p) >= j + 2)
    weights = np.maximum(((horizon + 2) * first - (j + 1) / p * second) / p, 0.0)
    weights = np.where(p >= 1.0, (horizon + 1 - j).astype(float), weights)
    weights = np.where(weights > 1e-30 * weights[:, :1], weights, 0.0)
    return weights[:, : int(np.flatnonzero(weights.any(axis=0))[-1]) + 1]
