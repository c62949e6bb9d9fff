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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import cv2
import numpy as np

from rmbvideo.sensor.params import SensorParams


def stable_hash(name: str) -> int:
    """A 64-bit hash of ``name`` that is the same in every process (unlike ``hash``)."""
    return int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:8], "little")


def effect_rng(seed: int, name: str) -> np.random.Generator:
    """The private random generator of effect ``name`` for a simulation seeded with ``seed``."""
    return np.random.default_rng(np.random.SeedSequence([seed, stable_hash(name)]))


@dataclass(frozen=True)
class EffectContext:
    """What every effect is built from: the simulation's seed, the pixel array's shape, the sensor
    parameters, and the spatial correlation of the dark current (pixels)."""

    seed: int
    shape: tuple[int, int]
    params: SensorParams
    dark_correlation_px: float = 1.5


class Effect:
    """One physical effect of the emission model. Each hook is one step of a readout with a neutral
    default, so an effect overrides only the steps it changes (``SpikeEmitter`` calls only those):

    ``photo_electrons`` (expected -> drawn photo-charge), ``dark_electrons`` (extra charge per
    interval), ``capacitance_offset`` (fixed C^S), ``voltage_offset`` (V^S + V^T0 this readout),
    ``threshold`` (the threshold as the circuit resolves it), ``after_readout`` (given the pixels
    that fired and were reset), and ``row_delay`` (readout time of each row, used by the capture
    simulation). A new effect is one subclass plus one line in ``EFFECT_TYPES``.
    """

    name: ClassVar[str]
    description: ClassVar[str]

    def __init__(self, context: EffectContext) -> None:
        self.context = context

    def photo_electrons(self, expected: np.ndarray) -> np.ndarray:
        return expected

    def dark_electrons(self) -> np.ndarray | float:
        return 0.0

    def capacitance_offset(self) -> np.ndarray | float:
        return 0.0

    def voltage_offset(self) -> np.ndarray | float:
        return 0.0

    def threshold(self, threshold: np.ndarray | float) -> np.ndarray | float:
        return threshold

    def after_readout(self, fired: np.ndarray) -> None:
        return None

    @staticmethod
    def row_delay(height: int) -> np.ndarray | float:
        return 0.0

    @classmethod
    def overrides(cls, hook: str) -> bool:
        """Whether this effect changes step ``hook`` (so the emitter can skip neutral calls)."""
        return getattr(cls, hook) is not getattr(Effect, hook)


class ShotNoise(Effect):
    """Poisson photo-electrons: the number of photons converted in an interval is random."""

    name = "shot_noise"
    description = "Poisson photo-electrons"

    def __init__(self, context: EffectContext) -> None:
        super().__init__(context)
        self.rng = effect_rng(context.seed, self.name)

    def photo_electrons(self, expected: np.ndarray) -> np.ndarray:
        """Draw photo-electron counts with mean ``expected`` (same shape, float64)."""
        return self.rng.poisson(expected).astype(np.float64)


class DarkCurrent(Effect):
    """Spatially correlated Gaussian dark current, rounded to whole electrons per interval."""

    name = "dark_current"
    description = "spatially correlated Gaussian dark electrons, rounded"

    def __init__(self, context: EffectContext) -> None:
        super().__init__(context)
        self.rng = effect_rng(context.seed, self.name)
        self.shape = context.shape
        self.mean = context.params.dark_mean
        self.std = context.params.dark_std
        correlation_px = context.dark_correlation_px
        if correlation_px > 0:
            radius = max(1, int(np.ceil(3 * correlation_px)))
            kernel = cv2.getGaussianKernel(2 * radius + 1, correlation_px, cv2.CV_64F)
            self.kernel = kernel
            # Variance of separably blurred unit white noise is (sum k^2)^2 away from borders.
            self.norm = 1.0 / float(np.sum(kernel ** 2))
        else:
            self.kernel = None
            self.norm = 1.0

    def dark_electrons(self) -> np.ndarray:
        """Dark electrons of one interval, (H, W) float64 integers."""
        white = self.rng.standard_normal(self.shape)
        if self.kernel is not None:
            white = cv2.sepFilter2D(white, cv2.CV_64F, self.kernel, self.kernel,
                                    borderType=cv2.BORDER_REFLECT) * self.norm
        return np.round(self.mean + self.std * white)


