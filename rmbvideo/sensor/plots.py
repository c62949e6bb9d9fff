"""Figures of the dynamic-range theory: paper Fig. 2 (mean and std of S^L/L) and Fig. 3 (SNR).

matplotlib is imported inside the functions so the rest of rmbvideo works without it.
Exposure is in photo-electrons per readout interval (alpha = 1); the paper's Fig. 3 axis is
photons/(um^2 s), a constant factor that shifts the curves but not the dynamic range in dB.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from rmbvideo.sensor.params import SensorParams
from rmbvideo.sensor.theory import snr, snr_curves, spike_law


def _figure_module():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def expectation_std_figure(params: SensorParams, levels: tuple[int, ...] = (1, 3, 7),
                           lam: np.ndarray | None = None) -> Any:
    """Paper Fig. 2: E and std of the normalised spike S^L/L versus exposure (N = 1)."""
    plt = _figure_module()
    lam = np.linspace(1.0, 300.0, 300) if lam is None else lam
    fig, (ax_mean, ax_std) = plt.subplots(1, 2, figsize=(10, 4))
    for level in levels:
        law = spike_law(lam, replace(params, level=level))
        ax_mean.plot(lam, law.mean / level, label=f"L = {level}")
        ax_std.plot(lam, np.sqrt(law.var) / level, label=f"L = {level}")
    ax_mean.set(xlabel="exposure (photo-electrons per readout)", ylabel="E(S^L / L)",
                title="(a) expectation")
    ax_std.set(xlabel="exposure (photo-electrons per readout)", ylabel="std(S^L / L)",
               title="(b) standard deviation")
    for ax in (ax_mean, ax_std):
        ax.legend()
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def snr_figure(params: SensorParams, levels: tuple[int, ...] = (1, 3, 7),
               n_fixed: int = 10, n_values: tuple[int, ...] = (10, 30, 70), level_fixed: int = 1,
               exact: bool = False, lam: np.ndarray | None = None) -> Any:
    """Paper Fig. 3: SNR of S_N^L vs exposure, (a) N fixed and L varied, (b) L fixed and N varied."""
    plt = _figure_module()
    lam = np.logspace(-2, 3, 300) if lam is None else lam
    fig, (ax_l, ax_n) = plt.subplots(1, 2, figsize=(10, 4))
    top = 1.0
    for level in levels:
        curve = snr(lam, n_fixed, replace(params, level=level), exact=exact)
        top = max(top, float(curve.max()))
        ax_l.plot(lam, curve, label=f"L = {level}")
    for n, curve in zip(n_values, snr_curves(lam, tuple(n_values), replace(params, level=level_fixed), exact=exact)):
        top = max(top, float(curve.max()))
        ax_n.plot(lam, curve, label=f"N = {n}")
    ax_l.set_title(f"(a) N = {n_fixed}")
    ax_n.set_title(f"(b) L = {level_fixed}")
    for ax in (ax_l, ax_n):
        ax.set(xscale="log", yscale="log", xlabel="exposure (photo-electrons per readout)",
               ylabel="SNR")
        ax.set_ylim(1e-2, 3.0 * top)
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.legend()
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return fig
