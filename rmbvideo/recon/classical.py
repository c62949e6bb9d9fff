"""Classical streaming reconstructions: TFP and TFI on raw 1-bit planes, TFW on the binned RMB stream.

All reconstructors share one shape (:class:`Reconstructor`): ``push(chunk) -> frames`` and
``flush() -> frames``, so the pipeline and the RMB-Net engine look the same.

Frame schedule: frame ``i`` is centred at ``c_i = i*step + step/2`` in units of the input stream
(raw planes for TFP/TFI, readouts for TFW), counted from plane/readout 0 of the file even when the
run starts later; its time stamp is ``c_i / rate_hz``. A frame is produced for every centre that lies
inside the data pushed. A window of ``w`` planes around ``c_i`` starts at ``round(c_i - w/2)``
(half up), so an odd window around a centre on a plane boundary is half a plane late. Windows that
reach before the first or after the last pushed plane are clipped to the data that exists (the
estimate then uses fewer planes; it is never padded or extrapolated).

Units: expected charge per raw readout interval relative to the threshold, i.e. spikes per raw
plane for a 1-bit camera below saturation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, ClassVar, Literal, Protocol, Sequence

import numpy as np

from rmbvideo.chunks import DenseChunk, Frame, RmbChunk, SpikeChunk
from rmbvideo.io.dat import DatGeometry, PackedChunk
from rmbvideo.image_pool import ImagePool
from rmbvideo.recon.prelim import MultiUpsampler, TemporalInterpolation
from rmbvideo.sensor.compiled import KERNELS

InputKind = Literal["spikes", "rmb"]
# Planes handled at once by TFI's (block, H, W) index arrays: bounds memory for any chunk size.
_TFI_BLOCK_PLANES = 64
_NONE_IN_BLOCK = np.uint8(255)  # > any offset in a block of _TFI_BLOCK_PLANES
_EXACT_FLOAT32_INTEGERS = 2**24


class Reconstructor(Protocol):
    """A streaming reconstructor: chunks in, frames out, in time order, independent of chunking.

    ``input_kind`` says which stream it consumes: ``"spikes"`` (raw :class:`SpikeChunk`) or
    ``"rmb"`` (binned/mixed-bit :class:`RmbChunk`). A spikes method may also set ``accepts_packed``
    to take the stored bits undecoded (:class:`rmbvideo.io.dat.PackedChunk`) where a reader has them.
    """

    input_kind: ClassVar[InputKind]

    def push(self, chunk: SpikeChunk | RmbChunk) -> list[Frame]:
        """Consume the next chunk; return the frames it completes."""
        ...

    def flush(self) -> list[Frame]:
        """End of stream: return the remaining frames (windows clipped at the end of the data)."""
        ...


def _centre2(i: int, step: int) -> int:
    """Twice the centre of frame ``i`` (an integer) in planes."""
    return (2 * i + 1) * step


def _first_frame(start: int, step: int) -> int:
    """Index of the first frame whose centre is at or after plane ``start``."""
    return max(0, -((step - 2 * start) // (2 * step)))


@dataclass
class _WindowTotal:
    """Sums over one frame's window: ``count`` planes, one (H, W)/(H,) sum per channel."""

    index: int
    centre: float
    count: int
    sums: list[np.ndarray]


class _Totals(Protocol):
    """Running totals of every plane added so far; window sums are differences of two moments."""

    def add(self, channels: Sequence[np.ndarray], a: int, b: int) -> None:
        """Add planes ``a..b`` of this push's channels."""
        ...

    def snapshot(self) -> object:
        """The totals now, to subtract later."""
        ...

    def since(self, snapshot: object) -> list[np.ndarray]:
        """Per channel, the sum of the planes added after ``snapshot`` was taken."""
        ...


#: Byte planes (1-bit spikes, bin counts) and how many of them a uint16 sum holds without overflow (257 * 255 = 65535).
_NARROW = (np.dtype(np.bool_), np.dtype(np.uint8))
_NARROW_RUN = 257


