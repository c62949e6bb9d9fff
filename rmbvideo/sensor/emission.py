"""Spike emission of an integrate-and-fire pixel array (paper Eqns. 1-3, supplement Sec. 7).

Per pixel and readout interval the charge is ``Q_c = Q_a + Q_p + Q_d`` (carried, photo and dark
electrons). A pixel read with level ``L`` (1 for single-bit) gives ``S = L`` when
``Q_c >= Q_th`` and ``floor(Q_c * L / Q_th)`` otherwise, and is reset to zero when ``S > 0``
(the paper's rule; ``SensorParams.reset = "subtract"``: the counted charge ``S * Q_th / L`` is taken off and the
rest kept, at most ``Q_th``, as a pixel reset at its crossing keeps it); otherwise its charge is carried to the
next interval. The threshold is
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

Single-bit readouts whose only noise is shot noise plus fixed or per-reset threshold deviations are
simulated by photon arrival (``ArrivalSpikeEmitter``: one Gamma draw per spike, the same statistics,
several times faster than a Poisson draw per pixel per readout); the others per readout.
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

    def settle(self, seed: int) -> None:
        """Start mid-cycle, as a running camera's pixels are when a capture begins: each pixel's carried
        charge uniform in [0, its nominal threshold), the steady state of a reset-to-zero pixel under
        constant light. A fresh array holds no charge, so its first spikes in a dark scene come
        hundreds of planes late (at 0.01 of the threshold per plane, ~100 planes)."""
        threshold = np.broadcast_to(self.capacitance * self.params.voltage, self.shape)
        self.charge = np.random.default_rng([seed, 0x5E77]).random(self.shape) * threshold

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
        if self.params.reset == "subtract":  # the charge the reading counted is taken off, at most a threshold kept
            kept = np.minimum(charge - values * threshold / row_level, threshold)
            charge = np.where(fired, np.maximum(kept, 0.0), charge)
        else:
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


#: Effects ``ArrivalSpikeEmitter`` reproduces exactly (shot noise is required): the others change the
#: charge or the threshold at every readout, so they need ``SpikeEmitter``'s per-readout charge.
ARRIVAL_EFFECTS = frozenset({"shot_noise", "threshold_mismatch", "readout_rounding", "reset_noise",
                             "rolling_readout"})


def arrivals_apply(effects: Sequence[str], level: int) -> bool:
    """Whether ``ArrivalSpikeEmitter`` can stand in for ``SpikeEmitter`` (1-bit, shot noise, and only
    effects it reproduces)."""
    return level == 1 and "shot_noise" in effects and set(effects) <= ARRIVAL_EFFECTS


class ArrivalSpikeEmitter:
    """1-bit pixels with Poisson shot noise, simulated by photon arrival instead of per-readout counts.

    Photons arrive as a Poisson process, so a pixel whose threshold needs m electrons (ceil of the
    threshold) fires at the first readout where its expected charge since the last reset reaches the
    m-th arrival, a Gamma(m, 1) draw; the reset then discards the charge, as in ``SpikeEmitter`` (or, resetting by
    subtraction, keeps what arrived after the crossing photon, short of the next spike). One
    Gamma draw per spike instead of one Poisson draw per pixel per readout: the same statistics for the
    effects in ``ARRIVAL_EFFECTS`` (threshold offsets and rounding set m; reset noise redraws it at each
    reset), a different random stream.
    """

    def __init__(self, height: int, width: int, params: SensorParams, effects: Sequence[str], seed: int,
                 dark_correlation_px: float = 1.5) -> None:
        if not arrivals_apply(effects, 1):
            raise ValueError(f"photon arrivals need shot noise and only {sorted(ARRIVAL_EFFECTS)}, got {list(effects)}")
        self._pixels = SpikeEmitter(height, width, params, effects, seed, dark_correlation_px)
        self._rng = np.random.default_rng([seed, 0xA771])
        # Electrons to fire: fixed unless reset noise redraws the threshold at every reset.
        self._electrons = None if "reset_noise" in effects else self._threshold_electrons()
        self._expected = np.zeros((height, width), dtype=np.float64)
        self._target = self._arrival(np.arange(height * width)).reshape(height, width)

    def settle(self, seed: int) -> None:
        """Start mid-cycle (``SpikeEmitter.settle``): each pixel a uniform fraction of the way to its
        next spike."""
        self._expected = np.random.default_rng([seed, 0x5E77]).random(self._expected.shape) * self._target

    def _threshold_electrons(self) -> np.ndarray:
        """Photons needed to fire, per pixel: the threshold's charge rounded up (charge is whole electrons)."""
        return np.ceil(np.broadcast_to(self._pixels._threshold(), self._pixels.shape) - 1e-9)

    def _arrival(self, which: np.ndarray) -> np.ndarray:
        """Expected charge at which the threshold's m-th photon arrives, for the pixels at the flat indices
        ``which`` (ascending: the order of a boolean mask, so the random stream is the mask's)."""
        electrons = self._electrons if self._electrons is not None else self._threshold_electrons()
        return self._rng.gamma(electrons.reshape(-1)[which])

    def emit_one(self, photo_expected: np.ndarray, row_level: np.ndarray | int = 1) -> np.ndarray:
        """One readout of ``photo_expected`` (H, W) mean photo-electrons -> (H, W) uint8 0/1.

        The fired pixels are gathered and scattered by their flat indices, found once (boolean-mask indexing
        searches the mask again at every use: 2-3x slower for the same values)."""
        self._expected += photo_expected
        fired = self._expected >= self._target
        index = np.flatnonzero(fired)
        if index.size:
            expected, target = self._expected.reshape(-1), self._target.reshape(-1)
            past = expected[index] - target[index]  # charge since the crossing photon
            for effect in self._pixels._hooks["after_readout"]:
                effect.after_readout(fired)
            arrival = self._arrival(index)
            target[index] = arrival
            # reset to zero discards it; reset at the crossing keeps it, short of the next spike (one a plane)
            expected[index] = np.minimum(past, arrival) if self._pixels.params.reset == "subtract" else 0.0
        return fired.view(np.uint8)


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
