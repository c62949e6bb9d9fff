"""The mean response of a camera's binned stream to a steady light: the rate per raw pixel-plane that a pixel of
charge ``q`` per raw plane (in units of its firing threshold) fires at, measured on the emission model.

A reset-to-zero pixel wastes the charge above its threshold at each spike, so its rate is not ``q``: about
``q / (1 + q/2)`` up to ``q = 0.5``, then plateaus where it fires every second plane over a range of charges
(smoothed by noise), until the binned count saturates at 7 of 8. The network's box-filter candidates invert it
(``rmbvideo.net.blend``); this measures it, so that inverse can be checked and tabulated.
"""

from __future__ import annotations

import numpy as np

from rmbvideo.chunks import SpikeChunk
from rmbvideo.sensor.binning import StreamBinner
from rmbvideo.sensor.effects import REALISTIC_EFFECTS
from rmbvideo.sensor.emission import SpikeEmitter
from rmbvideo.sensor.params import SensorParams

#: raw pixel-planes behind one binned count (2 x 2 pixels x 2 planes)
BIN_TRIALS = 8


def mean_binned_rate(level: float, size: int = 64, readouts: int = 200, seed: int = 0,
                     params: SensorParams | None = None) -> float:
    """Mean binned rate per raw pixel-plane (count / 8) of a flat field at ``level`` (charge per raw plane / firing
    threshold) through the emission model with a real camera's noise (``REALISTIC_EFFECTS``), from a settled
    sensor: ``size`` x ``size`` binned pixels over ``readouts`` binned readouts."""
    params = params or SensorParams()
    emitter = SpikeEmitter(2 * size, 2 * size, params, REALISTIC_EFFECTS, seed)
    emitter.settle(seed)
    photo = np.full((2 * size, 2 * size), level * params.q_r)
    binner, total, count = StreamBinner(), 0.0, 0
    for start in range(0, 2 * readouts, 64):
        planes = np.stack([emitter.emit_one(photo, 1) for _ in range(min(64, 2 * readouts - start))])
        binned = binner.push(SpikeChunk(planes=planes, start=start, rate_hz=20_000.0))
        if binned is not None:
            total += float(binned.multi.astype(np.float64).sum())
            count += binned.multi.size
    return total / max(count, 1) / BIN_TRIALS


def response_table(levels: np.ndarray, **kwargs) -> np.ndarray:
    """``mean_binned_rate`` at each of ``levels``."""
    return np.array([mean_binned_rate(float(level), **kwargs) for level in levels])