class _DenseTotals:
    """Totals of unpacked channels: integer channels in int64, others in float64 (exact for the
    dyadic values produced upstream), so results do not depend on chunking."""

    def __init__(self, channels: Sequence[np.ndarray]) -> None:
        self._total = [np.zeros(c.shape[1:], dtype=np.int64 if c.dtype.kind in "biu" else np.float64) for c in channels]

    def add(self, channels: Sequence[np.ndarray], a: int, b: int) -> None:
        for total, channel in zip(self._total, channels):
            if channel.dtype in _NARROW:  # bytes: summed in uint16 runs that cannot overflow, 4-5x faster, exact
                for start in range(a, b, _NARROW_RUN):
                    total += channel[start : min(b, start + _NARROW_RUN)].sum(axis=0, dtype=np.uint16)
            else:
                total += channel[a:b].sum(axis=0, dtype=total.dtype)

    def snapshot(self) -> list[np.ndarray]:
        return [t.copy() for t in self._total]

    def since(self, snapshot: list[np.ndarray]) -> list[np.ndarray]:
        return [total - snap for total, snap in zip(self._total, snapshot)]


def _word_dtype(plane_bytes: int) -> np.dtype:
    """The widest unsigned word that tiles a stored plane exactly (fewer, wider bitwise operations)."""
    return next(np.dtype(t) for t in (np.uint64, np.uint32, np.uint16, np.uint8)
                if plane_bytes % np.dtype(t).itemsize == 0)


def _bit_sliced_sum(planes: np.ndarray) -> list[np.ndarray]:
    """Bit-sliced count (LSB first, ``m.bit_length()`` words arrays) of the packed planes ``(m, words)``.

    A carry-save (Wallace) tree: full adders turn three rows of one weight into a sum row of that
    weight and a carry row of the next, vectorised over every group of three, until each weight has
    one row (about five bitwise operations per plane, a third fewer than a tree of ripple adders).
    """
    columns: list[list[np.ndarray]] = [[planes]]  # rows of weight 2**k, in blocks
    out: list[np.ndarray] = []
    while len(out) < len(columns):
        blocks = columns[len(out)]
        rows = blocks[0] if len(blocks) == 1 else np.concatenate(blocks)
        carries = []
        while len(rows) >= 3:
            g = len(rows) // 3
            a, b, c = rows[:g], rows[g:2 * g], rows[2 * g:3 * g]
            partial = a ^ b
            carry = a & b
            carry |= partial & c
            partial ^= c
            carries.append(carry)
            rows = partial if len(rows) == 3 * g else np.concatenate((partial, rows[3 * g:]))
        if len(rows) == 2:
            carries.append(rows[:1] & rows[1:])
            rows = rows[:1] ^ rows[1:]
        out.append(rows[0])
        if carries:
            if len(out) == len(columns):
                columns.append([])
            columns[len(out)].extend(carries)
    return out


class _PackedTotals:
    """Running per-pixel totals of packed 1-bit planes, modulo ``2**(8 * itemsize)`` > ``window``.

    The planes between two window events are counted bit-sliced (``_bit_sliced_sum``: AND/XOR over
    the stored words, nothing unpacked per plane), that count is unpacked once into one integer per
    pixel and added to the total, so a window's sum is the wrapped difference of two totals, exact.
    Totals stay in the stored bit order until :meth:`image` views one in image orientation.
    """

    def __init__(self, window: int, geometry: DatGeometry) -> None:
        self._geometry = geometry
        self._word = _word_dtype(geometry.plane_bytes)
        self._total = np.zeros(geometry.plane_bytes * 8, dtype=np.min_scalar_type(window))

    def add(self, channels: Sequence[np.ndarray], a: int, b: int) -> None:
        if b > a:
            counts = _unpack_count(_bit_sliced_sum(channels[0][a:b].view(self._word)))
            np.add(self._total, counts, out=self._total, casting="unsafe")  # modulo: differences stay exact

    def snapshot(self) -> np.ndarray:
        return self._total.copy()

    def since(self, snapshot: np.ndarray) -> list[np.ndarray]:
        return [np.subtract(self._total, snapshot)]

    def image(self, counts: np.ndarray) -> np.ndarray:
        """Per-pixel counts in stored order -> (H, image_width) in image orientation (a strided view)."""
        g = self._geometry
        image = counts.reshape(g.height, g.width)
        if g.flip:
            image = image[::-1]
        return image[:, : g.image_width]


