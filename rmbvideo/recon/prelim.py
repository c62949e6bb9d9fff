"""Dense multi-bit planes from a rolling band, and the preliminary frames I_s, I_m (paper Sec. 4.1).

Upsampling: a row of an RMB stream has multi-bit values only at the readouts when the band covered
it. A :class:`MultiUpsampler` turns such a stream into :class:`DenseChunk` s with a multi-bit value
for every row at every readout. :class:`TemporalInterpolation` is the flow-free fast path; a
flow-based upsampler (warping with optical flow from the 1-bit stream) can replace it by
implementing the same two methods.

Preliminary frames: :class:`PreliminaryFrames` sums N readouts of 1-bit values (I_s) and of dense
multi-bit values (I_m), and the dense multi-bit values of the central 2, 4 and 6 readouts (I_c: the
frame's centre time at a finer time scale, for fast motion). Frame ``i`` covers readouts
``[i*N, (i+1)*N)`` counted from readout 0 of the file, so runs started at different planes produce aligned frames. A group that is not complete in
the data (the first one when the run starts mid-group, the last one when the data ends mid-group)
is dropped rather than emitted with fewer readouts, so every frame has the same exposure.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from rmbvideo.chunks import DenseChunk, RmbChunk

log = logging.getLogger(__name__)

# Interpolated multi-bit values are rounded to multiples of 2**-10: sums of such values are exact
# in float64, so windowed sums downstream do not depend on chunking or summation order. The
# rounding error (<= 5e-4 of a level) is far below the shot noise of one readout.
_DENSE_QUANTUM = 1024.0
#: Central sub-windows (readouts) whose multi-bit sums every preliminary frame also carries, where
#: they fit the frame symmetrically (``centre_windows``).
CENTRE_READOUTS = (2, 4, 6)
# Readouts interpolated per block: bounds the (block, H, W) float temporaries.
_BLOCK_READOUTS = 64


class MultiUpsampler(Protocol):
    """Streams an RMB stream into dense multi-bit readouts, in order, independent of chunking."""

    def push(self, chunk: RmbChunk) -> list[DenseChunk]:
        """Consume the next chunk; return the dense readouts that are now final (possibly none)."""
        ...

    def flush(self) -> list[DenseChunk]:
        """End of stream: return every readout still held back."""
        ...


class ReadoutBuffer:
    """Readouts of an RMB stream that an upsampler holds until they are final: contiguous from
    absolute readout ``start`` (``single``, ``multi``, ``rows`` as in ``RmbChunk``; None before the
    first chunk); ``meta`` is the stream's (rate_hz, level, raw_per_readout)."""

    def __init__(self) -> None:
        self.single: np.ndarray | None = None
        self.multi: np.ndarray | None = None
        self.rows: np.ndarray | None = None
        self.start = 0
        self.meta: tuple[float, int, int] = (0.0, 7, 2)

    @property
    def stop(self) -> int:
        """Absolute readout after the last one held."""
        return self.start + (0 if self.rows is None else len(self.rows))

    def append(self, chunk: RmbChunk) -> None:
        """Add the next chunk; it must start where the buffer ends."""
        if self.rows is None:
            self.start = chunk.start
            self.single, self.multi, self.rows = chunk.single[:0], chunk.multi[:0], chunk.multi_rows[:0].astype(bool)
        elif chunk.start != self.stop:
            raise ValueError(f"chunk starts at readout {chunk.start}, expected {self.stop}")
        self.meta = (chunk.rate_hz, chunk.level, chunk.raw_per_readout)
        self.single = np.concatenate([self.single, chunk.single])
        self.multi = np.concatenate([self.multi, chunk.multi])
        self.rows = np.concatenate([self.rows, chunk.multi_rows.astype(bool, copy=False)])

    def drop(self, count: int) -> None:
        """Forget the first ``count`` readouts (copies, so the dropped part can be freed)."""
        self.single, self.multi, self.rows = self.single[count:].copy(), self.multi[count:].copy(), self.rows[count:].copy()
        self.start += count


