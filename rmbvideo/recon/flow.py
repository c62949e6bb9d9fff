"""Classical optical flow on 1-bit spike images (paper Sec. 4.1, Fig. 4b; Sec. 4.2 alignment).

The paper uses Spike2Flow; no pretrained spike-flow network can ship here, so flow comes from
OpenCV (DIS by default, Farneback, or TV-L1 from opencv-contrib) computed on images reconstructed
from the 1-bit stream, tone-mapped to 8 bits (square-root gamma after a light blur, normalised by
the pair's joint maximum) because those methods expect 8-bit or [0, 1] input.

Two uses:

- ``FlowUpsampler``: a ``rmbvideo.recon.prelim.MultiUpsampler`` that rectifies the rolling
  distortion of the multi-bit band (every sample is warped from its readout time to the band
  cycle's half time t_h) and interpolates between cycles with bidirectional flow.
- ``align``: warp a window of preliminary frames to the reference frame's time.

Flow convention: ``estimate_flow(a, b)`` returns F with a(x) ~ b(x + F(x)), so
``warp(b, F)`` resamples b onto a's pixel grid (backward warping).
"""

from __future__ import annotations

import logging
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from rmbvideo.chunks import DenseChunk, RmbChunk
from rmbvideo.recon.prelim import ReadoutBuffer

log = logging.getLogger(__name__)

FLOW_METHODS = ("dis", "farneback", "tvl1")
#: The smallest image side given to OpenCV's DIS: it refuses images under 12 a side, and OpenCV 5.0's crashes
#: (a segmentation fault, no exception) on strips 8-15 rows high and 40 or more wide with every preset, 16-31 high and
#: 80 or more wide with the fast ones; from 32 a side none crashed (sides 32-128 by 32-4000, every preset:
#: ``python models/experiments/dis-sizes/scan.py``).
DIS_MIN_SIZE = 32
# Same rounding as the flow-free upsampler: sums of dense values stay exact in float64.
_DENSE_QUANTUM = 1024.0