def _unpack_count(bits: list[np.ndarray]) -> np.ndarray:
    """Bit-sliced count (LSB first, packed words) -> one integer per stored bit position."""
    unpacked = [np.unpackbits(bit.view(np.uint8), bitorder="little") for bit in reversed(bits)]
    counts = unpacked[0].astype(np.min_scalar_type(2 ** len(bits) - 1), copy=False)
    for bit in unpacked[1:]:
        np.add(counts, counts, out=counts)
        np.add(counts, bit, out=counts)
    return counts


class _WindowSums:
    """Sums of planes over windows of ``window`` planes centred every ``step`` planes, streaming.

    Keeps running totals since the first plane and a snapshot of them at each open window's start,
    so every plane is added once whatever the overlap. ``make_totals`` builds the totals from the
    first push's channels (default: :class:`_DenseTotals`).
    """

    def __init__(self, window: int, step: int,
                 make_totals: Callable[[Sequence[np.ndarray]], _Totals] = _DenseTotals) -> None:
        if window < 1 or step < 1:
            raise ValueError(f"window and step must be >= 1, got window={window}, step={step}")
        self.window = window
        self.step = step
        self._make_totals = make_totals
        self._first: int | None = None  # first plane pushed
        self._pos = 0  # next plane expected
        self._totals: _Totals | None = None
        self._open: dict[int, object] = {}  # frame -> snapshot of the totals at its (clipped) window start
        self._next_open = 0
        self._next_close = 0

    def _window_start(self, i: int) -> int:
        return (_centre2(i, self.step) - self.window + 1) // 2

    def push(self, start: int, channels: Sequence[np.ndarray]) -> list[_WindowTotal]:
        """Add planes ``start ..`` (each channel (T, ...)) and return the windows they complete."""
        if self._first is None:
            self._first = self._pos = start
            self._next_open = self._next_close = _first_frame(start, self.step)
            self._totals = self._make_totals(channels)
        elif start != self._pos:
            raise ValueError(f"chunk starts at plane {start}, expected {self._pos}")
        stop = start + len(channels[0])
        out: list[_WindowTotal] = []
        while True:
            p_open = max(self._window_start(self._next_open), self._first)
            p_close = self._window_start(self._next_close) + self.window
            position = min(p_open, p_close)
            if position > stop:
                break
            self._advance(start, channels, position)
            if p_open <= p_close:
                self._open[self._next_open] = self._totals.snapshot()
                self._next_open += 1
            else:
                out.append(self._close(self._next_close, p_close))
                self._next_close += 1
        self._advance(start, channels, stop)
        return out

    def flush(self) -> list[_WindowTotal]:
        """Close the windows whose centre lies in the data, clipped at the last plane."""
        out: list[_WindowTotal] = []
        if self._first is None:
            return out
        while _centre2(self._next_close, self.step) < 2 * self._pos:
            out.append(self._close(self._next_close, self._pos))
            self._next_close += 1
        self._open.clear()
        return out

    def _advance(self, start: int, channels: Sequence[np.ndarray], position: int) -> None:
        if position > self._pos:
            self._totals.add(channels, self._pos - start, position - start)
            self._pos = position

    def _close(self, i: int, end: int) -> _WindowTotal:
        begin = max(self._window_start(i), self._first)
        return _WindowTotal(
            index=i,
            centre=_centre2(i, self.step) / 2,
            count=max(end - begin, 1),
            sums=self._totals.since(self._open.pop(i)),
        )