class TemporalInterpolation:
    """Flow-free upsampling: per row, linear interpolation in time between consecutive multi-bit samples.

    A readout that has the row's own sample keeps it exactly. Before a row's first sample and after
    its last one the nearest sample is held. The next sample is looked for at most ``max_gap``
    readouts ahead (beyond that the previous sample is held), which bounds the lookahead buffer; the
    default 256 covers one band cycle (H / shift readouts) of a 500-row sensor with shift 2. A
    readout is emitted as soon as every row has a sample at or after it, so pure-M data passes
    through unchanged without delay and RMB data is delayed by at most one band cycle. A row that
    has no sample at all in reach (pure-S data) gets 0 with ``multi_valid`` False.
    """

    def __init__(self, max_gap: int = 256) -> None:
        if max_gap < 1:
            raise ValueError(f"max_gap must be >= 1, got {max_gap}")
        self.max_gap = max_gap
        self._buf = ReadoutBuffer()
        self._last_t: np.ndarray | None = None  # (H,) absolute readout of the row's last emitted sample, -1 if none
        self._last_v: np.ndarray | None = None  # (H, W) float32 values of that sample

    def push(self, chunk: RmbChunk) -> list[DenseChunk]:
        """Buffer ``chunk``; return the readouts whose interpolation no longer depends on later data."""
        self._append(chunk)
        rows = self._buf.rows
        length = len(rows)
        if length == 0:
            return []
        # A readout is final once every row has a sample at or after it (or max_gap readouts follow).
        last_known = length - 1 - np.argmax(rows[::-1], axis=0)
        last_known = np.where(rows.any(axis=0), last_known, -1)
        ready = max(int(last_known.min()) + 1, length - self.max_gap, 0)
        return self._emit(ready)

    def flush(self) -> list[DenseChunk]:
        """End of stream: interpolate what is left, holding each row's last sample."""
        if self._buf.rows is None:
            return []
        return self._emit(len(self._buf.rows))

    def _append(self, chunk: RmbChunk) -> None:
        if self._last_t is None:
            height, width = chunk.single.shape[1:]
            self._last_t = np.full(height, -1, dtype=np.int64)
            self._last_v = np.zeros((height, width), dtype=np.float32)
        self._buf.append(chunk)

    def _emit(self, count: int) -> list[DenseChunk]:
        """Interpolate the first ``count`` buffered readouts, update the carried samples, trim the buffer."""
        if count <= 0:
            return []
        rows, multi = self._buf.rows, self._buf.multi
        if rows[:count].all():
            return self._emit_measured(count)
        length, height = rows.shape
        index = np.arange(length, dtype=np.int64)[:, None]
        prev = np.maximum.accumulate(np.where(rows, index, -1), axis=0)[:count]
        nxt = np.minimum.accumulate(np.where(rows, index, length)[::-1], axis=0)[::-1][:count]
        last_rel = self._last_t - self._buf.start  # negative: before the buffer
        in_buffer_prev = prev >= 0
        has_prev = in_buffer_prev | (self._last_t >= 0)[None, :]
        prev_time = np.where(in_buffer_prev, prev, last_rel[None, :])
        t = index[:count]
        has_next = (nxt < length) & (nxt - t <= self.max_gap)
        row_index = np.arange(height)[None, :]
        rate_hz, level, raw_per_readout = self._buf.meta
        out: list[DenseChunk] = []
        for b0 in range(0, count, _BLOCK_READOUTS):
            b1 = min(b0 + _BLOCK_READOUTS, count)
            sl = slice(b0, b1)
            v_prev = np.where(
                in_buffer_prev[sl, :, None],
                multi[np.maximum(prev[sl], 0), row_index].astype(np.float32),
                self._last_v[None],
            )
            v_next = multi[np.minimum(nxt[sl], length - 1), row_index].astype(np.float32)
            both = has_prev[sl] & has_next[sl]
            span = np.maximum(nxt[sl] - prev_time[sl], 1)
            weight = np.where(both, (t[sl] - prev_time[sl]) / span, 0.0).astype(np.float32)
            dense = np.where(has_prev[sl, :, None], v_prev, v_next)
            dense = dense + (v_next - v_prev) * weight[:, :, None] * both[:, :, None]
            dense = np.round(dense * _DENSE_QUANTUM) / _DENSE_QUANTUM
            valid = has_prev[sl] | has_next[sl]
            dense = np.where(valid[:, :, None], dense, 0.0).astype(np.float32)
            out.append(
                DenseChunk(
                    single=self._buf.single[sl],
                    multi=dense,
                    multi_rows=valid,
                    start=self._buf.start + b0,
                    rate_hz=rate_hz,
                    level=level,
                    raw_per_readout=raw_per_readout,
                    measured=rows[sl].copy(),
                )
            )
        seen = rows[:count].any(axis=0)
        if seen.any():
            last = count - 1 - np.argmax(rows[:count][::-1], axis=0)
            self._last_t = np.where(seen, self._buf.start + last, self._last_t)
            self._last_v = np.where(seen[:, None], multi[last, np.arange(height)].astype(np.float32), self._last_v)
        self._buf.drop(count)
        return out

    def _emit_measured(self, count: int) -> list[DenseChunk]:
        """The first ``count`` readouts when every row has its own sample at each (pure-M data): the
        samples themselves, what interpolation gives there, without its gathers."""
        multi, rows = self._buf.multi, self._buf.rows
        rate_hz, level, raw_per_readout = self._buf.meta
        out = [
            DenseChunk(
                single=self._buf.single[b0:b1],
                multi=multi[b0:b1].astype(np.float32),
                multi_rows=rows[b0:b1].copy(),
                start=self._buf.start + b0,
                rate_hz=rate_hz,
                level=level,
                raw_per_readout=raw_per_readout,
                measured=rows[b0:b1].copy(),
            )
            for b0, b1 in ((b, min(b + _BLOCK_READOUTS, count)) for b in range(0, count, _BLOCK_READOUTS))
        ]
        self._last_t[:] = self._buf.start + count - 1
        self._last_v = multi[count - 1].astype(np.float32)
        self._buf.drop(count)
        return out