def to_flow_images(a: np.ndarray, b: np.ndarray, blur_sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Tone-map a pair of linear images to uint8 with one shared scale (flow needs equal brightness)."""
    out = []
    for img in (a, b):
        img = np.nan_to_num(np.asarray(img, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        out.append(cv2.GaussianBlur(img, (0, 0), blur_sigma) if blur_sigma > 0 else img)
    scale = max(float(out[0].max()), float(out[1].max()), 1e-12)
    return tuple(np.round(255.0 * np.sqrt(np.clip(o / scale, 0.0, 1.0))).astype(np.uint8) for o in out)


def dis_flow(dis: cv2.DISOpticalFlow, a8: np.ndarray, b8: np.ndarray) -> np.ndarray:
    """``dis.calc(a8, b8)`` on images of any size: a side under ``DIS_MIN_SIZE`` (a tiny capture or a narrow strip,
    binned) is padded with its edge pixels to that size and the flow cropped back, where DIS itself would refuse
    the images or crash the process."""
    h, w = a8.shape
    pad_y, pad_x = max(0, DIS_MIN_SIZE - h), max(0, DIS_MIN_SIZE - w)
    if not (pad_y or pad_x):
        return dis.calc(a8, b8, None)
    a8, b8 = (cv2.copyMakeBorder(img, 0, pad_y, 0, pad_x, cv2.BORDER_REPLICATE) for img in (a8, b8))
    return np.ascontiguousarray(dis.calc(a8, b8, None)[:h, :w])


def estimate_flow(a: np.ndarray, b: np.ndarray, method: str = "dis") -> np.ndarray:
    """Flow (H, W, 2) float32 from linear image ``a`` to ``b``: a(x) ~ b(x + F(x))."""
    a8, b8 = to_flow_images(a, b)
    if method == "dis":
        flow = dis_flow(cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM), a8, b8)
    elif method == "farneback":
        flow = cv2.calcOpticalFlowFarneback(a8, b8, None, 0.5, 3, 15, 3, 5, 1.2, 0)
    elif method == "tvl1":
        flow = cv2.optflow.DualTVL1OpticalFlow_create().calc(a8, b8, None)
    else:
        raise ValueError(f"flow method must be one of {FLOW_METHODS}, got {method!r}")
    return np.nan_to_num(flow.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)


def warp(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Backward-warp: out(x) = image(x + flow(x)), bilinear, edges replicated."""
    h, w = image.shape
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(np.asarray(image, np.float32), gx + flow[..., 0], gy + flow[..., 1],
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


class _FrameLike(Protocol):
    i_s: np.ndarray
    i_m: np.ndarray


def align(
    frames: Sequence[_FrameLike],
    ref_index: int,
    method: str,
    cache: dict | None = None,
    keys: Sequence[Hashable] | None = None,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Warp each frame's (I_s, I_m) to ``frames[ref_index]``'s time; returns float32 pairs.

    Flow is estimated between I_s images. ``cache`` (with one ``keys`` entry per frame, e.g. frame
    indices) keeps each (reference, frame) flow so overlapping windows compute it once.
    """
    if method == "none":
        return [(np.asarray(f.i_s, np.float32), np.asarray(f.i_m, np.float32)) for f in frames]
    keys = list(range(len(frames))) if keys is None else list(keys)
    ref = frames[ref_index]
    out = []
    for key, frame in zip(keys, frames):
        if key == keys[ref_index]:
            out.append((np.asarray(frame.i_s, np.float32), np.asarray(frame.i_m, np.float32)))
            continue
        cache_key = (keys[ref_index], key, method)
        flow = cache.get(cache_key) if cache is not None else None
        if flow is None:
            flow = estimate_flow(ref.i_s, frame.i_s, method)
            if cache is not None:
                cache[cache_key] = flow
        out.append((np.maximum(warp(frame.i_s, flow), 0.0), np.maximum(warp(frame.i_m, flow), 0.0)))
    return out


@dataclass
class _Cycle:
    """One band cycle rectified to its half time: ``multi`` (H,W) per-readout multi-bit estimate."""

    index: int
    t_half: float
    multi: np.ndarray
    valid: np.ndarray   # (H,) rows with a sample in this cycle
    single: np.ndarray  # mean 1-bit image of the cycle (for inter-cycle flow)


class FlowUpsampler:
    """Flow-based ``MultiUpsampler``: rolling-shutter rectification plus flow interpolation.

    Readouts are grouped in cycles of ``cycle`` readouts (absolute: cycle c is readouts
    [c*cycle, (c+1)*cycle); default ceil(H / shift), one sweep of the RMB band). Per cycle, each row's samples
    are averaged at their mean readout time tau(y); motion per readout v comes from the flow
    between the mean 1-bit images of the cycle's two halves; the row is warped by v*(tau(y) - t_h)
    to the half time t_h. A readout t between t_h(c) and t_h(c+1) blends the two warped cycles with
    the bidirectional flow between their 1-bit images (Super SloMo's linear flow approximation).
    Before the first/after the last half time the nearest cycle is held. Rows without a sample in
    a cycle take the previous cycle's value (``multi_valid`` False if none yet). Output lags input
    by up to two cycles; memory holds about two cycles of readouts.
    """

    def __init__(self, cycle: int | None = None, method: str = "dis", shift: int = 2) -> None:
        if cycle is not None and cycle < 2:
            raise ValueError(f"cycle must be >= 2 readouts, got {cycle}")
        if method not in FLOW_METHODS:
            raise ValueError(f"flow method must be one of {FLOW_METHODS}, got {method!r}")
        self.cycle = cycle
        self.shift = shift
        self.method = method
        self._buf = ReadoutBuffer()
        self._next_emit = 0
        self._cycles: list[_Cycle] = []   # the last two rectified cycles
        self._pair_flow: tuple[np.ndarray, np.ndarray] | None = None  # flows between them

    def push(self, chunk: RmbChunk) -> list[DenseChunk]:
        """Buffer ``chunk``; return the readouts that are now final."""
        if self._buf.rows is None:
            if self.cycle is None:
                self.cycle = max(2, -(-chunk.multi_rows.shape[1] // self.shift))
            self._next_emit = chunk.start
        self._buf.append(chunk)
        out: list[DenseChunk] = []
        stop = self._buf.start + len(self._buf.rows)
        while True:
            c = self._cycles[-1].index + 1 if self._cycles else self._buf.start // self.cycle
            if (c + 1) * self.cycle > stop:
                break
            self._add_cycle(c, stop)
            # readouts up to the newest half time are final: later data only affects later readouts
            out += self._emit_until(int(np.floor(self._cycles[-1].t_half)) + 1)
        return out

    def flush(self) -> list[DenseChunk]:
        """End of stream: rectify the partial last cycle, emit everything left."""
        if self._buf.rows is None:
            return []
        stop = self._buf.start + len(self._buf.rows)
        c = self._cycles[-1].index + 1 if self._cycles else self._buf.start // self.cycle
        if c * self.cycle < stop:
            self._add_cycle(c, stop)
        return self._emit_until(stop)

    def _add_cycle(self, c: int, stop: int) -> None:
        a = max(c * self.cycle, self._buf.start)
        b = min((c + 1) * self.cycle, stop)
        rows = self._buf.rows[a - self._buf.start : b - self._buf.start]
        multi = self._buf.multi[a - self._buf.start : b - self._buf.start].astype(np.float32)
        single = self._buf.single[a - self._buf.start : b - self._buf.start].astype(np.float32)
        counts = rows.sum(axis=0)
        valid = counts > 0
        safe = np.maximum(counts, 1)
        m_r = (multi * rows[:, :, None]).sum(axis=0) / safe[:, None]
        t_idx = np.arange(a, b, dtype=np.float64)[:, None]
        tau = np.where(valid, (rows * t_idx).sum(axis=0) / safe, 0.0)
        t_half = (a + b - 1) / 2.0
        half = max(1, (b - a) // 2)
        if b - a >= 2:
            flow = estimate_flow(single[:half].mean(axis=0), single[half:].mean(axis=0), self.method)
            velocity = flow / float((b - a) / 2.0)
            shift = velocity * (tau - t_half).astype(np.float32)[:, None, None]
            # bilinear warping mixes in rows without samples: renormalise by the warped validity
            weight = warp(np.broadcast_to(valid[:, None], m_r.shape).astype(np.float32), shift)
            m_rect = warp(m_r * valid[:, None], shift) / np.maximum(weight, 1e-3)
            valid = valid & (weight.min(axis=1) > 1e-3)
        else:
            m_rect = m_r
        if self._cycles:
            previous = self._cycles[-1]
            m_rect = np.where(valid[:, None], m_rect, previous.multi)
            valid = valid | previous.valid
        cycle = _Cycle(c, t_half, m_rect.astype(np.float32), valid, single.mean(axis=0))
        if self._cycles:
            prev = self._cycles[-1]
            self._pair_flow = (estimate_flow(prev.single, cycle.single, self.method),
                               estimate_flow(cycle.single, prev.single, self.method))
        self._cycles = (self._cycles + [cycle])[-2:]

    def _dense_at(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        last = self._cycles[-1]
        if len(self._cycles) == 1 or t >= last.t_half:
            return last.multi, last.valid
        first = self._cycles[0]
        if t <= first.t_half:
            return first.multi, first.valid
        alpha = float((t - first.t_half) / (last.t_half - first.t_half))
        f01, f10 = self._pair_flow
        f_t0 = -(1 - alpha) * alpha * f01 + alpha * alpha * f10
        f_t1 = (1 - alpha) ** 2 * f01 - alpha * (1 - alpha) * f10
        dense = (1 - alpha) * warp(first.multi, f_t0) + alpha * warp(last.multi, f_t1)
        return dense, first.valid & last.valid

    def _emit_until(self, stop: int) -> list[DenseChunk]:
        stop = min(stop, self._buf.start + len(self._buf.rows))
        if stop <= self._next_emit:
            return []
        planes, valids = [], []
        for t in range(self._next_emit, stop):
            dense, valid = self._dense_at(t)
            planes.append(np.where(valid[:, None], np.round(np.maximum(dense, 0.0) * _DENSE_QUANTUM) / _DENSE_QUANTUM, 0.0))
            valids.append(valid)
        a, b = self._next_emit - self._buf.start, stop - self._buf.start
        rate_hz, level, raw_per_readout = self._buf.meta
        out = DenseChunk(single=self._buf.single[a:b], multi=np.stack(planes).astype(np.float32),
                         multi_rows=np.stack(valids), start=self._next_emit, rate_hz=rate_hz,
                         level=level, raw_per_readout=raw_per_readout)
        self._next_emit = stop
        keep_from = min(self._next_emit, (self._cycles[-1].index + 1) * self.cycle)
        drop = keep_from - self._buf.start
        if drop > 0:
            self._buf.drop(drop)
        return [out]