class Tfp:
    """Texture from playback: mean of ``window`` raw 1-bit planes centred on each frame time.

    Running sums: each plane is added once, whatever the window overlap. Fed :class:`PackedChunk`s
    (``accepts_packed``), it counts the stored bits between two window events bit-sliced and
    unpacks only that count (``_PackedTotals``), never a plane; the frames are identical to those
    from unpacked planes.
    """

    input_kind: ClassVar[InputKind] = "spikes"
    accepts_packed: ClassVar[bool] = True
    #: The frames a push returns are alive together: the dozen of a 256-plane push stay in cache where a 1,024-plane
    #: chunk's 51 (20 MB at 400x250) do not, and the run is about 15 % faster (README, "What accuracy costs in time").
    max_push_planes: ClassVar[int] = 256

    def __init__(self, window: int = 41, step: int = 20) -> None:
        self._sums = _WindowSums(window, step, self._make_totals)
        self._packed: bool | None = None  # set by the first chunk: which kind of totals
        self._geometry: DatGeometry | None = None  # layout of packed chunks
        self._packed_totals: _PackedTotals | None = None  # the totals of packed chunks, to orient sums
        self._images = ImagePool()  # the frames' images, reused once released
        self._rate_hz = 0.0

    def _make_totals(self, channels: Sequence[np.ndarray]) -> _Totals:
        if not self._packed:
            return _DenseTotals(channels)
        self._packed_totals = _PackedTotals(self._sums.window, self._geometry)
        return self._packed_totals

    def push(self, chunk: SpikeChunk | PackedChunk) -> list[Frame]:
        """Consume raw planes (unpacked or packed); return the frames whose window is complete."""
        packed = isinstance(chunk, PackedChunk)
        if self._packed is None:
            self._packed = packed
            if packed:
                self._geometry = chunk.geometry
        elif packed and not self._packed:
            chunk, packed = chunk.unpack(), False
        elif packed != self._packed:
            raise ValueError("Tfp: unpacked planes after packed ones; feed one kind of chunk per run")
        self._rate_hz = chunk.rate_hz
        data = chunk.data if packed else chunk.planes
        return [self._frame(w) for w in self._sums.push(chunk.start, [data])]

    def flush(self) -> list[Frame]:
        """Return the last frames, their windows clipped at the end of the data."""
        return [self._frame(w) for w in self._sums.flush()]

    def _frame(self, total: _WindowTotal) -> Frame:
        if self._packed:
            counts = self._packed_totals.image(total.sums[0])
            if total.count < _EXACT_FLOAT32_INTEGERS:
                # Integers exact in float32: their float32 quotient is the correctly rounded one, the
                # same value as rounding the float64 quotient of the unpacked path (53 >= 2 * 24 + 2).
                image = np.divide(counts, np.float32(total.count), out=self._images.take(counts.shape),
                                  dtype=np.float32)
            else:
                image = (counts / total.count).astype(np.float32)
        else:
            # float64 quotients rounded to float32 on the way out, as ``(sums / count).astype(np.float32)``
            sums = total.sums[0]
            image = np.divide(sums, total.count, out=self._images.take(sums.shape), casting="unsafe")
        return Frame(index=total.index, time_s=total.centre / self._rate_hz, image=image)