def centre_windows(n: int) -> tuple[int, ...]:
    """The ``CENTRE_READOUTS`` that fit a frame of ``n`` readouts symmetrically (shorter than n, same parity)."""
    return tuple(k for k in CENTRE_READOUTS if k < n and (n - k) % 2 == 0)


def select_centre(i_c: np.ndarray | None, n: int, windows: tuple[int, ...]) -> np.ndarray:
    """The channels of central sums ``i_c`` (laid out as ``centre_windows(n)``, leading axes kept) that
    ``windows`` names, (..., len(windows), H, W) float32. Raises ``ValueError`` if any is missing."""
    available = centre_windows(n)
    missing = [k for k in windows if k not in available]
    if i_c is None or missing:
        raise ValueError(f"central sums over {list(windows)} readouts are needed; frames of {n} readouts carry "
                         f"{list(available) if i_c is not None else 'none'}")
    return np.asarray(i_c, np.float32)[..., [available.index(k) for k in windows], :, :]


@dataclass
class PrelimFrame:
    """Sums over N readouts: ``i_s`` of 1-bit values, ``i_m`` of dense multi-bit values ((H, W) float32).

    ``m_valid`` (H,) bool is False for rows without multi-bit evidence (``i_m`` is 0 there).
    ``time_s`` is the centre of the N readouts in seconds from the start of the file. ``i_c``
    (len(centre_windows(N)), H, W) float32: dense multi-bit sums over each central sub-window, or None.
    """

    index: int
    time_s: float
    i_s: np.ndarray
    i_m: np.ndarray
    m_valid: np.ndarray
    i_c: np.ndarray | None = None


