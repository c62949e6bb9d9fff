"""2x2x2 binning of real 1-bit spike planes into mixed-bit form (paper Sec. 4.3, "real-synthetic").

A bin covers 2 planes x 2 rows x 2 columns (time, height, width) of a raw 1-bit stream:

- ``multi`` is the number of spikes in the bin clamped to ``MULTI_LEVEL`` = 7 (a 3-bit value);
- ``single`` keeps one pixel of the bin: the **top-left pixel (in image orientation) of the first
  plane of the pair**, i.e. raw pixel ``(2t, 2i, 2j)`` for bin ``(t, i, j)``.

The result has half the width, half the height and half the readout rate of the raw stream.

Odd sizes: a trailing odd row (the bottom one in image orientation) and a trailing odd column (the
right one) are dropped. A trailing odd plane is dropped at the end of a capture; when streaming,
:class:`StreamBinner` carries it over to the next chunk, so results never depend on chunking.
Readout ``k`` of the binned stream is made of raw planes ``2k`` and ``2k + 1``, so binning starts
at an even raw plane.
"""

from __future__ import annotations

import numpy as np

from rmbvideo.chunks import RmbChunk, SpikeChunk

MULTI_LEVEL = 7
# Planes decoded per block by the fused path: keeps the intermediates in cache and memory bounded.
_FUSED_BLOCK_PLANES = 64

_PAIR_BITS = np.uint8(0x55)  # bit 0 of each 2-bit field
_NIBBLE_FIELDS = np.uint8(0x33)  # low 2 bits of each 4-bit field
_NIBBLE_BIT0 = np.uint8(0x11)
_SPREAD_NIBBLES = np.uint32(0x000F000F)
_SPREAD_EVEN_BITS_1 = np.uint32(0x00050005)
_SPREAD_EVEN_BITS_2 = np.uint32(0x01010101)


