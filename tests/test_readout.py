"""Readout designs: band positions, wrap-around, modes, data volume, chunk independence."""

from __future__ import annotations

import numpy as np
import pytest

from rmbvideo.chunks import RmbChunk
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout, data_volume


def _pure_m_chunk(t: int, h: int, w: int, start: int = 0, seed: int = 0) -> RmbChunk:
    rng = np.random.default_rng(seed)
    return RmbChunk(
        single=(rng.random((t, h, w)) < 0.5).astype(np.uint8),
        multi=rng.integers(0, 8, (t, h, w), dtype=np.uint8),
        multi_rows=np.ones((t, h), dtype=bool),
        start=start,
        rate_hz=10000.0,
    )


def test_band_rows_move_by_shift_and_wrap():
    readout = RmbReadout()
    assert readout.band_rows(0, 10).tolist() == [0, 1, 2, 3]
    assert readout.band_rows(1, 10).tolist() == [2, 3, 4, 5]
    assert readout.band_rows(4, 10).tolist() == [8, 9, 0, 1]  # wraps around the bottom
    assert readout.band_rows(5, 10).tolist() == [0, 1, 2, 3]  # one cycle = H / shift readouts


def test_rmb_mask_matches_band_rows_and_counts():
    readout = RmbReadout(band=4, shift=2)
    mask = readout.multi_rows(start=3, count=20, height=11)
    for k in range(20):
        assert sorted(np.flatnonzero(mask[k]).tolist()) == sorted(readout.band_rows(3 + k, 11).tolist())
    assert (mask.sum(axis=1) == 4).all()


def test_modes():
    h = 12
    assert not RmbReadout(ReadoutMode.PURE_S).multi_rows(0, 5, h).any()
    assert RmbReadout("pure-m").multi_rows(0, 5, h).all()
    full = RmbReadout("full-m", band=4).multi_rows(0, 10, h)  # default period round(12/4) = 3
    assert full.all(axis=1).tolist() == [k % 3 == 0 for k in range(10)]
    assert (full.any(axis=1) == full.all(axis=1)).all()  # whole planes only
    assert RmbReadout("full-m", full_m_period=4).multi_rows(2, 4, h).all(axis=1).tolist() == [False, False, True, False]
    with pytest.raises(ValueError):
        RmbReadout("half-m")


def test_apply_keeps_band_values_and_single_plane():
    chunk = _pure_m_chunk(8, 10, 5, start=2)
    out = RmbReadout().apply(chunk)
    assert np.array_equal(out.single, chunk.single)
    assert np.array_equal(out.multi_rows, RmbReadout().multi_rows(2, 8, 10))
    kept = out.multi_rows[:, :, None]
    assert np.array_equal(np.where(kept, chunk.multi, 0), out.multi)
    assert (out.multi[~out.multi_rows] == 0).all()
    assert out.start == 2 and out.rate_hz == chunk.rate_hz and out.raw_per_readout == 2


def test_apply_is_chunk_independent():
    whole = _pure_m_chunk(23, 9, 4)
    readout = RmbReadout(band=3, shift=2)
    expected = readout.apply(whole)
    for size in (1, 5):
        parts = [
            readout.apply(RmbChunk(whole.single[a:a + size], whole.multi[a:a + size], whole.multi_rows[a:a + size], a, 1e4))
            for a in range(0, 23, size)
        ]
        assert np.array_equal(np.concatenate([p.multi for p in parts]), expected.multi)
        assert np.array_equal(np.concatenate([p.multi_rows for p in parts]), expected.multi_rows)


def test_data_volume():
    assert data_volume(500, 4) == pytest.approx(1.016)
    assert data_volume(500, 4, mode="pure-s") == 1.0
    assert data_volume(500, 4, mode="pure-m") == 3.0
    assert data_volume(500, 4, mode="full-m") == pytest.approx(data_volume(500, 4))
    assert data_volume(500, 4, mode="full-m", full_m_period=50) == pytest.approx(1.04)


def test_measured_volume_matches_formula():
    h, readouts = 20, 100
    for mode in ReadoutMode:
        mask = RmbReadout(mode, band=4, shift=2).multi_rows(0, readouts, h)
        bits = (1 + 2 * mask).sum() / (h * readouts)  # 3 bits per multi-bit pixel, 1 otherwise
        assert bits == pytest.approx(data_volume(h, 4, 3, mode))