class PreliminaryFrames:
    """Streams an RMB stream into preliminary frames of ``n`` readouts each (see module docstring)."""

    def __init__(self, n: int = 10, upsampler: MultiUpsampler | None = None) -> None:
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        self.n = n
        self.upsampler: MultiUpsampler = upsampler if upsampler is not None else TemporalInterpolation()
        self._group = -1  # frame index being accumulated
        self._count = 0  # readouts of that group accumulated so far
        self._complete_from_start = False  # the group's first readout was seen
        self._sum_s: np.ndarray | None = None
        self._sum_m: np.ndarray | None = None
        self._sum_c: np.ndarray | None = None
        self._centre = [((n - k) // 2, (n + k) // 2) for k in centre_windows(n)]  # offsets in the frame
        self._valid: np.ndarray | None = None
        self._next_readout: int | None = None

    def push(self, chunk: RmbChunk) -> list[PrelimFrame]:
        """Consume the next chunk; return the frames completed by it."""
        return [f for dense in self.upsampler.push(chunk) for f in self._accumulate(dense)]

    def flush(self) -> list[PrelimFrame]:
        """End of stream: return the frames still held by the upsampler; a trailing partial group is dropped."""
        frames = [f for dense in self.upsampler.flush() for f in self._accumulate(dense)]
        if self._count:
            log.debug("dropping incomplete preliminary frame %d (%d of %d readouts)", self._group, self._count, self.n)
        self._count = 0
        return frames

    def _accumulate(self, dense: DenseChunk) -> list[PrelimFrame]:
        if self._next_readout is not None and dense.start != self._next_readout:
            raise ValueError(f"dense chunk starts at readout {dense.start}, expected {self._next_readout}")
        self._next_readout = dense.stop
        frames: list[PrelimFrame] = []
        pos = dense.start
        while pos < dense.stop:
            group = pos // self.n
            if group != self._group:
                self._start_group(group, dense, from_start=pos % self.n == 0)
            end = min(dense.stop, (group + 1) * self.n)
            a, b = pos - dense.start, end - dense.start
            self._sum_s += dense.single[a:b].sum(axis=0, dtype=np.int32)
            offset = pos - group * self.n  # of readout a within the frame
            self._add_multi(dense, a, b, offset)
            self._valid &= dense.multi_valid[a:b].all(axis=0)
            self._count += b - a
            pos = end
            if self._count == self.n and self._complete_from_start:
                frames.append(
                    PrelimFrame(
                        index=group,
                        time_s=(group * self.n + self.n / 2) / dense.rate_hz,
                        i_s=self._sum_s.astype(np.float32),
                        i_m=self._sum_m.astype(np.float32),
                        m_valid=self._valid.copy(),
                        i_c=self._sum_c.astype(np.float32),
                    )
                )
                self._count = 0
        return frames

    def _add_multi(self, dense: DenseChunk, a: int, b: int, offset: int) -> None:
        """Add readouts ``a:b`` of ``dense`` (``offset`` the first one's place in the frame) to the frame's multi-bit
        sum and to its central sums. Measured counts are whole numbers, so float32 sums of them are exact: one
        running sum gives every window as a difference. Upsampled values are summed in float64."""
        block = dense.multi[a:b]
        windows = [(max(lo, offset) - offset, min(hi, offset + b - a) - offset) for lo, hi in self._centre]
        if dense.measured is not None and dense.measured[a:b].all():
            running = np.empty(block.shape, np.float32)  # np.cumsum along axis 0 runs strided: 3x slower
            running[0] = block[0]
            for k in range(1, len(block)):
                np.add(running[k - 1], block[k], out=running[k])
            self._sum_m += running[-1]
            for c, (c0, c1) in enumerate(windows):
                if c0 < c1:
                    self._sum_c[c] += running[c1 - 1] - running[c0 - 1] if c0 else running[c1 - 1]
            return
        self._sum_m += block.sum(axis=0, dtype=np.float64)
        for c, (c0, c1) in enumerate(windows):
            if c0 < c1:
                self._sum_c[c] += block[c0:c1].sum(axis=0, dtype=np.float64)

    def _start_group(self, group: int, dense: DenseChunk, from_start: bool) -> None:
        if self._count:
            log.debug("dropping incomplete preliminary frame %d (%d of %d readouts)", self._group, self._count, self.n)
        height, width = dense.single.shape[1:]
        self._group = group
        self._count = 0
        self._complete_from_start = from_start
        self._sum_s = np.zeros((height, width), dtype=np.int64)
        self._sum_m = np.zeros((height, width), dtype=np.float64)
        self._sum_c = np.zeros((len(self._centre), height, width), dtype=np.float64)
        self._valid = np.ones(height, dtype=bool)
