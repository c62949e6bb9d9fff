"""Poisson tables of the photo-electrons in one readout interval, and the charges at which each level fires.

Shared by the spike law (``theory``) and the exact lag sums (``lag_sums``); probabilities come from scipy's log-space
Poisson functions, so they stay exact from 1e-6 to 1e6 electrons an interval.
"""

from __future__ import annotations

import numpy as np
from scipy import stats


def level_thresholds(q_th: int, level: int) -> np.ndarray:
    """Charges T_H = ceil(H*Q'/L), H = 1..L, at which level H is reached (Eqn. 2, integer charge)."""
    h = np.arange(1, level + 1, dtype=np.int64)
    return np.maximum(-((-h * q_th) // level), 1)


class PoissonTables:
    """Poisson(lam) pmf, cdf P(Y<=j) and sf P(Y>j) for j = 0..jmax, from log-space scipy calls."""

    def __init__(self, lam: np.ndarray, jmax: int) -> None:
        j = np.arange(jmax + 1)[None, :]
        lam2 = lam[:, None]
        self.pmf = np.exp(stats.poisson.logpmf(j, lam2))
        self.cdf = np.exp(stats.poisson.logcdf(j, lam2))
        self.sf = np.exp(stats.poisson.logsf(j, lam2))
        self.lam, self.jmax = lam, jmax

    def take(self, table: str, j: np.ndarray, below: float) -> np.ndarray:
        """Table values at integer indices ``j <= jmax`` (any shape); ``below`` where j < 0."""
        arr = getattr(self, table)
        jj = np.clip(j, 0, self.jmax)
        out = arr[:, jj]
        out = np.where(j < 0, below, out)
        return out


def at_least(tab: PoissonTables, part: slice, need: np.ndarray) -> np.ndarray:
    """P(Y >= need) at the exposures ``part`` (1 where need <= 0), for any shape of ``need`` after theirs."""
    out = tab.sf[part][:, np.clip(need - 1, 0, tab.jmax)]
    return np.where(need <= 0, 1.0, out)
