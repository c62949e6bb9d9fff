"""2x2x2 binning: plain and fused paths against a per-bin Python reference, and streaming."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rmbvideo.chunks import SpikeChunk
from rmbvideo.sensor.binning import MULTI_LEVEL, StreamBinner, bin_2x2x2, bin_packed
from rmbvideo.sensor.compiled import COMPILED

#: both paths of ``bin_packed``: numpy everywhere, the compiled kernel where the install built it
PATHS = [
    pytest.param(False, id="numpy"),
    pytest.param(True, id="compiled", marks=pytest.mark.skipif(not COMPILED, reason="no compiled kernel built")),
]


def reference_bin(planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-bin loops straight from the definition: count clamped to 7, keep the top-left pixel of plane 2t."""
    t2, h2, w2 = (n // 2 for n in planes.shape)
    single = np.zeros((t2, h2, w2), np.uint8)
    multi = np.zeros((t2, h2, w2), np.uint8)
    for t in range(t2):
        for i in range(h2):
            for j in range(w2):
                count = sum(int(planes[2 * t + dt, 2 * i + di, 2 * j + dj]) for dt in (0, 1) for di in (0, 1) for dj in (0, 1))
                multi[t, i, j] = min(count, 7)
                single[t, i, j] = planes[2 * t, 2 * i, 2 * j]
    return single, multi


def pack_stored(planes: np.ndarray, header_cols: int, flip: bool) -> np.ndarray:
    """Pack image-orientation planes as a .dat stores them: (T, H, row_bytes), LSB first, zero header."""
    t, h, w = planes.shape
    stored = np.zeros((t, h, w + header_cols), np.uint8)
    stored[:, :, :w] = planes[:, ::-1] if flip else planes
    return np.packbits(stored.reshape(t, h * (w + header_cols)), axis=1, bitorder="little").reshape(t, h, (w + header_cols) // 8)


def random_planes(rng: np.random.Generator, shape: tuple[int, int, int], rate: float) -> np.ndarray:
    return (rng.random(shape) < rate).astype(np.uint8)


@pytest.mark.parametrize("shape", [(4, 4, 4), (5, 7, 9), (6, 3, 10), (1, 4, 4), (3, 1, 6), (8, 6, 2)])
@pytest.mark.parametrize("rate", [0.3, 0.9])
def test_plain_binning_matches_reference(shape: tuple[int, int, int], rate: float) -> None:
    planes = random_planes(np.random.default_rng(sum(shape)), shape, rate)
    single, multi = bin_2x2x2(planes)
    ref_single, ref_multi = reference_bin(planes)
    assert single.shape == ref_single.shape == tuple(n // 2 for n in shape)
    np.testing.assert_array_equal(single, ref_single)
    np.testing.assert_array_equal(multi, ref_multi)
    assert single.dtype == multi.dtype == np.uint8


def test_full_bins_clamp_to_seven_and_empty_bins_are_zero() -> None:
    planes = np.zeros((4, 4, 4), np.uint8)
    planes[:2] = 1
    single, multi = bin_2x2x2(planes)
    assert (multi[0] == MULTI_LEVEL).all() and (multi[1] == 0).all()
    assert (single[0] == 1).all() and (single[1] == 0).all()


def test_kept_pixel_is_top_left_of_first_plane() -> None:
    planes = np.zeros((2, 2, 2), np.uint8)
    planes[0, 0, 0] = 1
    assert bin_2x2x2(planes)[0][0, 0, 0] == 1
    for other in [(1, 0, 0), (0, 1, 0), (0, 0, 1)]:
        planes = np.zeros((2, 2, 2), np.uint8)
        planes[other] = 1
        single, multi = bin_2x2x2(planes)
        assert single[0, 0, 0] == 0 and multi[0, 0, 0] == 1


@pytest.mark.parametrize(
    "shape,header_cols,flip",
    [
        ((6, 8, 16), 0, True),
        ((7, 9, 24), 0, True),  # odd T and odd H with a flip: stored row 0 is dropped
        ((7, 9, 24), 0, False),
        ((4, 5, 8), 16, True),  # header columns after the image
        ((2, 1, 8), 0, True),  # a single row: no bins
        ((1, 4, 8), 0, True),  # a single plane: no readouts
        ((130, 6, 40), 0, True),  # two whole 64-plane blocks (uint64 words) and a last pair of 60 bytes (uint8)
        ((131, 7, 40), 8, False),
    ],
)
@pytest.mark.parametrize("rate", [0.05, 0.5, 0.97])
@pytest.mark.parametrize("compiled", PATHS)
def test_fused_path_is_bit_exact(shape: tuple[int, int, int], header_cols: int, flip: bool, rate: float,
                                 compiled: bool) -> None:
    planes = random_planes(np.random.default_rng(shape[0] * 100 + shape[1]), shape, rate)
    single, multi = bin_packed(pack_stored(planes, header_cols, flip), shape[2], flip, compiled=compiled)
    ref_single, ref_multi = reference_bin(planes)
    assert single.shape == ref_single.shape and multi.shape == ref_multi.shape
    np.testing.assert_array_equal(single, ref_single)
    np.testing.assert_array_equal(multi, ref_multi)


@pytest.mark.parametrize("flip", [True, False])
@pytest.mark.parametrize("compiled", PATHS)
def test_fused_path_every_bin_pattern_at_every_byte_position(flip: bool, compiled: bool) -> None:
    """All 256 patterns of a bin's 8 bits, each in all four bins of a stored byte (the SWAR lanes)."""
    patterns = np.repeat(np.arange(256, dtype=np.uint8), 4)  # bin k holds pattern k // 4, lane k % 4
    bits = np.unpackbits(patterns[:, None], axis=1, bitorder="little").reshape(-1, 2, 2, 2)  # (bin, t, i, j)
    planes = bits.transpose(1, 2, 0, 3).reshape(2, 2, 2 * len(patterns))
    single, multi = bin_packed(pack_stored(planes, 0, flip), planes.shape[2], flip, compiled=compiled)
    np.testing.assert_array_equal(multi[0, 0], np.minimum(bits.sum(axis=(1, 2, 3)), MULTI_LEVEL))
    np.testing.assert_array_equal(single[0, 0], bits[:, 0, 0, 0])


@pytest.mark.parametrize("compiled", PATHS)
def test_fused_path_spans_several_blocks(compiled: bool) -> None:
    planes = random_planes(np.random.default_rng(7), (133, 10, 64), 0.4)  # > 2 fused blocks, odd T
    fused = bin_packed(pack_stored(planes, 0, True), 64, True, compiled=compiled)
    plain = bin_2x2x2(planes)
    np.testing.assert_array_equal(fused[0], plain[0])
    np.testing.assert_array_equal(fused[1], plain[1])


def test_fused_path_rejects_unaligned_width() -> None:
    with pytest.raises(ValueError):
        bin_packed(np.zeros((2, 4, 2), np.uint8), 12, True)


@pytest.mark.parametrize("compiled", PATHS)
def test_fused_path_reads_strided_input_and_fills_a_reused_output(compiled: bool) -> None:
    """A non-contiguous view (every other stored plane) and an ``out`` holding an earlier chunk's bins."""
    planes = random_planes(np.random.default_rng(9), (12, 6, 16), 0.5)
    stored = pack_stored(planes, 8, True)
    out = np.full((2, 3, 3, 8), 255, np.uint8)
    single, multi = bin_packed(stored[::2], 16, True, out=out, compiled=compiled)
    ref_single, ref_multi = reference_bin(planes[::2])
    np.testing.assert_array_equal(single, ref_single)
    np.testing.assert_array_equal(multi, ref_multi)
    assert single.base is out or np.shares_memory(single, out)


@pytest.mark.skipif(not COMPILED, reason="no compiled kernel built")
def test_compiled_kernel_rejects_buffers_that_do_not_fit_the_geometry() -> None:
    """The kernel checks sizes itself: a wrong call is a ValueError, never a write out of bounds."""
    from rmbvideo.sensor import _packed

    packed = np.zeros((4, 6, 3), np.uint8)
    single, multi = np.zeros((2, 3, 8), np.uint8), np.zeros((2, 3, 8), np.uint8)
    _packed.bin_packed(packed, single, multi, 4, 6, 3, 2, 0, True)  # fits
    with pytest.raises(ValueError, match="sizes"):
        _packed.bin_packed(packed, single[:1], multi, 4, 6, 3, 2, 0, True)
    with pytest.raises(ValueError, match="sizes"):
        _packed.bin_packed(packed[:2], single, multi, 4, 6, 3, 2, 0, True)
    with pytest.raises(ValueError, match="geometry"):
        _packed.bin_packed(packed, single, multi, 3, 6, 3, 2, 0, True)
    with pytest.raises((TypeError, ValueError)):  # a strided view: the kernel takes contiguous buffers only
        _packed.bin_packed(packed, np.zeros((2, 3, 16), np.uint8)[:, :, ::2], multi, 4, 6, 3, 2, 0, True)


@settings(max_examples=40, deadline=None)
@given(
    t=st.integers(0, 9),
    h=st.integers(1, 9),
    w_bytes=st.integers(1, 3),
    header_bytes=st.integers(0, 2),
    flip=st.booleans(),
    seed=st.integers(0, 2**16),
    compiled=st.sampled_from([False, True] if COMPILED else [False]),
)
def test_fused_equals_plain_property(t: int, h: int, w_bytes: int, header_bytes: int, flip: bool, seed: int,
                                     compiled: bool) -> None:
    planes = random_planes(np.random.default_rng(seed), (t, h, 8 * w_bytes), 0.5)
    fused = bin_packed(pack_stored(planes, 8 * header_bytes, flip), 8 * w_bytes, flip, compiled=compiled)
    plain = bin_2x2x2(planes)
    np.testing.assert_array_equal(fused[0], plain[0])
    np.testing.assert_array_equal(fused[1], plain[1])


def _stream(planes: np.ndarray, sizes: list[int], start: int = 0) -> tuple[list, StreamBinner]:
    binner = StreamBinner()
    out = []
    s = 0
    for size in sizes:
        chunk = SpikeChunk(planes=planes[s : s + size], start=start + s, rate_hz=20000.0)
        s += size
        result = binner.push(chunk)
        if result is not None:
            out.append(result)
    return out, binner


@pytest.mark.parametrize("sizes", [[11], [1] * 11, [3, 3, 5], [2, 1, 1, 7], [5, 0, 6]])
def test_stream_binner_is_independent_of_chunking(sizes: list[int]) -> None:
    planes = random_planes(np.random.default_rng(3), (11, 6, 10), 0.5)
    whole_single, whole_multi = bin_2x2x2(planes)
    out, binner = _stream(planes, sizes, start=40)
    np.testing.assert_array_equal(np.concatenate([c.single for c in out]), whole_single)
    np.testing.assert_array_equal(np.concatenate([c.multi for c in out]), whole_multi)
    assert [c.start for c in out] == list(np.cumsum([0] + [len(c.single) for c in out[:-1]]) + 20)
    assert binner.pending_planes == 1  # the 11th plane waits for a pair that never comes
    first = out[0]
    assert first.rate_hz == 10000.0 and first.level == 7 and first.raw_per_readout == 2
    assert first.multi_rows.shape == first.single.shape[:2] and first.multi_rows.all()


def test_stream_binner_rejects_odd_start_and_gaps() -> None:
    planes = np.zeros((4, 2, 2), np.uint8)
    with pytest.raises(ValueError):
        StreamBinner().push(SpikeChunk(planes, start=3, rate_hz=1.0))
    binner = StreamBinner()
    binner.push(SpikeChunk(planes, start=0, rate_hz=1.0))
    with pytest.raises(ValueError):
        binner.push(SpikeChunk(planes, start=6, rate_hz=1.0))


@pytest.mark.parametrize("sizes", [[11], [1] * 11, [3, 3, 5], [2, 1, 1, 7]])
@pytest.mark.parametrize("flip", [True, False])
def test_stream_binner_bins_stored_bytes_as_it_bins_decoded_planes(sizes: list[int], flip: bool) -> None:
    """``push_stored`` (planes as a .dat stores them, header columns and all) gives ``push``'s readouts, carried
    planes included; a stream does not mix the two kinds."""
    planes = random_planes(np.random.default_rng(4), (11, 7, 16), 0.4)
    stored = pack_stored(planes, header_cols=8, flip=flip).reshape(11, -1)
    decoded, _ = _stream(planes, sizes, start=40)
    binner, out, s = StreamBinner(), [], 0
    for size in sizes:
        result = binner.push_stored(stored[s : s + size], 40 + s, 20000.0, height=7, image_width=16, flip=flip)
        s += size
        if result is not None:
            out.append(result)
    assert [c.start for c in out] == [c.start for c in decoded] and binner.pending_planes == 1
    for a, b in zip(out, decoded):
        np.testing.assert_array_equal(a.single, b.single)
        np.testing.assert_array_equal(a.multi, b.multi)
    with pytest.raises(ValueError, match="one kind"):
        binner.push(SpikeChunk(planes[:2], start=51, rate_hz=20000.0))


@pytest.mark.skipif(not COMPILED, reason="no compiled kernel built")
def test_a_build_of_another_version_is_not_used(monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """A kernel built from older sources (a tree updated without reinstalling) falls back to numpy, with a warning."""
    from rmbvideo.sensor import _packed, compiled

    assert compiled._load() is _packed
    monkeypatch.setattr(_packed, "VERSION", compiled.KERNELS_VERSION + 1)
    with caplog.at_level("WARNING"):
        assert compiled._load() is None
    assert "reinstall" in caplog.text
