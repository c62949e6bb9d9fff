"""The units that flow between pipeline stages: every stage is a generator over these.

Conventions shared by all stages:

- Planes are ``uint8`` arrays shaped ``(T, H, W)`` in image orientation (row 0 at the top).
- ``start`` is the absolute index of the first plane/readout of the chunk in the capture, so a
  stage can compute exact times however the capture was chunked.
- Times are seconds from the start of the file: plane ``k`` spans ``[k, k+1) / rate_hz``.
- Linear intensities are in the sensor model's units: expected photo-charge per *raw* readout
  interval relative to the firing threshold (alpha*lambda/Q_th); for a 1-bit camera below
  saturation this is the firing probability per plane.
"""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np


@dataclass
class SpikeChunk:
    """Consecutive raw 1-bit planes from a capture: ``planes`` is (T, H, W) uint8 of 0/1."""

    planes: np.ndarray
    start: int
    rate_hz: float

    @property
    def stop(self) -> int:
        return self.start + len(self.planes)


@dataclass
class RmbChunk:
    """Consecutive readouts of a mixed-bit stream (binned real data or a native RMB sensor).

    ``single``: (T, H, W) uint8 1-bit values; ``multi``: (T, H, W) uint8 multi-bit values in
    0..``level``; ``multi_rows``: (T, H) bool, True where that row was read as multi-bit at that
    readout (values of ``multi`` elsewhere are 0 and carry no information). ``rate_hz`` is the
    readout rate of this stream (half the raw rate for binned data); ``raw_per_readout`` is how
    many raw planes one readout spans (2 for binned data, 1 for a native sensor), so linear
    values can be expressed per raw readout interval.
    """

    single: np.ndarray
    multi: np.ndarray
    multi_rows: np.ndarray
    start: int
    rate_hz: float
    level: int = 7
    raw_per_readout: int = 2

    @property
    def stop(self) -> int:
        return self.start + len(self.single)


@dataclass
class DenseChunk(RmbChunk):
    """An ``RmbChunk`` whose multi-bit plane is dense: every row has a value at every readout
    (measured or upsampled, float32 in levels 0..``level``), made by the band upsamplers of
    ``rmbvideo.recon.prelim``. ``multi_rows`` (also ``multi_valid``) is False where a row had no
    multi-bit sample anywhere in reach (its ``multi`` is 0 and carries no information, e.g. pure-S).
    ``measured`` (T, H) bool, where known: True where the value was read at that readout, not upsampled."""

    measured: np.ndarray | None = None

    @property
    def multi_valid(self) -> np.ndarray:
        """(T, H) bool: rows with multi-bit evidence."""
        return self.multi_rows


@dataclass
class Frame:
    """One reconstructed output frame: linear HDR ``image`` (H, W) float32, finite, >= 0."""

    index: int
    time_s: float
    image: np.ndarray


_INF_BITS = int(np.array(np.inf, np.float32).view(np.uint32))


def clean_image(image: np.ndarray) -> tuple[np.ndarray, int]:
    """``image`` as a ``Frame`` must be (float32, finite, >= 0): NaN/Inf become 0, negatives 0;
    also returns how many pixels were not finite. Returns the input itself when it is clean."""
    image = np.asarray(image, dtype=np.float32)
    # Fast path, one reduction and no temporaries: as unsigned integers, the float32 values that are finite and
    # >= 0 (but -0.0) are exactly those below +Inf's bits; negatives have the sign bit set, NaNs lie above +Inf.
    if image.size == 0 or int(image.view(np.uint32).max()) < _INF_BITS:
        return image, 0
    # Then two: max and min propagate NaN, so a finite max and a min >= 0 mean every value is finite and >= 0.
    if math.isfinite(float(image.max())) and float(image.min()) >= 0:
        return image, 0
    bad = ~np.isfinite(image)
    count = int(bad.sum())
    return np.where(bad, np.float32(0.0), np.maximum(image, np.float32(0.0))).astype(np.float32), count
