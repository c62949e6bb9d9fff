"""Optical flow: estimation on spike images, alignment, and the flow-based multi-bit upsampler."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from rmbvideo.chunks import RmbChunk
from rmbvideo.recon.flow import DIS_MIN_SIZE, FlowUpsampler, align, dis_flow, estimate_flow, warp
from rmbvideo.recon.prelim import PreliminaryFrames, TemporalInterpolation
from rmbvideo.sensor.readout import RmbReadout

H, W = 48, 64
SPEED = 0.25  # pixels per readout, to the right


def texture(shift: float) -> np.ndarray:
    """A smooth random texture in [0.05, 0.95], translated right by ``shift`` pixels."""
    rng = np.random.default_rng(7)
    base = cv2.GaussianBlur(rng.random((H, 3 * W)).astype(np.float32), (0, 0), 3.0)
    base = (base - base.min()) / (base.max() - base.min())
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32) + W - shift, np.arange(H, dtype=np.float32))
    img = cv2.remap(base, gx, gy, cv2.INTER_LINEAR)
    return 0.05 + 0.9 * img


def translating_stream(readouts: int) -> tuple[RmbChunk, RmbChunk]:
    """Deterministic integrate-and-fire streams: (pure-M chunk as ground truth, its RMB readout)."""
    acc_s = np.zeros((H, W), np.float64)
    acc_m = np.zeros((H, W), np.float64)
    single, multi = [], []
    for t in range(readouts):
        light = texture(SPEED * t)
        acc_s += light
        acc_m += 6.0 * light
        s = np.minimum(np.floor(acc_s), 1)
        m = np.minimum(np.floor(acc_m), 7)
        acc_s -= s
        acc_m -= m
        single.append(s)
        multi.append(m)
    full = RmbChunk(single=np.array(single, np.uint8), multi=np.array(multi, np.uint8),
                    multi_rows=np.ones((readouts, H), bool), start=0, rate_hz=10_000.0)
    return full, RmbReadout(band=4, shift=2).apply(full)


def chunks_of(chunk: RmbChunk, size: int) -> list[RmbChunk]:
    return [RmbChunk(chunk.single[a:a + size], chunk.multi[a:a + size], chunk.multi_rows[a:a + size],
                     a, chunk.rate_hz) for a in range(0, len(chunk.single), size)]


def prelim_i_m(chunk: RmbChunk, upsampler, size: int) -> np.ndarray:
    prelim = PreliminaryFrames(n=10, upsampler=upsampler)
    frames = [f for c in chunks_of(chunk, size) for f in prelim.push(c)] + prelim.flush()
    return np.stack([f.i_m for f in frames])


def test_estimate_flow_recovers_translation_and_warp_aligns():
    a, b = texture(0.0), texture(3.0)
    for method in ("dis", "farneback", "tvl1"):
        flow = estimate_flow(a, b, method)
        inner = flow[8:-8, 8:-8]
        assert abs(float(np.median(inner[..., 0])) - 3.0) < 0.5, method
        assert abs(float(np.median(inner[..., 1]))) < 0.5, method
        assert np.abs(warp(b, flow) - a)[8:-8, 8:-8].mean() < 0.5 * np.abs(b - a)[8:-8, 8:-8].mean()


@pytest.mark.parametrize("height, width", [(1, 1), (1, 40), (2, 40), (8, 8), (11, 11), (12, 5)])
def test_dis_flow_takes_images_dis_refuses(height: int, width: int):
    """A tiny capture's binned frames are smaller than OpenCV's DIS accepts (it raised and the run ended in a
    traceback); padded with their edge pixels, they get a finite flow of their own size."""
    rng = np.random.default_rng(0)
    a8, b8 = (rng.integers(0, 256, (height, width), dtype=np.uint8) for _ in range(2))
    with pytest.raises(cv2.error):  # (an object that raised once may crash on its next call: a fresh one below)
        cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(a8, b8, None)
    flow = dis_flow(cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM), a8, b8)
    assert flow.shape == (height, width, 2) and flow.dtype == np.float32 and np.isfinite(flow).all()


@pytest.mark.parametrize("height, width, preset", [(12, 40, cv2.DISOPTICAL_FLOW_PRESET_MEDIUM),
                                                   (15, 200, cv2.DISOPTICAL_FLOW_PRESET_MEDIUM),
                                                   (24, 100, cv2.DISOPTICAL_FLOW_PRESET_FAST),
                                                   (31, 400, cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)])
def test_dis_flow_takes_strips_dis_crashes_on(height: int, width: int, preset: int):
    """Narrow strips on which OpenCV 5.0's DIS itself ends the process with a segmentation fault (measured; not
    called here) get a finite flow that follows a translation along the strip."""
    base = cv2.GaussianBlur(np.random.default_rng(5).random((height, width + 8)).astype(np.float32), (0, 0), 2.0)
    base = (base - base.min()) / (base.max() - base.min())
    a8, b8 = (np.round(255 * base[:, s : s + width]).astype(np.uint8) for s in (4, 2))  # b(x + 2) = a(x)
    flow = dis_flow(cv2.DISOpticalFlow_create(preset), a8, b8)
    assert flow.shape == (height, width, 2) and np.isfinite(flow).all()
    assert abs(float(np.median(flow[:, 8:-8, 0])) - 2.0) < 0.5


def test_dis_flow_is_dis_itself_from_its_minimum_size():
    a, b = texture(0.0), texture(3.0)
    a8, b8 = (np.clip(img * 255, 0, 255).astype(np.uint8) for img in (a[:DIS_MIN_SIZE, :50], b[:DIS_MIN_SIZE, :50]))
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    np.testing.assert_array_equal(dis_flow(dis, a8, b8), dis.calc(a8, b8, None))


def test_flow_upsampler_beats_flow_free_interpolation_on_translation():
    full, rmb = translating_stream(240)
    truth = prelim_i_m(full, TemporalInterpolation(), 240)
    flow_free = prelim_i_m(rmb, TemporalInterpolation(), 240)
    with_flow = prelim_i_m(rmb, FlowUpsampler(cycle=H // 2), 240)
    assert with_flow.shape == truth.shape == flow_free.shape
    assert np.isfinite(with_flow).all() and (with_flow >= 0).all()
    inner = (slice(2, -2), slice(6, -6), slice(6, -6))  # frames away from stream ends, no borders
    err_flow = np.abs(with_flow - truth)[inner].mean()
    err_free = np.abs(flow_free - truth)[inner].mean()
    assert err_flow < 0.8 * err_free, (err_flow, err_free)


def test_flow_upsampler_does_not_depend_on_chunk_size():
    _, rmb = translating_stream(130)
    whole = prelim_i_m(rmb, FlowUpsampler(cycle=H // 2), 130)
    for size in (1, 17):
        np.testing.assert_array_equal(prelim_i_m(rmb, FlowUpsampler(cycle=H // 2), size), whole)


@dataclass
class _Frame:
    i_s: np.ndarray
    i_m: np.ndarray


def test_align_warps_to_reference_and_caches_flow():
    frames = [_Frame(texture(2.0 * k) * 10, texture(2.0 * k) * 60) for k in range(3)]
    cache: dict = {}
    aligned = align(frames, 1, "dis", cache=cache, keys=[10, 11, 12])
    assert len(cache) == 2 and (11, 10, "dis") in cache
    ref = frames[1].i_s
    for (i_s, _), frame in zip(aligned, frames):
        before = np.abs(frame.i_s - ref)[8:-8, 8:-8].mean()
        after = np.abs(i_s - ref)[8:-8, 8:-8].mean()
        assert after <= 0.5 * before + 1e-6
    np.testing.assert_array_equal(aligned[1][0], frames[1].i_s)
    again = align(frames, 1, "dis", cache=cache, keys=[10, 11, 12])
    assert len(cache) == 2
    np.testing.assert_array_equal(again[0][1], aligned[0][1])


def test_unknown_method_is_refused():
    with pytest.raises(ValueError):
        estimate_flow(texture(0), texture(1), "spike2flow")
