"""Independent physical effects of the emission model (paper Sec. 3.1, supplement Sec. 7).

Each effect is a component that a scene switches on by name. Only listed effects are built, and
each random effect owns a generator derived from ``(seed, effect name)``, so switching one effect
off never changes the random numbers the others draw. A set of effects without any random one
builds no generator at all: the simulation is then deterministic.

Effects and where the randomness lives (all charges in electrons, one interval = one readout):

- ``shot_noise``: photo-electrons are Poisson with the expected charge as mean (without it the
  charge is exactly the expected value, a real number).
- ``dark_current``: dark electrons per interval are ``round(mu_d + sigma_d * z)`` (supplement
  Eqn. 16) where ``z`` is unit-variance white noise blurred by a Gaussian of standard deviation
  ``correlation_px`` pixels (reflecting borders) and renormalised, redrawn every interval.
- ``threshold_mismatch``: capacitance deviation C^S, fixed per pixel for the whole capture.
- ``reset_noise``: reset-voltage deviation V^S, drawn at the start and at every reset of a pixel.
- ``thermal_noise``: temperature voltage deviation V^T0, drawn per pixel at every readout.
- ``readout_rounding``: the threshold charge is rounded to whole electrons (supplement Eqn. 21).
- ``rolling_readout``: row ``r`` of an ``H``-row sensor is read ``r / H`` of an interval after row
  0, so each row integrates the scene over its own, later interval.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import cv2
import numpy as np

from rmbvideo.sensor.params import SensorParams


def stable_hash(name: str) -> int:
    """A 64-bit hash of ``name`` that is the same in every process (unlike ``hash``)."""
    return int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:8], "little")


def effect_rng(seed: int, name: str) -> np.random.Generator:
    """The private random generator of effect ``name`` for a simulation seeded with ``seed``."""
    return np.random.default_rng(np.random.SeedSequence([seed, stable_hash(name)]))


class ShotNoise:
    """Poisson photo-electrons: the number of photons converted in an interval is random."""

    name = "shot_noise"

    def __init__(self, seed: int) -> None:
        self.rng = effect_rng(seed, self.name)

    def electrons(self, expected: np.ndarray) -> np.ndarray:
        """Draw photo-electron counts with mean ``expected`` (same shape, float64)."""
        return self.rng.poisson(expected).astype(np.float64)


class DarkCurrent:
    """Spatially correlated Gaussian dark current, rounded to whole electrons per interval."""

    name = "dark_current"

    def __init__(self, seed: int, shape: tuple[int, int], params: SensorParams,
                 correlation_px: float) -> None:
        self.rng = effect_rng(seed, self.name)
        self.shape = shape
        self.mean = params.dark_mean
        self.std = params.dark_std
        self.correlation_px = correlation_px
        if correlation_px > 0:
            radius = max(1, int(np.ceil(3 * correlation_px)))
            kernel = cv2.getGaussianKernel(2 * radius + 1, correlation_px, cv2.CV_64F)
            self.kernel = kernel
            # Variance of separably blurred unit white noise is (sum k^2)^2 away from borders.
            self.norm = 1.0 / float(np.sum(kernel ** 2))
        else:
            self.kernel = None
            self.norm = 1.0

    def electrons(self) -> np.ndarray:
        """Dark electrons of one interval, (H, W) float64 integers."""
        white = self.rng.standard_normal(self.shape)
        if self.kernel is not None:
            white = cv2.sepFilter2D(white, cv2.CV_64F, self.kernel, self.kernel,
                                    borderType=cv2.BORDER_REFLECT) * self.norm
        return np.round(self.mean + self.std * white)


class ThresholdMismatch:
    """Capacitance deviation C^S: a fixed per-pixel offset of the threshold (fixed-pattern noise)."""

    name = "threshold_mismatch"

    def __init__(self, seed: int, shape: tuple[int, int], params: SensorParams) -> None:
        rng = effect_rng(seed, self.name)
        self.capacitance_offset = params.cap_std * rng.standard_normal(shape)


class ResetNoise:
    """Reset-voltage deviation V^S: a new value each time a pixel is reset."""

    name = "reset_noise"

    def __init__(self, seed: int, shape: tuple[int, int], params: SensorParams) -> None:
        self.rng = effect_rng(seed, self.name)
        self.shape = shape
        self.std = params.reset_v_std
        self.voltage_offset = self.std * self.rng.standard_normal(shape)

    def reset(self, mask: np.ndarray) -> None:
        """Redraw V^S of the pixels in ``mask``; one full draw per readout keeps streams aligned."""
        fresh = self.std * self.rng.standard_normal(self.shape)
        self.voltage_offset[mask] = fresh[mask]


class ThermalNoise:
    """Temperature voltage deviation V^T0: independent per pixel and readout."""

    name = "thermal_noise"

    def __init__(self, seed: int, shape: tuple[int, int], params: SensorParams) -> None:
        self.rng = effect_rng(seed, self.name)
        self.shape = shape
        self.std = params.temp_v_std

    def voltage_offset(self) -> np.ndarray:
        """V^T0 for one readout, (H, W)."""
        return self.std * self.rng.standard_normal(self.shape)


@dataclass(frozen=True)
class ReadoutRounding:
    """The readout circuit resolves whole electrons: the threshold is rounded (Eqn. 21)."""

    name = "readout_rounding"

    @staticmethod
    def apply(threshold: np.ndarray) -> np.ndarray:
        return np.round(threshold)


@dataclass(frozen=True)
class RollingReadout:
    """Rows are read one after another within an interval: row ``r`` is ``r/H`` interval late."""

    name = "rolling_readout"

    @staticmethod
    def row_delay(height: int) -> np.ndarray:
        """Delay of each row in readout intervals, (H, 1) float64 in [0, 1)."""
        return (np.arange(height, dtype=np.float64) / height)[:, None]


#: Every effect a scene may list, with a one-line description (for ``--list`` and errors).
EFFECTS: dict[str, str] = {
    "shot_noise": "Poisson photo-electrons",
    "dark_current": "spatially correlated Gaussian dark electrons, rounded",
    "threshold_mismatch": "fixed per-pixel capacitance deviation C^S",
    "reset_noise": "reset-voltage deviation V^S per reset",
    "thermal_noise": "temperature voltage deviation V^T0 per readout",
    "readout_rounding": "threshold rounded to whole electrons",
    "rolling_readout": "rows read at staggered times within each interval",
}
#: Noise effects of a real 1-bit camera (rolling readout is left out: real captures are global).
REALISTIC_EFFECTS = ("shot_noise", "dark_current", "threshold_mismatch", "reset_noise", "thermal_noise",
                     "readout_rounding")

