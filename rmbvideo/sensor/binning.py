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
from rmbvideo.image_pool import ImagePool
from rmbvideo.sensor.compiled import KERNELS

MULTI_LEVEL = 7
#: raw pixel-planes behind one binned count (2 x 2 pixels x 2 planes): its Bernoulli trials
BIN_TRIALS = 8
# Planes decoded per block by the fused path: keeps the intermediates in cache and memory bounded.
_FUSED_BLOCK_PLANES = 64

_PAIR_BITS = 0x55  # bit 0 of each 2-bit field
_NIBBLE_FIELDS = 0x33  # low 2 bits of each 4-bit field
_NIBBLE_BIT0 = 0x11
_BYTES_PER_WORD = 8
_SPREAD_NIBBLES = np.uint32(1 + (1 << 12))
_SPREAD_EVEN_BITS = np.uint32(1 + (1 << 6) + (1 << 12) + (1 << 18))
_MULTI_BITS = np.uint32(0x07070707)
_SINGLE_BITS = np.uint32(0x01010101)


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


def bin_packed(packed: np.ndarray, image_width: int, flip: bool,
               out: np.ndarray | None = None, compiled: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Decode and bin packed ``.dat`` planes in one pass, without unpacking them to bits.

    ``packed`` is (T, H, row_bytes) uint8 as stored (LSB-first bits, rows upside down when
    ``flip``); the first ``image_width`` columns of each row are the image, the rest a header.
    Needs ``image_width % 8 == 0`` (byte-aligned rows). Bit-exact with ``bin_2x2x2`` of the
    decoded planes; the speed comes from SWAR arithmetic on whole bytes (4 bins per byte), in
    the compiled kernel (``compiled.COMPILED``) unless ``compiled=False`` or none was built, else in numpy.
    ``out``, when given, is a (2, T//2, H//2, image_width//2) uint8 array
    that receives ``single`` and ``multi`` (the returned views of it), e.g. a reused one.
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
    if out is None:
        out = np.empty((2, t2, h2, image_width // 2), np.uint8)
    elif out.shape != (2, t2, h2, image_width // 2) or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a contiguous (2, {t2}, {h2}, {image_width // 2}) uint8 array")
    single, multi = out
    if single.size == 0:
        return single, multi
    if KERNELS is not None and compiled:
        KERNELS.bin_packed(np.ascontiguousarray(packed[: 2 * t2]), single, multi, 2 * t2, height, row_bytes,
                           image_bytes, first_row, flip)
        return single, multi
    # Each image byte becomes 4 output bytes: written through uint32 views.
    single32 = single.view(np.uint32)
    multi32 = multi.view(np.uint32)
    # Within each stored row pair, the image's top row is the stored second row when flipped.
    keep_row = 1 if flip else 0
    block_pairs = _FUSED_BLOCK_PLANES // 2
    work = _FusedWorkspace(min(block_pairs, t2), h2, image_bytes)
    for p0 in range(0, t2, block_pairs):
        p1 = min(p0 + block_pairs, t2)
        x = packed[2 * p0 : 2 * p1, first_row : first_row + 2 * h2, :image_bytes]
        x = x.reshape(p1 - p0, 2, h2, 2, image_bytes)
        work.bin(x, keep_row, flip, multi_out=multi32[p0:p1], single_out=single32[p0:p1])
    return single, multi


def _words(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """The byte arrays as flat uint64 words when all are contiguous whole words, else as they are.

    numpy's uint8 shifts are not vectorised; a word's shift moves bits across its bytes, which every
    caller masks off, and its adds and subtracts never carry across bytes here (no field overflows).
    """
    if all(a.flags.c_contiguous and a.nbytes % _BYTES_PER_WORD == 0 for a in arrays):
        return tuple(a.reshape(-1).view(np.uint64) for a in arrays)
    return arrays


def _repeat_byte(byte: int, like: np.ndarray) -> np.unsignedinteger:
    """``byte`` in every byte of ``like``'s element type."""
    return like.dtype.type(byte * (0x0101010101010101 & ((1 << (8 * like.itemsize)) - 1)))


class _FusedWorkspace:
    """Preallocated intermediates of ``bin_packed`` for blocks of up to ``pairs`` plane pairs.

    Every step writes with ``out=`` into these buffers: no allocation (and no page faults) per
    block, and the block stays in cache from one step to the next.
    """

    def __init__(self, pairs: int, h2: int, n_bytes: int) -> None:
        self.pair_counts = np.empty((pairs, 2, h2, 2, n_bytes), np.uint8)
        self.shifted = np.empty((pairs, 2, h2, 2, n_bytes), np.uint8)
        self.fields = np.empty((2, pairs, 2, h2, 2, n_bytes), np.uint8)  # even/odd column pairs
        self.plane_sum = np.empty((2, pairs, h2, 2, n_bytes), np.uint8)
        self.counts = np.empty((2, pairs, h2, n_bytes), np.uint8)
        self.carry = np.empty((2, pairs, h2, n_bytes), np.uint8)
        self.kept = np.empty((pairs, h2, n_bytes), np.uint8)
        self.packed16 = np.empty((pairs, h2, n_bytes), np.uint16)
        self.wide = np.empty((pairs, h2, n_bytes), np.uint32)

    def bin(self, x: np.ndarray, keep_row: int, flip: bool, multi_out: np.ndarray, single_out: np.ndarray) -> None:
        """Bin a (P, 2 planes, H2, 2 rows, B bytes) block into (P, H2, B) uint32 outputs, 4 bins each.

        ``flip`` reverses the row order, once per output, when spreading to bytes.
        """
        import cv2  # here, not at the top: `rmbvideo info` reads captures without paying for OpenCV

        p = len(x)
        counts2, shifted = self.pair_counts[:p], self.shifted[:p]
        # 2-bit fields: spikes in each column pair (0..2), as x - ((x >> 1) & 0b01010101).
        xw, shifted_w, counts2_w = _words(x, shifted, counts2)
        np.right_shift(xw, 1, out=shifted_w)
        np.bitwise_and(shifted_w, _repeat_byte(_PAIR_BITS, xw), out=shifted_w)
        np.subtract(xw, shifted_w, out=counts2_w)
        # 4-bit fields: column pairs 0 and 2 of each byte in ``even``, pairs 1 and 3 in ``odd``.
        fields = self.fields[:, :p]
        counts2_w, odd_w, even_w = _words(counts2, fields[1], fields[0])
        nibble_fields = _repeat_byte(_NIBBLE_FIELDS, counts2_w)
        np.right_shift(counts2_w, 2, out=odd_w)
        np.bitwise_and(odd_w, nibble_fields, out=odd_w)
        np.bitwise_and(counts2_w, nibble_fields, out=even_w)
        plane_sum, counts, carry = self.plane_sum[:, :p], self.counts[:, :p], self.carry[:, :p]
        np.add(fields[:, :, 0], fields[:, :, 1], out=plane_sum)  # the two planes
        # The two rows (0..8), as one OpenCV add of 2-D views: numpy's loop over 50-byte rows is 4x slower.
        width = plane_sum.shape[-1]
        for e in range(2):  # each a contiguous prefix of the workspace, so the reshapes are views
            rows = plane_sum[e].reshape(-1, 2, width)
            cv2.add(rows[:, 0], rows[:, 1], dst=counts[e].reshape(-1, width))
        counts_w, carry_w = _words(counts, carry)
        np.right_shift(counts_w, 3, out=carry_w)
        np.bitwise_and(carry_w, _repeat_byte(_NIBBLE_BIT0, counts_w), out=carry_w)
        np.subtract(counts_w, carry_w, out=counts_w)  # clamp 8 -> 7
        # Nibbles even-lo, even-hi, odd-lo, odd-hi (bins 0, 2, 1, 3) of a uint16 (even and odd bytes
        # interleaved by one OpenCV merge) -> bytes 0..3 of a uint32: w + (w << 12) moves the odd
        # nibbles two bytes up (no carries: nibbles are <= 7).
        packed16 = self.packed16[:p]
        cv2.merge([counts[0].reshape(-1, width), counts[1].reshape(-1, width)],
                  dst=packed16.view(np.uint8).reshape(-1, width, 2))
        wide = self.wide[:p]
        np.copyto(wide, packed16[:, ::-1] if flip else packed16)
        np.multiply(wide, _SPREAD_NIBBLES, out=wide)
        np.bitwise_and(wide, _MULTI_BITS, out=multi_out)
        # The kept pixels (bits 0, 2, 4, 6) -> bytes 0..3: shifts by 0, 6, 12 and 18 in one multiply
        # (the only carry, bits 6 + 6, lands in bit 7, which is masked off).
        kept = self.kept[:p]
        np.bitwise_and(x[:, 0, :, keep_row], np.uint8(_PAIR_BITS), out=kept)
        np.copyto(wide, kept[:, ::-1] if flip else kept)
        np.multiply(wide, _SPREAD_EVEN_BITS, out=wide)
        np.bitwise_and(wide, _SINGLE_BITS, out=single_out)


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
    ``push_stored`` takes planes as a ``.dat`` stores them (byte-aligned rows) and bins them from the
    stored bytes (``bin_packed``: bit for bit the same, several times faster than decoding, then
    binning), into arrays reused once the chunks made of them are released. One stream is one kind of chunk.
    """

    def __init__(self) -> None:
        self._outputs = ImagePool()
        self._carry: np.ndarray | None = None  # (1, ...) plane waiting for its pair, as its chunk held it
        self._next_start: int | None = None
        self._stored: bool | None = None  # whether the stream comes as stored bytes

    @property
    def pending_planes(self) -> int:
        """Raw planes held back waiting for their pair (0 or 1); dropped if the capture ends."""
        return 0 if self._carry is None else 1

    def push(self, chunk: SpikeChunk) -> RmbChunk | None:
        """Bin ``chunk`` with any carried plane; ``None`` when no complete pair is available yet."""
        paired = self._pair(chunk.planes, chunk.start, stored=False)
        return None if paired is None else binned_rmb_chunk(*bin_2x2x2(paired[0]), paired[1], chunk.rate_hz)

    def push_stored(self, data: np.ndarray, start: int, rate_hz: float, height: int, image_width: int,
                    flip: bool) -> RmbChunk | None:
        """``push`` for planes as stored: ``data`` (T, plane_bytes) uint8 of ``height`` rows whose first
        ``image_width`` columns (a multiple of 8) are the image, rows upside down when ``flip``."""
        paired = self._pair(data, start, stored=True)
        if paired is None:
            return None
        planes, raw_start = paired
        out = self._outputs.take((2, len(planes) // 2, height // 2, image_width // 2), np.uint8)
        single, multi = bin_packed(planes.reshape(len(planes), height, -1), image_width, flip, out=out)
        return binned_rmb_chunk(single, multi, raw_start, rate_hz)

    def _pair(self, planes: np.ndarray, start: int, stored: bool) -> tuple[np.ndarray, int] | None:
        """The whole pairs of planes from the carried one and ``planes`` (from raw plane ``start``), and the raw
        plane they start at; an odd last plane is carried."""
        if self._next_start is None:
            if start % 2:
                raise ValueError(f"binning must start at an even raw plane, got {start}")
        elif start != self._next_start:
            raise ValueError(f"chunk starts at plane {start}, expected {self._next_start}")
        if self._stored is not None and stored != self._stored:
            raise ValueError("a binned stream is one kind of chunk: stored bytes or decoded planes")
        self._stored = stored
        self._next_start = start + len(planes)
        if self._carry is not None:
            planes = np.concatenate([self._carry, planes])
            start -= 1
            self._carry = None
        if len(planes) % 2:
            self._carry = planes[-1:].copy()
            planes = planes[:-1]
        return (planes, start) if len(planes) else None
