"""The mean response of a camera's binned stream to a steady light: the rate per raw pixel-plane that a pixel of
charge ``q`` per raw plane (in units of its firing threshold) fires at, measured on the emission model.

A reset-to-zero pixel wastes the charge above its threshold at each spike, so its rate is not ``q``: about
``q / (1 + q/2)`` up to ``q = 0.5``, then plateaus where it fires every second plane over a range of charges
(smoothed by noise), until the binned count saturates at 7 of 8. The network's box-filter candidates invert it
(``rmbvideo.net.blend.RESET_TO_ZERO_RATES``: the table ``tabulated_response`` makes, kept in the network's package,
which imports only torch).
"""

from __future__ import annotations

import numpy as np

from rmbvideo.chunks import RmbChunk, SpikeChunk
from rmbvideo.sensor.binning import BIN_TRIALS, StreamBinner
from rmbvideo.sensor.effects import REALISTIC_EFFECTS
from rmbvideo.sensor.emission import SpikeEmitter
from rmbvideo.sensor.params import SensorParams



#: raw planes a second of the emission model's streams (a 20 kHz camera)
RAW_RATE_HZ = 20_000.0


def flat_field_chunks(level: float, width: int, height: int, readouts: int, seed: int = 0,
                      params: SensorParams | None = None) -> list[RmbChunk]:
    """Binned chunks of a static flat field at ``level`` (charge per raw plane / firing threshold) through the
    physical emission model with a real camera's noise (``REALISTIC_EFFECTS``; raw size 2x, raw planes
    2 x ``readouts``), starting mid-stream (``settle``)."""
    params = params or SensorParams()
    emitter = SpikeEmitter(2 * height, 2 * width, params, REALISTIC_EFFECTS, seed)
    emitter.settle(seed)
    photo = np.full((2 * height, 2 * width), level * params.q_r)
    binner, chunks = StreamBinner(), []
    for start in range(0, 2 * readouts, 64):
        count = min(64, 2 * readouts - start)
        planes = np.stack([emitter.emit_one(photo, 1) for _ in range(count)])
        binned = binner.push(SpikeChunk(planes=planes, start=start, rate_hz=RAW_RATE_HZ))
        if binned is not None:
            chunks.append(binned)
    return chunks


def mean_binned_rate(level: float, size: int = 64, readouts: int = 200, seed: int = 0,
                     params: SensorParams | None = None) -> float:
    """Mean binned rate per raw pixel-plane (count / 8) of ``flat_field_chunks`` at ``level``: ``size`` x ``size``
    binned pixels over ``readouts`` binned readouts."""
    chunks = flat_field_chunks(level, size, size, readouts, seed, params)
    total = sum(float(c.multi.astype(np.float64).sum()) for c in chunks)
    return total / max(sum(c.multi.size for c in chunks), 1) / BIN_TRIALS


def response_table(levels: np.ndarray, **kwargs) -> np.ndarray:
    """``mean_binned_rate`` at each of ``levels``."""
    return np.array([mean_binned_rate(float(level), **kwargs) for level in levels])


def tabulated_response(step: float = 0.025, top: float = 1.3, size: int = 96, readouts: int = 400) -> np.ndarray:
    """The rates of ``rmbvideo.net.blend.RESET_TO_ZERO_RATES``: ``mean_binned_rate`` at levels ``step``, ``2 step``,
    ..., ``top`` (about 2 minutes with the defaults), after 0 at level 0 (a dark pixel)."""
    levels = step * np.arange(1, int(round(top / step)) + 1)
    return np.concatenate([[0.0], response_table(levels, size=size, readouts=readouts)])
