"""Sensor parameters of the emission model (paper Sec. 3.1, supplement Sec. 7), shared by the
Monte-Carlo simulator and the theory so both describe the same sensor.

All charges are in electrons; one "interval" is one readout interval tau.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


#: What a spike does to the pixel's charge: "zero" (the paper's rule: the charge is discarded, so the part past the
#: threshold is lost and the pixel fires every second plane for any light from about 0.6 to 0.8 of a threshold) or
#: "subtract" (the threshold's charge is taken off and the rest kept, at most one threshold: a pixel reset at its
#: crossing, as real spiking cameras such as the one behind ``car.dat`` behave: its rate is its light up to one
#: spike a plane; ``rmbvideo.sensor.conventions``).
RESETS = ("zero", "subtract")


@dataclass(frozen=True)
class SensorParams:
    """Integrate-and-fire pixel with L-level quantisation and the noise sources of supplement Sec. 7.

    The threshold is Q_th = (C + C^S)(V + V^S + V^T0) (supplement Eqn. 18) with Q_r = C*V.
    C^S is fixed per pixel (capacitance mismatch), V^S is drawn per reset and V^T0 per readout.
    Dark electrons per interval are round(N(dark_mean, dark_std^2)) (supplement Eqn. 16).
    Defaults follow supplement Sec. 10 ("Q_r = 105, mu_d = 0.05, variance of all noise 0.005"). The
    paper does not give the split of Q_r into C and V; C = 1.4, V = 75 reproduces its Table 1
    (``rmbvideo.sensor.theory``).
    """

    level: int = 1                     # L = 2^B - 1
    capacitance: float = 1.4           # C (arbitrary units; Q_r = C * V = 105)
    voltage: float = 75.0              # V
    cap_std: float = math.sqrt(0.005)  # sigma of C^S, fixed per pixel
    reset_v_std: float = math.sqrt(0.005)  # sigma of V^S, drawn per reset
    temp_v_std: float = math.sqrt(0.005)   # sigma of V^T0, drawn per readout
    dark_mean: float = 0.05            # mu_d, mean dark electrons per interval
    dark_std: float = math.sqrt(0.005)  # sigma_d of the dark electrons per interval
    reset: str = "zero"                # what a spike does to the charge: see RESETS

    def __post_init__(self) -> None:
        if self.reset not in RESETS:
            raise ValueError(f"reset must be one of {RESETS}, got {self.reset!r}")

    @property
    def q_r(self) -> float:
        """Nominal threshold charge Q_r = C * V (electrons)."""
        return self.capacitance * self.voltage
