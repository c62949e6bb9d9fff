"""Property-based tests: .dat round trip, binning invariants, readout designs (hypothesis)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rmbvideo.chunks import SpikeChunk
from rmbvideo.io.dat import DatGeometry, DatReader, write_dat
from rmbvideo.sensor.binning import MULTI_LEVEL, StreamBinner, bin_2x2x2, bin_packed
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def geometries(draw) -> DatGeometry:
    height = draw(st.integers(1, 24))
    width = draw(st.integers(2, 40).filter(lambda w: (w * height) % 8 == 0))
    header = draw(st.integers(0, width - 1))
    return DatGeometry(width, height, header_cols=header, flip=draw(st.booleans()))


def spikes(seed: int, shape: tuple[int, ...], rate: float) -> np.ndarray:
    return (np.random.default_rng(seed).random(shape) < rate).astype(np.uint8)


def split_points(draw, total: int) -> list[int]:
    cuts = draw(st.lists(st.integers(0, total), max_size=5))
    return sorted({0, total, *cuts})


@SETTINGS
@given(geometry=geometries(), planes=st.integers(1, 12), seed=st.integers(0, 2**16),
       rate=st.floats(0, 1), chunk=st.integers(1, 13))
def test_dat_round_trip_any_geometry_and_chunking(geometry: DatGeometry, planes: int, seed: int, rate: float,
                                                  chunk: int) -> None:
    data = spikes(seed, (planes, geometry.height, geometry.image_width), rate)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "c.dat"
        write_dat(path, data, geometry)
        assert path.stat().st_size == planes * geometry.plane_bytes
        reader = DatReader(path, geometry)
        assert reader.n_planes == planes and reader.trailing_bytes == 0
        np.testing.assert_array_equal(reader.read(), data)
        chunks = list(reader.chunks(chunk))
        assert [c.start for c in chunks] == list(range(0, planes, chunk))
        np.testing.assert_array_equal(np.concatenate([c.planes for c in chunks]), data)
        del reader, chunks  # release the memory map before the folder goes


@SETTINGS
@given(t=st.integers(1, 9), h=st.integers(1, 11), w=st.integers(1, 11), seed=st.integers(0, 2**16),
       rate=st.floats(0, 1), data=st.data())
def test_binning_invariants_and_chunk_independence(t: int, h: int, w: int, seed: int, rate: float, data) -> None:
    planes = spikes(seed, (t, h, w), rate)
    single, multi = bin_2x2x2(planes)
    assert single.shape == multi.shape == (t // 2, h // 2, w // 2)
    assert multi.max(initial=0) <= MULTI_LEVEL
    assert np.all(single <= multi) and np.all(single <= 1)
    p = planes[: t // 2 * 2, : h // 2 * 2, : w // 2 * 2].astype(int)
    counts = p.reshape(t // 2, 2, h // 2, 2, w // 2, 2).sum(axis=(1, 3, 5))
    np.testing.assert_array_equal(multi, np.minimum(counts, MULTI_LEVEL))
    # Streaming in any chunking gives the same readouts as binning the whole capture.
    binner = StreamBinner()
    parts = []
    cuts = split_points(data.draw, t)
    for a, b in zip(cuts, cuts[1:]):
        out = binner.push(SpikeChunk(planes[a:b], start=a, rate_hz=20000.0))
        if out is not None:
            parts.append(out)
    if parts:
        np.testing.assert_array_equal(np.concatenate([c.multi for c in parts]), multi)
        np.testing.assert_array_equal(np.concatenate([c.single for c in parts]), single)
        assert [c.start for c in parts] == sorted(c.start for c in parts)
    else:
        assert len(multi) == 0


@SETTINGS
@given(t=st.integers(2, 8), h=st.integers(2, 10), bytes_per_row=st.integers(1, 3), header_bytes=st.integers(0, 1),
       flip=st.booleans(), seed=st.integers(0, 2**16), rate=st.floats(0, 1))
def test_fused_binning_matches_reference(t: int, h: int, bytes_per_row: int, header_bytes: int, flip: bool,
                                         seed: int, rate: float) -> None:
    image_width = 8 * bytes_per_row
    stored = spikes(seed, (t, h, image_width + 8 * header_bytes), rate)
    packed = np.packbits(stored, axis=2, bitorder="little")
    image = stored[:, ::-1, :image_width] if flip else stored[:, :, :image_width]
    single, multi = bin_packed(packed, image_width, flip)
    ref_single, ref_multi = bin_2x2x2(image)
    np.testing.assert_array_equal(multi, ref_multi)
    np.testing.assert_array_equal(single, ref_single)


@SETTINGS
@given(height=st.integers(1, 40), band=st.integers(1, 8), shift=st.integers(1, 7), start=st.integers(0, 500),
       count=st.integers(1, 30), data=st.data())
def test_rmb_readout_band_rows_wrap_and_chunk_independence(height: int, band: int, shift: int, start: int,
                                                            count: int, data) -> None:
    design = RmbReadout(ReadoutMode.RMB, band=band, shift=shift)
    rows = design.multi_rows(start, count, height)
    assert rows.shape == (count, height)
    assert np.all(rows.sum(axis=1) == min(band, height))  # exactly `band` rows per readout
    for k in range(count):
        expected = ((start + k) * shift + np.arange(min(band, height))) % height  # wraps at the bottom
        assert set(np.flatnonzero(rows[k])) == set(expected.tolist())
        np.testing.assert_array_equal(np.sort(design.band_rows(start + k, height)), np.sort(expected))
    cuts = split_points(data.draw, count)
    pieces = [design.multi_rows(start + a, b - a, height) for a, b in zip(cuts, cuts[1:])]
    np.testing.assert_array_equal(np.concatenate(pieces), rows)


@SETTINGS
@given(height=st.integers(1, 30), start=st.integers(0, 100), count=st.integers(1, 20), band=st.integers(1, 6))
def test_pure_and_full_m_modes(height: int, start: int, count: int, band: int) -> None:
    assert not RmbReadout(ReadoutMode.PURE_S).multi_rows(start, count, height).any()
    assert RmbReadout(ReadoutMode.PURE_M).multi_rows(start, count, height).all()
    full = RmbReadout(ReadoutMode.FULL_M, band=band)
    rows = full.multi_rows(start, count, height)
    period = full.period(height)
    for k in range(count):
        assert rows[k].all() if (start + k) % period == 0 else not rows[k].any()
