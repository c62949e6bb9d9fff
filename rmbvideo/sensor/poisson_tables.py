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
    """Poisson(lam) pmf, cdf P(Y <= j) and sf P(Y > j) for j = -pad..jmax (0, 0 and 1 below zero), from log-space
    scipy calls.

    Stored with j descending (column r holds j = jmax - r), so the values at j = top, top - 1, ..., which carried
    charges c = 0, 1, ... need, are a contiguous slice (``run``), not a gather.
    """

    def __init__(self, lam: np.ndarray, jmax: int, pad: int = 1) -> None:
        j = np.arange(jmax, -pad - 1, -1)[None, :]
        jj, lam2, real = np.maximum(j, 0), lam[:, None], j >= 0
        self.pmf = np.where(real, np.exp(stats.poisson.logpmf(jj, lam2)), 0.0)
        self.cdf = np.where(real, np.exp(stats.poisson.logcdf(jj, lam2)), 0.0)
        self.sf = np.where(real, np.exp(stats.poisson.logsf(jj, lam2)), 1.0)
        self.lam, self.jmax, self.pad = lam, jmax, pad

    def take(self, table: str, j: np.ndarray, part: slice = slice(None)) -> np.ndarray:
        """(exposures, *j.shape) table values at integer indices -pad <= j <= jmax."""
        j = np.asarray(j)
        if j.size and (int(j.max()) > self.jmax or int(j.min()) < -self.pad):
            raise ValueError(f"Poisson table index outside {-self.pad}..{self.jmax}")
        return getattr(self, table)[part][:, self.jmax - j]

    def run(self, table: str, top: int, length: int, part: slice = slice(None)) -> np.ndarray:
        """(exposures, length) table values at j = top, top - 1, ..., top - length + 1: a view."""
        start = self.jmax - top
        if start < 0 or start + length > self.jmax + self.pad + 1:
            raise ValueError(f"Poisson table run {top}..{top - length + 1} outside {-self.pad}..{self.jmax}")
        return getattr(self, table)[part, start: start + length]


def at_least(tab: PoissonTables, part: slice, need: np.ndarray) -> np.ndarray:
    """P(Y >= need) at the exposures ``part`` (1 where need <= 0), for any shape of ``need`` after theirs."""
    return tab.take("sf", np.maximum(need - 1, -1), part)