def block_scan(planes: np.ndarray, compiled: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Per plane of a block of decoded planes (at most ``_TFI_BLOCK_PLANES``; nonzero: a spike), the last spike at or
    before it as its offset + 1 (0: none) and the first spike at or after it as its offset (``_NONE_IN_BLOCK``: none);
    uint8 offsets. By the compiled kernel where the install built one (``rmbvideo.sensor.compiled``; about 3x faster)
    unless ``compiled=False``, else in numpy: the same bytes."""
    count = len(planes)
    if KERNELS is not None and compiled and planes.dtype in (np.uint8, np.bool_):
        flat = np.ascontiguousarray(planes).view(np.uint8)
        last_in, first_from = np.empty(planes.shape, np.uint8), np.empty(planes.shape, np.uint8)
        KERNELS.scan_block(flat, last_in, first_from, count, flat[0].size if count else 0)
        return last_in, first_from
    offsets = np.arange(count, dtype=np.uint8)[:, None, None]
    spikes = planes.astype(bool, copy=False)
    last_in = spikes * (offsets + np.uint8(1))
    first_from = _NONE_IN_BLOCK - spikes * (_NONE_IN_BLOCK - offsets)
    # Plane-by-plane running max/min: far faster than ufunc.accumulate along a leading axis.
    for k in range(1, count):
        np.maximum(last_in[k - 1], last_in[k], out=last_in[k])
        np.minimum(first_from[count - k], first_from[count - k - 1], out=first_from[count - k - 1])
    return last_in, first_from


class BlockScans:
    """The last block's ``Tfi`` scan, kept for the next ``Tfi`` pushed the same planes: several TFI searches over one
    stream (the detail stage's, a gate's two windows), fed block by block (``push_by_block``), then scan each block
    once. ``clear`` drops it once every search has read the chunk, so it holds no memory between chunks."""

    def __init__(self) -> None:
        self._key: tuple[int, int, int] | None = None
        self._scan: tuple[np.ndarray, np.ndarray] | None = None
        self.computed = 0  # blocks scanned (a check that the searches share them)

    def get(self, planes: np.ndarray, start: int,
            scan: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        """``scan(planes)`` of the block at plane ``start``, computed once for the same planes."""
        key = (start, len(planes), planes.__array_interface__["data"][0])
        if key != self._key or self._scan is None:
            self._key, self._scan = key, scan(planes)
            self.computed += 1
        return self._scan

    def clear(self) -> None:
        self._key = self._scan = None


def push_by_block(searches: Sequence[Tfi], chunk: SpikeChunk) -> list[list[Frame]]:
    """Each search's frames from ``chunk``, pushed one block of planes at a time to every search in turn, so that
    searches sharing a ``BlockScans`` scan each block once (a search's frames are the same for any chunking)."""
    out: list[list[Frame]] = [[] for _ in searches]
    for b0 in range(0, len(chunk.planes), _TFI_BLOCK_PLANES):
        block = SpikeChunk(chunk.planes[b0 : b0 + _TFI_BLOCK_PLANES], chunk.start + b0, chunk.rate_hz)
        for frames, search in zip(out, searches):
            frames += search.push(block)
    return out


class Tfi:
    """Texture from inter-spike interval: 1 / (interval between the spikes around each frame time); with a
    ``window`` of M planes, the rate over the whole intervals that cover the frame's central M planes.

    For frame ``i`` centred at ``c_i`` (plane k spans [k, k + 1)) the central planes are TFP's window of M planes
    centred there, ``p + 1 .. p + M`` with ``p = floor(c_i - (M - 1) / 2) - 1`` (none when M = 0: ``prev`` then at or
    before the plane that ends nearest ``c_i``, ``next`` after it); per pixel ``prev`` is the last spike at or before
    ``p`` and ``next`` the first spike after the central planes, each searched at most ``max_reach`` planes beyond
    them and never outside the pushed data.
    Value = (spikes in the central planes + 1) / (next - prev): the spikes from just after ``prev`` up to ``next``
    over the planes they span, so M = 0 is plain TFI. A pixel that fires regularly (the rate convention, no
    noise) reads its rate to within one spike over the span, where TFP's fixed window of the same length is off
    by up to one spike at each end and a single interval quantises it coarsely (at 0.4 spikes a plane it reads
    1/2 or 1/3). Where no spike is found on a side, the edge of the searched range stands in for it
    (``p - max_reach`` or the plane before the data; ``p + M + max_reach + 1`` or the plane after the data): the
    value is then an upper bound on the rate, finite and > 0, and an all-dark pixel reads about
    ``1 / (2 * max_reach + M + 1)``. next - prev >= 1.

    ``shorter``: further reaches below ``max_reach`` read from the same search (each frame's image is then
    (len(shorter) + 1, H, W): each of them, then ``max_reach``), exactly what a ``Tfi`` of that reach gives, for the
    cost of one search: the spikes around a frame within the shorter reach are the same ones.

    ``scans``: a ``BlockScans`` shared with other ``Tfi`` pushed the same chunks (other windows), so each block's
    running first/last spike offsets are computed once.
    """

    input_kind: ClassVar[InputKind] = "spikes"

    def __init__(self, step: int = 20, max_reach: int = 200, shorter: tuple[int, ...] = (), window: int = 0,
                 scans: BlockScans | None = None) -> None:
        if step < 1 or max_reach < 1 or window < 0:
            raise ValueError(f"step and max_reach must be >= 1 and window >= 0, got step={step}, "
                             f"max_reach={max_reach}, window={window}")
        if any(not 1 <= reach < max_reach for reach in shorter):
            raise ValueError(f"shorter reaches must lie in 1 .. {max_reach - 1}, got {shorter}")
        self.step = step
        self.max_reach = max_reach
        self.window = window
        self.shorter = tuple(shorter)
        self._scans = scans
        self._first: int | None = None
        self._pos = 0
        self._rate_hz = 0.0
        # plane numbers in int32 (int64 once a capture nears 2**31 planes, 30 hours at 20 kHz), the central planes'
        # spikes in the narrowest type that holds window + 1: a frame waiting for its next spikes holds 9 bytes a
        # pixel, not 24 (about 300 MB less for the default job on a 1000x1000 camera)
        self._index_dtype: type = np.int32
        self._count_dtype = np.min_scalar_type(window + 1)
        self._last_spike: np.ndarray | None = None  # (H, W) last spike plane so far, -1 if none
        self._next_frame = 0  # next frame whose reference plane is not yet reached
        # frame -> (p, prev, next or -1, spikes so far in the central planes p + 1 .. p + window; None without)
        self._pending: dict[int, tuple[int, np.ndarray, np.ndarray, np.ndarray | None]] = {}

    def _reference(self, i: int) -> int:
        """The plane ``p`` just before frame ``i``'s central planes (TFP's window there, so both are centred alike)."""
        return (_centre2(i, self.step) - self.window + 1) // 2 - 1

    def push(self, chunk: SpikeChunk) -> list[Frame]:
        """Consume raw planes; return the frames whose look-ahead is complete."""
        if self._first is None:
            self._first = self._pos = chunk.start
            self._next_frame = _first_frame(chunk.start, self.step)
            self._last_spike = self._indices_like(chunk.planes[0], -1)
        elif chunk.start != self._pos:
            raise ValueError(f"chunk starts at plane {chunk.start}, expected {self._pos}")
        self._rate_hz = chunk.rate_hz
        for b0 in range(0, len(chunk.planes), _TFI_BLOCK_PLANES):
            self._process_block(chunk.planes[b0 : b0 + _TFI_BLOCK_PLANES], chunk.start + b0)
        done = sorted(i for i, (r, *_) in self._pending.items() if r + self.window + self.max_reach < self._pos)
        return [self._frame(i, self._pending.pop(i)) for i in done]

    def flush(self) -> list[Frame]:
        """Return the remaining frames whose centre lies in the data, their look-ahead clipped at its end (a
        ``window`` starts frames a little before their centre's plane is reached)."""
        frames = [self._frame(i, self._pending[i]) for i in sorted(self._pending)
                  if _centre2(i, self.step) // 2 < self._pos]
        self._pending.clear()
        return frames

    # The array operations, numpy's here (``rmbvideo.recon.device_rates.DeviceTfi``: torch's, on a device).
    _where = staticmethod(np.where)
    _stack = staticmethod(np.stack)

    def _indices_like(self, like: np.ndarray, value: int) -> np.ndarray:
        return np.full(like.shape, value, dtype=self._index_dtype)

    def _counts_like(self, like: np.ndarray) -> np.ndarray:
        return np.zeros(like.shape, dtype=self._count_dtype)

    def _indices(self, a: np.ndarray) -> np.ndarray:
        return a.astype(self._index_dtype)

    def _widen_indices(self, stop: int) -> None:
        """Plane numbers in int64 from the block whose search reaches past int32's range (``stop``) on."""
        if self._index_dtype is np.int64 or stop < np.iinfo(np.int32).max:
            return
        self._index_dtype = np.int64
        self._last_spike = self._last_spike.astype(np.int64)
        self._pending = {i: (r, prev.astype(np.int64), nxt.astype(np.int64), spikes)
                         for i, (r, prev, nxt, spikes) in self._pending.items()}

    @staticmethod
    def _count(planes: np.ndarray) -> np.ndarray:
        """Spikes per pixel over ``planes`` (at most a block's ``_TFI_BLOCK_PLANES``): summed in uint16, 4-5x faster
        than in int64 and exact here; added to the counts (at most the window's planes)."""
        return planes.sum(axis=0, dtype=np.uint16)

    @staticmethod
    def _image(interval: np.ndarray, spikes: np.ndarray | None = None) -> np.ndarray:
        """``spikes`` / ``interval`` (1 / ``interval`` when None) in float64, rounded to float32."""
        return ((1.0 if spikes is None else spikes) / interval).astype(np.float32)

    @staticmethod
    def _fill_next(nxt: np.ndarray, first: np.ndarray, start: int, limit: int) -> None:
        """Where ``nxt`` has no spike yet (-1) and the block's ``first`` spike offset (uint8, ``_scan``) is at most
        ``limit``, set ``nxt`` to ``start`` + that offset: one masked add, no int64 copy of the offsets."""
        take = (first <= limit) & (nxt < 0)
        np.add(first, nxt.dtype.type(start), out=nxt, where=take)

    @staticmethod
    def _scan(planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return block_scan(planes)

    def _process_block(self, planes: np.ndarray, start: int) -> None:
        count = len(planes)
        if count == 0:
            return
        last_in, first_from = self._scan(planes) if self._scans is None else self._scans.get(planes, start, self._scan)
        self._widen_indices(start + count + self.window + self.max_reach + 1)

        m = self.window

        def search(r: int, nxt: np.ndarray, spikes: np.ndarray | None) -> None:
            """Add this block's central planes of the frame at ``r`` to ``spikes``; search it for ``next``."""
            lo, hi = max(r + 1, start), min(r + m, start + count - 1)
            if spikes is not None and lo <= hi:
                spikes += self._count(planes[lo - start : hi - start + 1])
            lo, hi = max(r + m + 1, start), min(r + m + self.max_reach, start + count - 1)
            if lo <= hi:
                self._fill_next(nxt, first_from[lo - start], start, hi - start)

        for r, _, nxt, spikes in self._pending.values():  # pending frames: this block's part of each
            search(r, nxt, spikes)
        while self._reference(self._next_frame) < start + count:
            # r >= start, except at the data's start (central planes before the data: no spike there)
            r = self._reference(self._next_frame)
            prev = self._last_spike
            if r >= start:
                in_block = self._indices(last_in[r - start])
                prev = self._where(in_block > 0, start + in_block - 1, prev)
            nxt, spikes = self._indices_like(prev, -1), self._counts_like(prev) if m else None
            search(r, nxt, spikes)
            self._pending[self._next_frame] = (r, prev, nxt, spikes)
            self._next_frame += 1
        last = self._indices(last_in[-1])
        self._last_spike = self._where(last > 0, start + last - 1, self._last_spike)
        self._pos = start + count

    def _frame(self, i: int, state: tuple[int, np.ndarray, np.ndarray, np.ndarray | None]) -> Frame:
        images = [self._reach_image(*state, reach) for reach in (*self.shorter, self.max_reach)]
        image = images[0] if len(images) == 1 else self._stack(images)
        return Frame(index=i, time_s=_centre2(i, self.step) / 2 / self._rate_hz, image=image)

    def _reach_image(self, r: int, prev: np.ndarray, nxt: np.ndarray, spikes: np.ndarray | None,
                     reach: int) -> np.ndarray:
        """(central spikes + 1) / interval for spikes searched at most ``reach`` planes beyond the central planes (a
        next spike found further out, by the longer search, is out of reach)."""
        lo = max(r - reach + 1, self._first)
        hi = min(r + self.window + reach, self._pos - 1)
        prev = self._where(prev >= lo, prev, lo - 1)
        nxt = self._where((nxt >= 0) & (nxt <= hi), nxt, hi + 1)
        interval = nxt - prev
        return self._image(self._where(interval >= 1, interval, 1), None if spikes is None else spikes + 1)


class Tfw:
    """Texture from window on the binned RMB stream: pooled spike rate over ``window`` readouts.

    Evidence per pixel over the window: ``n`` 1-bit readouts (each one raw pixel-plane) and ``n_m``
    dense multi-bit readouts, each counting spikes over ``q`` raw pixel-planes (binned data: q = 8,
    a 2x2x2 bin; a native L-level sensor: q = L sub-threshold steps of one pixel). The estimate is
    the pooled rate ``(sum single + sum multi) / (n + q * n_m)`` spikes per raw pixel-plane: the
    maximum-likelihood rate when all counts are Bernoulli trials, i.e. each source weighted by its
    number of trials. Rows without multi-bit evidence (pure-S) use the 1-bit mean alone. Binned data
    whose bin count was read at every readout of the window (pure-M) uses the counts alone: the 1-bit
    value is one of the bin's 8 trials, so pooling it would count that trial twice. Saturated
    bins (multi clamped at ``level``) bias bright pixels low by at most 1/9 for binned data.
    ``window`` and ``step`` are in readouts of the RMB stream; the defaults give frames at the
    same times as TFP/TFI with step 20 on the raw stream.
    """

    input_kind: ClassVar[InputKind] = "rmb"

    def __init__(self, window: int = 10, step: int = 10, upsampler: MultiUpsampler | None = None) -> None:
        self._sums = _WindowSums(window, step)
        self.upsampler: MultiUpsampler = upsampler if upsampler is not None else TemporalInterpolation()
        self._rate_hz = 0.0
        self._quanta = 8  # raw pixel-planes (trials) per multi-bit readout; set from the data

    def push(self, chunk: RmbChunk) -> list[Frame]:
        """Consume RMB readouts; return the frames whose window is complete."""
        return [f for dense in self.upsampler.push(chunk) for f in self._add(dense)]

    def flush(self) -> list[Frame]:
        """Return the last frames, their windows clipped at the end of the data."""
        frames = [f for dense in self.upsampler.flush() for f in self._add(dense)]
        return frames + [self._frame(w) for w in self._sums.flush()]

    def _add(self, dense: DenseChunk) -> list[Frame]:
        self._rate_hz = dense.rate_hz
        self._quanta = 4 * dense.raw_per_readout if dense.raw_per_readout > 1 else dense.level
        measured = dense.measured if dense.measured is not None and dense.raw_per_readout > 1 \
            else np.zeros_like(dense.multi_valid)
        channels = [dense.single, dense.multi, dense.multi_valid, measured]
        return [self._frame(w) for w in self._sums.push(dense.start, channels)]

    def _frame(self, total: _WindowTotal) -> Frame:
        sum_s, sum_m, n_m, n_read = total.sums
        trials = total.count + self._quanta * n_m[:, None].astype(np.float64)
        pooled = (sum_s + sum_m) / trials
        counts_only = (n_read == total.count)[:, None]  # every readout of the window read the bin count
        image = np.where(counts_only, sum_m / (self._quanta * max(total.count, 1)), pooled).astype(np.float32)
        return Frame(index=total.index, time_s=total.centre / self._rate_hz, image=image)


def tfw_s(upsampler: MultiUpsampler | None = None) -> Tfw:
    """TFW-S of the paper's Table 2: a window of 10 readouts."""
    return Tfw(window=10, upsampler=upsampler)


def tfw_l(upsampler: MultiUpsampler | None = None) -> Tfw:
    """TFW-L of the paper's Table 2: a window of 70 readouts."""
    return Tfw(window=70, upsampler=upsampler)
