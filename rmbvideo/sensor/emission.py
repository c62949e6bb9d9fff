"""Spike emission of an integrate-and-fire pixel array (paper Eqns. 1-3, supplement Sec. 7).

Per pixel and readout interval the charge is ``Q_c = Q_a + Q_p + Q_d`` (carried, photo and dark
electrons). A pixel read with level ``L`` (1 for single-bit) gives ``S = L`` when
``Q_c >= Q_th`` and ``floor(Q_c * L / Q_th)`` otherwise, and is reset to zero when ``S > 0``
(the paper's rule); otherwise its charge is carried to the next interval. The threshold is
``Q_th = (C + C^S)(V + V^S + V^T0)``. Which noise terms exist is decided by the effects of
``rmbvideo.sensor.effects``; without any, ``Q_p`` is the expected charge and ``Q_th = C*V``.

Readouts (``ReadoutSpec.kind``):

- ``1bit``: every pixel single-bit.
- ``Lbit``: every pixel at level ``L`` (full multi-bit planes).
- ``rmb``: a native rolling-mixed-bit sensor: at readout ``k`` the rows
  ``(k*shift + j) mod H`` for ``j < band`` are read at level ``L`` (and reset by the multi-bit
  rule), the others single-bit.
- ``binned``: single-bit at the scene's (raw) size and rate; the stream is binned 2x2x2 later,
  exactly as real captures are (``rmbvideo.sensor.binning``).

For ``Lbit`` and ``rmb`` the single-bit plane of an ``RmbChunk`` is ``S == L`` where a row was read
multi-bit (the charge reached the threshold), and the single-bit value elsewhere.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np


from rmbvideo.sensor.effects import EFFECT_TYPES, Effect, EffectContext
from rmbvideo.sensor.params import SensorParams
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

log = logging.getLogger(__name__)

READOUT_KINDS = ("1bit", "Lbit", "rmb", "binned")

#: The smallest threshold charge allowed, so extreme noise settings never divide by zero.
MIN_THRESHOLD_E = 1.0


@dataclass(frozen=True)
class ReadoutSpec:
    """How pixels are read: kind (see module docstring), multi-bit level, RMB band and shift."""

    kind: str = "1bit"
    level: int = 7
    band: int = 4
    shift: int = 2

    def __post_init__(self) -> None:
        if self.kind not in READOUT_KINDS:
            raise ValueError(f"readout kind must be one of {READOUT_KINDS}, not {self.kind!r}")
        if self.level < 1 or (self.level + 1) & self.level:
            raise ValueError(f"level must be 2^B - 1 (1, 3, 7, ...), not {self.level}")
        if self.band < 1 or self.shift < 1:
            raise ValueError("band and shift must be >= 1")

    @property
    def is_multibit(self) -> bool:
        """Whether the readout produces multi-bit values (``Lbit`` or ``rmb``)."""
        return self.kind in ("Lbit", "rmb")

    def multi_rows(self, start: int, count: int, height: int) -> np.ndarray:
        """(count, H) bool: rows read multi-bit at readouts ``start .. start+count-1``."""
        if self.kind == "Lbit":
            return np.ones((count, height), dtype=bool)
        if self.kind == "rmb":
            return RmbReadout(ReadoutMode.RMB, self.band, self.shift).multi_rows(start, count, height)
        return np.zeros((count, height), dtype=bool)


class SpikeEmitter:
    """The pixel array's state machine: expected photo-charge in, quantised spikes out.

    State (carried charge, V^S) persists across calls, so feeding a capture in chunks of any
    size gives the same result as feeding it at once.
    """

    def __init__(self, height: int, width: int, params: SensorParams, effects: Sequence[str],
                 seed: int, dark_correlation_px: float = 1.5) -> None:
        unknown = sorted(set(effects) - set(EFFECT_TYPES))
        if unknown:
            raise ValueError(f"unknown effects {unknown}; known: {sorted(EFFECT_TYPES)}")
        shape = (height, width)
        self.shape = shape
        self.params = params
        context = EffectContext(seed, shape, params, dark_correlation_px)
        self.effects = [cls(context) for name, cls in EFFECT_TYPES.items() if name in effects]
        self._hooks = {hook: [e for e in self.effects if e.overrides(hook)]
                       for hook in ("photo_electrons", "dark_electrons", "voltage_offset", "threshold",
                                    "after_readout")}
        self.charge = np.zeros(shape, dtype=np.float64)
        self.capacitance: np.ndarray | float = params.capacitance
        for effect in self.effects:
            if effect.overrides("capacitance_offset"):
                self.capacitance = self.capacitance + effect.capacitance_offset()

    @property
    def components(self) -> dict[str, Effect]:
        """The effects that were built (only those the caller listed), by name."""
        return {e.name: e for e in self.effects}

    def _threshold(self) -> np.ndarray | float:
        voltage: np.ndarray | float = self.params.voltage
        for effect in self._hooks["voltage_offset"]:
            voltage = voltage + effect.voltage_offset()
        threshold = self.capacitance * voltage
        for effect in self._hooks["threshold"]:
            threshold = effect.threshold(threshold)
        return np.maximum(threshold, MIN_THRESHOLD_E)

    def emit_one(self, photo_expected: np.ndarray, row_level: np.ndarray | int) -> np.ndarray:
        """One readout: ``photo_expected`` (H, W) mean photo-electrons, ``row_level`` (H, 1) or
        scalar quantisation level per row. Returns (H, W) uint8 values in 0..level."""
        photo = photo_expected
        for effect in self._hooks["photo_electrons"]:
            photo = effect.photo_electrons(photo)
        charge = self.charge + np.asarray(photo, dtype=np.float64)
        for effect in self._hooks["dark_electrons"]:
            charge += effect.dark_electrons()
        np.maximum(charge, 0.0, out=charge)  # a pixel cannot hold negative charge
        threshold = self._threshold()
        values = np.minimum(np.floor(charge * row_level / threshold), row_level)
        fired = values > 0
        charge[fired] = 0.0
        self.charge = charge
        for effect in self._hooks["after_readout"]:
            effect.after_readout(fired)
        return values.astype(np.uint8)

    def emit(self, photo_expected: np.ndarray, level: int = 1) -> np.ndarray:
        """Several readouts of a static or precomputed input: ``photo_expected`` (T, H, W), every
        pixel at ``level``. Returns (T, H, W) uint8."""
        out = np.empty(photo_expected.shape, dtype=np.uint8)
        for t in range(len(photo_expected)):
            out[t] = self.emit_one(photo_expected[t], level)
        return out


class RateIntegrateFire:
    """The rate convention of other simulators (e.g. spikezoo's REDS streams): each plane adds the
    pixel's firing rate (< 1 per plane) to an accumulator that starts at a uniform random phase; a
    spike fires when it reaches 1, and 1 is subtracted. No noise: the long-run rate is exact."""

    def __init__(self, shape: tuple[int, int], seed: int) -> None:
        self.accumulator = np.random.default_rng([seed, 0x5A7E]).random(shape)

    def emit_one(self, rate: np.ndarray) -> np.ndarray:
        """One plane: ``rate`` (H, W) in spikes per plane -> (H, W) uint8 0/1."""
        self.accumulator += rate
        fired = self.accumulator >= 1.0
        self.accumulator -= fired
        return fired.astype(np.uint8)