def bin_2x2x2(planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bin raw 0/1 planes (T, H, W) into ``(single, multi)``, both (T//2, H//2, W//2) uint8.

    The plain reference path, on unpacked planes in image orientation; see the module docstring
    for the kept pixel and the odd-size policy.
    """
    if planes.ndim != 3:
        raise ValueError(f"planes must be (T, H, W), got shape {planes.shape}")
    t2, h2, w2 = (n // 2 for n in planes.shape)
    p = planes[: 2 * t2, : 2 * h2, : 2 * w2].astype(np.uint8, copy=False)
    multi = p[0::2] + p[1::2]
    multi = multi[:, 0::2] + multi[:, 1::2]
    multi = multi[:, :, 0::2] + multi[:, :, 1::2]
    np.minimum(multi, MULTI_LEVEL, out=multi)
    single = np.ascontiguousarray(p[0::2, 0::2, 0::2])
    return single, multi


def bin_packed(packed: np.ndarray, image_width: int, flip: bool) -> tuple[np.ndarray, np.ndarray]:
    """Decode and bin packed ``.dat`` planes in one pass, without unpacking them to bits.

    ``packed`` is (T, H, row_bytes) uint8 as stored (LSB-first bits, rows upside down when
    ``flip``); the first ``image_width`` columns of each row are the image, the rest a header.
    Needs ``image_width % 8 == 0`` (byte-aligned rows). Bit-exact with ``bin_2x2x2`` of the
    decoded planes; the speed comes from SWAR arithmetic on whole bytes (4 bins per byte).
    """
    if packed.ndim != 3:
        raise ValueError(f"packed must be (T, H, row_bytes), got shape {packed.shape}")
    n_planes, height, row_bytes = packed.shape
    if image_width % 8 or image_width // 8 > row_bytes or image_width <= 0:
        raise ValueError(f"image_width {image_width} must be a multiple of 8 within {row_bytes} bytes")
    image_bytes = image_width // 8
    t2, h2 = n_planes // 2, height // 2
    # Stored rows used: image rows 0..2*h2-1. With a flip and odd H the dropped bottom image row
    # is stored row 0.
    first_row = 1 if (flip and height % 2) else 0
    single = np.empty((t2, h2, image_width // 2), np.uint8)
    multi = np.empty((t2, h2, image_width // 2), np.uint8)
    # Each image byte becomes 4 output bytes: write through uint32 views, flipped by row order.
    single32 = single.view(np.uint32)
    multi32 = multi.view(np.uint32)
    if flip:
        single32, multi32 = single32[:, ::-1], multi32[:, ::-1]
    # Within each stored row pair, the image's top row is the stored second row when flipped.
    keep_row = 1 if flip else 0
    block_pairs = _FUSED_BLOCK_PLANES // 2
    work = _FusedWorkspace(min(block_pairs, t2), h2, image_bytes)
    for p0 in range(0, t2, block_pairs):
        p1 = min(p0 + block_pairs, t2)
        x = packed[2 * p0 : 2 * p1, first_row : first_row + 2 * h2, :image_bytes]
        x = x.reshape(p1 - p0, 2, h2, 2, image_bytes)
        work.bin_multi(x, out=multi32[p0:p1])
        work.spread_even_bits(x[:, 0, :, keep_row], out=single32[p0:p1])
    return single, multi


class _FusedWorkspace:
    """Preallocated intermediates of ``bin_packed`` for blocks of up to ``pairs`` plane pairs.

    Every step writes with ``out=`` into these buffers: no allocation (and no page faults) per
    block, and the block stays in cache from one step to the next.
    """

    def __init__(self, pairs: int, h2: int, n_bytes: int) -> None:
        self.fields = np.empty((2, pairs, 2, h2, 2, n_bytes), np.uint8)  # even/odd column pairs
        self.shifted = np.empty((pairs, 2, h2, 2, n_bytes), np.uint8)
        self.plane_sum = np.empty((pairs, h2, 2, n_bytes), np.uint8)
        self.counts = np.empty((2, pairs, h2, n_bytes), np.uint8)
        self.carry = np.empty((pairs, h2, n_bytes), np.uint8)
        self.wide = np.empty((2, pairs, h2, n_bytes), np.uint32)
        self.wide_shifted = np.empty((pairs, h2, n_bytes), np.uint32)

    def bin_multi(self, x: np.ndarray, out: np.ndarray) -> None:
        """Clamped counts of a (P, 2 planes, H2, 2 rows, B bytes) block into ``out`` (P, H2, B) uint32."""
        p = len(x)
        even, odd = self.fields[0, :p], self.fields[1, :p]
        shifted = self.shifted[:p]
        # 2-bit fields: spikes in each column pair (0..2).
        np.bitwise_and(x, _PAIR_BITS, out=even)
        np.right_shift(x, 1, out=shifted)
        np.bitwise_and(shifted, _PAIR_BITS, out=shifted)
        np.add(even, shifted, out=even)
        # 4-bit fields: column pairs 0 and 2 of each byte in ``even``, pairs 1 and 3 in ``odd``.
        np.right_shift(even, 2, out=odd)
        np.bitwise_and(odd, _NIBBLE_FIELDS, out=odd)
        np.bitwise_and(even, _NIBBLE_FIELDS, out=even)
        plane_sum, carry = self.plane_sum[:p], self.carry[:p]
        for k, fields in enumerate((even, odd)):
            counts = self.counts[k, :p]
            np.add(fields[:, 0], fields[:, 1], out=plane_sum)  # the two planes
            np.add(plane_sum[:, :, 0], plane_sum[:, :, 1], out=counts)  # the two rows: 0..8
            np.right_shift(counts, 3, out=carry)
            np.bitwise_and(carry, _NIBBLE_BIT0, out=carry)
            np.subtract(counts, carry, out=counts)  # clamp 8 -> 7
            self._spread_nibbles(counts, out=self.wide[k, :p])
        # Byte b of a row holds bins 4b..4b+3: even fields give bins 4b, 4b+2; odd 4b+1, 4b+3.
        np.left_shift(self.wide[1, :p], 8, out=self.wide[1, :p])
        np.bitwise_or(self.wide[0, :p], self.wide[1, :p], out=out)

    def _spread_nibbles(self, v: np.ndarray, out: np.ndarray) -> None:
        """Each uint8 ``lo | hi << 4`` -> uint32 with ``lo`` in byte 0 and ``hi`` in byte 2."""
        shifted = self.wide_shifted[: len(v)]
        np.copyto(out, v)
        np.left_shift(out, 12, out=shifted)
        np.bitwise_or(out, shifted, out=out)
        np.bitwise_and(out, _SPREAD_NIBBLES, out=out)

    def spread_even_bits(self, v: np.ndarray, out: np.ndarray) -> None:
        """Bits 0, 2, 4, 6 of each uint8 -> bytes 0..3 of a uint32: the kept left pixel of each pair."""
        wide, shifted = self.wide[0, : len(v)], self.wide_shifted[: len(v)]
        np.bitwise_and(v, _PAIR_BITS, out=self.carry[: len(v)])
        np.copyto(wide, self.carry[: len(v)])
        np.left_shift(wide, 12, out=shifted)
        np.bitwise_or(wide, shifted, out=wide)
        np.bitwise_and(wide, _SPREAD_EVEN_BITS_1, out=wide)
        np.left_shift(wide, 6, out=shifted)
        np.bitwise_or(wide, shifted, out=wide)
        np.bitwise_and(wide, _SPREAD_EVEN_BITS_2, out=out)


def binned_rmb_chunk(single: np.ndarray, multi: np.ndarray, raw_start: int, raw_rate_hz: float) -> RmbChunk:
    """Wrap binned planes as a pure-M ``RmbChunk``: every row multi-bit, half the raw rate."""
    if raw_start % 2:
        raise ValueError(f"binned data must start at an even raw plane, got {raw_start}")
    return RmbChunk(
        single=single,
        multi=multi,
        multi_rows=np.ones(single.shape[:2], dtype=bool),
        start=raw_start // 2,
        rate_hz=raw_rate_hz / 2,
        level=MULTI_LEVEL,
        raw_per_readout=2,
    )


class StreamBinner:
    """Bins a stream of consecutive ``SpikeChunk``s, carrying an odd plane to the next chunk.

    Binning a capture in any chunking gives the same readouts as binning it whole. The first
    chunk must start at an even raw plane, and chunks must follow each other without gaps.
    """

    def __init__(self) -> None:
        self._carry: np.ndarray | None = None  # (1, H, W) plane waiting for its pair
        self._next_start: int | None = None

    @property
    def pending_planes(self) -> int:
        """Raw planes held back waiting for their pair (0 or 1); dropped if the capture ends."""
        return 0 if self._carry is None else 1

    def push(self, chunk: SpikeChunk) -> RmbChunk | None:
        """Bin ``chunk`` with any carried plane; ``None`` when no complete pair is available yet."""
        if self._next_start is None:
            if chunk.start % 2:
                raise ValueError(f"binning must start at an even raw plane, got {chunk.start}")
        elif chunk.start != self._next_start:
            raise ValueError(f"chunk starts at plane {chunk.start}, expected {self._next_start}")
        self._next_start = chunk.stop
        planes = chunk.planes
        raw_start = chunk.start
        if self._carry is not None:
            planes = np.concatenate([self._carry, planes])
            raw_start -= 1
            self._carry = None
        if len(planes) % 2:
            self._carry = planes[-1:].copy()
            planes = planes[:-1]
        if len(planes) == 0:
            return None
        single, multi = bin_2x2x2(planes)
        return binned_rmb_chunk(single, multi, raw_start, chunk.rate_hz)
