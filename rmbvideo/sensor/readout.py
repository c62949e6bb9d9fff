"""Mixed-bit readout designs (paper Sec. 4.1, Fig. 4a, supplement Sec. 11).

A readout design decides which rows of each readout are transmitted as multi-bit values:

- ``pure-s``: none (plain 1-bit spiking camera);
- ``pure-m``: all rows at every readout (``bits`` times the data volume);
- ``full-m``: whole multi-bit planes every ``full_m_period`` readouts (Fig. 4a-I);
- ``rmb``: a band of ``band`` rows starting at row ``(t * shift) % H`` at readout ``t``, wrapping
  around the bottom edge (Fig. 4a-II, the paper's rolling-mixed-bit design).

``RmbReadout.apply`` turns a fully multi-bit stream (binned real data, or a pure-M simulation) into
what that design would transmit. Rows are indexed by the absolute readout index, so the result does
not depend on how the stream is chunked.

The 1-bit plane is kept unchanged in every row, including band rows: binned data has a genuine 1-bit
value there (one raw pixel of the bin), and keeping it gives every pixel a 1-bit sample at every
readout. The data-volume accounting (``data_volume``) nevertheless counts a band pixel as ``bits``
bits *instead of* 1 bit, as the paper does, since a native RMB sensor would send the 3-bit value only.

The default ``full_m_period`` is ``round(H / band)``: one full multi-bit plane every H/b readouts
adds the same ``(bits - 1)`` extra bits per pixel on average as a band of ``b`` rows at every
readout, so full-M and RMB cost the same data volume (exactly so when ``b`` divides ``H``).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from rmbvideo.chunks import RmbChunk


class ReadoutMode(str, Enum):
    """Which rows of each readout are transmitted as multi-bit values."""

    PURE_S = "pure-s"
    PURE_M = "pure-m"
    FULL_M = "full-m"
    RMB = "rmb"


def default_full_m_period(height: int, band: int) -> int:
    """Readouts between full multi-bit planes so that full-M has RMB's data volume: round(H / band)."""
    return max(1, round(height / max(1, min(band, height))))


@dataclass(frozen=True)
class RmbReadout:
    """A readout design: ``mode`` plus the band geometry (rows read per readout, rows moved per readout)."""

    mode: ReadoutMode = ReadoutMode.RMB
    band: int = 4
    shift: int = 2
    full_m_period: int | None = None

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "mode", ReadoutMode(self.mode))
        except ValueError:
            names = ", ".join(m.value for m in ReadoutMode)
            raise ValueError(f"unknown readout mode {self.mode!r} (expected one of {names})") from None
        if self.band < 1 or self.shift < 1:
            raise ValueError(f"band and shift must be >= 1, got band={self.band}, shift={self.shift}")
        if self.full_m_period is not None and self.full_m_period < 1:
            raise ValueError(f"full_m_period must be >= 1, got {self.full_m_period}")

    def band_rows(self, t: int, height: int) -> np.ndarray:
        """Rows (ascending in band order, wrapping) read as multi-bit at readout ``t`` in RMB mode."""
        return (t * self.shift + np.arange(min(self.band, height))) % height

    def period(self, height: int) -> int:
        """Readouts between full multi-bit planes in full-M mode (explicit or the volume-matched default)."""
        return self.full_m_period or default_full_m_period(height, self.band)

    def multi_rows(self, start: int, count: int, height: int) -> np.ndarray:
        """(count, height) bool: rows read as multi-bit at absolute readouts ``start .. start+count-1``."""
        t = np.arange(start, start + count, dtype=np.int64)[:, None]
        if self.mode is ReadoutMode.PURE_S:
            return np.zeros((count, height), dtype=bool)
        if self.mode is ReadoutMode.PURE_M:
            return np.ones((count, height), dtype=bool)
        if self.mode is ReadoutMode.FULL_M:
            return np.broadcast_to(t % self.period(height) == 0, (count, height)).copy()
        rows = np.arange(height, dtype=np.int64)[None, :]
        return (rows - t * self.shift) % height < min(self.band, height)

    def apply(self, chunk: RmbChunk) -> RmbChunk:
        """Keep multi-bit values only where this design reads them; the 1-bit plane is unchanged.

        Rows that the input itself did not read as multi-bit stay unread (the masks intersect), so
        the input should be fully multi-bit (pure-M), as binned real data is.
        """
        n, height = chunk.multi_rows.shape
        rows = self.multi_rows(chunk.start, n, height) & chunk.multi_rows
        multi = np.where(rows[:, :, None], chunk.multi, np.uint8(0)).astype(chunk.multi.dtype, copy=False)
        return RmbChunk(
            single=chunk.single,
            multi=multi,
            multi_rows=rows,
            start=chunk.start,
            rate_hz=chunk.rate_hz,
            level=chunk.level,
            raw_per_readout=chunk.raw_per_readout,
        )


def data_volume(
    height: int,
    band: int = 4,
    bits: int = 3,
    mode: ReadoutMode | str = ReadoutMode.RMB,
    full_m_period: int | None = None,
) -> float:
    """Data volume of a readout design relative to pure 1-bit readout of the same frames.

    RMB: ``((H - b) + bits * b) / H`` (1.016 for H = 500, b = 4: the paper's +1.6 %); pure-S: 1;
    pure-M: ``bits``; full-M: ``1 + (bits - 1) / period`` (equal to RMB's with the default period).
    """
    if height < 1 or band < 1 or bits < 1:
        raise ValueError(f"height, band and bits must be >= 1, got {height}, {band}, {bits}")
    mode = ReadoutMode(mode)
    b = min(band, height)
    if mode is ReadoutMode.PURE_S:
        return 1.0
    if mode is ReadoutMode.PURE_M:
        return float(bits)
    if mode is ReadoutMode.FULL_M:
        period = full_m_period or default_full_m_period(height, band)
        return 1.0 + (bits - 1) / period
    return ((height - b) + bits * b) / height