class ThresholdMismatch(Effect):
    """Capacitance deviation C^S: a fixed per-pixel offset of the threshold (fixed-pattern noise)."""

    name = "threshold_mismatch"
    description = "fixed per-pixel capacitance deviation C^S"

    def __init__(self, context: EffectContext) -> None:
        super().__init__(context)
        rng = effect_rng(context.seed, self.name)
        self._offset = context.params.cap_std * rng.standard_normal(context.shape)

    def capacitance_offset(self) -> np.ndarray:
        return self._offset


class ResetNoise(Effect):
    """Reset-voltage deviation V^S: a new value each time a pixel is reset."""

    name = "reset_noise"
    description = "reset-voltage deviation V^S per reset"

    def __init__(self, context: EffectContext) -> None:
        super().__init__(context)
        self.rng = effect_rng(context.seed, self.name)
        self.shape = context.shape
        self.std = context.params.reset_v_std
        self._offset = self.std * self.rng.standard_normal(self.shape)

    def voltage_offset(self) -> np.ndarray:
        return self._offset

    def after_readout(self, fired: np.ndarray) -> None:
        """Redraw V^S of the pixels that were reset; one full draw per readout keeps streams aligned."""
        fresh = self.std * self.rng.standard_normal(self.shape)
        self._offset[fired] = fresh[fired]


class ThermalNoise(Effect):
    """Temperature voltage deviation V^T0: independent per pixel and readout."""

    name = "thermal_noise"
    description = "temperature voltage deviation V^T0 per readout"

    def __init__(self, context: EffectContext) -> None:
        super().__init__(context)
        self.rng = effect_rng(context.seed, self.name)
        self.shape = context.shape
        self.std = context.params.temp_v_std

    def voltage_offset(self) -> np.ndarray:
        """V^T0 for one readout, (H, W)."""
        return self.std * self.rng.standard_normal(self.shape)


class ReadoutRounding(Effect):
    """The readout circuit resolves whole electrons: the threshold is rounded (Eqn. 21)."""

    name = "readout_rounding"
    description = "threshold rounded to whole electrons"

    def threshold(self, threshold: np.ndarray | float) -> np.ndarray | float:
        return np.round(threshold)


class RollingReadout(Effect):
    """Rows are read one after another within an interval: row ``r`` is ``r/H`` interval late."""

    name = "rolling_readout"
    description = "rows read at staggered times within each interval"

    @staticmethod
    def row_delay(height: int) -> np.ndarray:
        """Delay of each row in readout intervals, (H, 1) float64 in [0, 1)."""
        return (np.arange(height, dtype=np.float64) / height)[:, None]


#: Every effect a scene may list, in the order the emitter applies them.
EFFECT_TYPES: dict[str, type[Effect]] = {cls.name: cls for cls in (
    ShotNoise, DarkCurrent, ThresholdMismatch, ResetNoise, ThermalNoise, ReadoutRounding, RollingReadout)}
#: Name -> one-line description (for ``--list`` and errors).
EFFECTS: dict[str, str] = {name: cls.description for name, cls in EFFECT_TYPES.items()}
#: Noise effects of a real 1-bit camera (rolling readout is left out: real captures are global).
REALISTIC_EFFECTS = ("shot_noise", "dark_current", "threshold_mismatch", "reset_noise", "thermal_noise",
                     "readout_rounding")


def row_delay(effects: Sequence[str], height: int) -> np.ndarray | float:
    """Readout delay of each row (intervals) under ``effects``: 0 for a global readout."""
    delay: np.ndarray | float = 0.0
    for name in effects:
        delay = delay + EFFECT_TYPES[name].row_delay(height)
    return delay
