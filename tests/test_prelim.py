"""Dense multi-bit upsampling by temporal interpolation, and preliminary frames I_s, I_m."""

from __future__ import annotations

import numpy as np
import pytest

from rmbvideo.chunks import RmbChunk
from rmbvideo.recon.prelim import PreliminaryFrames, TemporalInterpolation, centre_windows, select_centre
from rmbvideo.sensor.readout import RmbReadout


def _chunk(single, multi, rows, start=0, rate=10000.0):
    return RmbChunk(single=single, multi=multi, multi_rows=rows, start=start, rate_hz=rate)


def _split(chunk: RmbChunk, size: int) -> list[RmbChunk]:
    n = len(chunk.single)
    return [
        _chunk(chunk.single[a:a + size], chunk.multi[a:a + size], chunk.multi_rows[a:a + size], chunk.start + a)
        for a in range(0, n, size)
    ]


def _random_pure_m(t=60, h=10, w=6, seed=1, start=0):
    rng = np.random.default_rng(seed)
    single = (rng.random((t, h, w)) < 0.4).astype(np.uint8)
    multi = rng.integers(0, 8, (t, h, w), dtype=np.uint8)
    return _chunk(single, multi, np.ones((t, h), bool), start)


def _upsample(upsampler, chunks):
    dense = [d for c in chunks for d in upsampler.push(c)] + upsampler.flush()
    return (np.concatenate([d.multi for d in dense]), np.concatenate([d.multi_valid for d in dense]),
            [d.start for d in dense])


def test_interpolation_exact_on_a_ramp():
    t, h, w = 40, 8, 3
    ramp = np.broadcast_to(np.arange(t, dtype=np.uint8)[:, None, None], (t, h, w)).copy()
    chunk = RmbReadout(band=2, shift=1).apply(_chunk(np.zeros((t, h, w), np.uint8), ramp, np.ones((t, h), bool)))
    multi, valid, _ = _upsample(TemporalInterpolation(), [chunk])
    assert valid.all()
    for r in range(h):
        sampled = np.flatnonzero(chunk.multi_rows[:, r])
        first, last = sampled[0], sampled[-1]
        assert np.array_equal(multi[first:last + 1, r], ramp[first:last + 1, r].astype(np.float32))
        assert (multi[:first, r] == first).all() and (multi[last + 1:, r] == last).all()  # held at the ends


def test_interpolation_fractional_slope():
    rows = np.zeros((7, 1), bool)
    rows[[0, 3, 6], 0] = True
    multi = np.zeros((7, 1, 1), np.uint8)
    multi[[0, 3, 6], 0, 0] = [0, 7, 1]
    out, _, _ = _upsample(TemporalInterpolation(), [_chunk(np.zeros((7, 1, 1), np.uint8), multi, rows)])
    assert out[:, 0, 0] == pytest.approx([0, 7 / 3, 14 / 3, 7, 5, 3, 1], abs=1e-3)


def test_pure_m_is_identity_without_delay():
    chunk = _random_pure_m()
    up = TemporalInterpolation()
    first = up.push(_split(chunk, 5)[0])
    assert sum(len(d.single) for d in first) == 5  # nothing held back
    multi, valid, _ = _upsample(TemporalInterpolation(), [chunk])
    assert np.array_equal(multi, chunk.multi.astype(np.float32)) and valid.all()


def test_pure_s_is_zero_and_flagged():
    chunk = RmbReadout("pure-s").apply(_random_pure_m())
    multi, valid, _ = _upsample(TemporalInterpolation(max_gap=16), _split(chunk, 7))
    assert (multi == 0).all() and not valid.any()


def test_lookahead_is_bounded_by_max_gap():
    chunk = RmbReadout("pure-s").apply(_random_pure_m(t=60))
    up = TemporalInterpolation(max_gap=16)
    emitted = sum(len(d.single) for c in _split(chunk, 1) for d in up.push(c))
    assert emitted == 60 - 16


@pytest.mark.parametrize("size", [1, 7])
def test_interpolation_chunk_independent(size):
    chunk = RmbReadout(band=3, shift=2).apply(_random_pure_m(t=70, h=11))
    whole, valid_whole, _ = _upsample(TemporalInterpolation(), [chunk])
    parts, valid_parts, starts = _upsample(TemporalInterpolation(), _split(chunk, size))
    assert np.array_equal(whole, parts) and np.array_equal(valid_whole, valid_parts)
    assert starts == sorted(starts)


def test_measured_fast_path_hands_over_the_interpolation_state():
    """Pure-M readouts take a shortcut; a band readout after them must interpolate from the same held
    samples as when the whole stream goes through the general path."""
    full = _random_pure_m(t=80, h=11)
    band = RmbReadout(band=3, shift=2).apply(full)
    rows = band.multi_rows.copy()
    rows[:30] = True  # the first 30 readouts read every row: pure-M
    mixed = _chunk(full.single, full.multi, rows)
    whole, valid_whole, _ = _upsample(TemporalInterpolation(), [mixed])
    parts, valid_parts, _ = _upsample(TemporalInterpolation(), _split(mixed, 30))
    assert np.array_equal(whole, parts) and np.array_equal(valid_whole, valid_parts)
    assert np.array_equal(parts[:30], full.multi[:30].astype(np.float32))


def _frames(prelim, chunks):
    return [f for c in chunks for f in prelim.push(c)] + prelim.flush()


def test_preliminary_frames_sums_and_times():
    chunk = _random_pure_m(t=35)
    frames = _frames(PreliminaryFrames(n=10), [chunk])
    assert [f.index for f in frames] == [0, 1, 2]  # readouts 30..34 are an incomplete group: dropped
    assert frames[1].time_s == pytest.approx(15 / 10000.0)
    assert np.array_equal(frames[1].i_s, chunk.single[10:20].sum(0).astype(np.float32))
    assert np.array_equal(frames[1].i_m, chunk.multi[10:20].sum(0).astype(np.float32))
    assert frames[1].m_valid.all() and frames[1].i_s.dtype == np.float32


def test_preliminary_frames_align_to_file_start():
    chunk = _random_pure_m(t=40)
    late = _chunk(chunk.single[13:], chunk.multi[13:], chunk.multi_rows[13:], start=13)
    early = {f.index: f for f in _frames(PreliminaryFrames(n=10), [chunk])}
    later = _frames(PreliminaryFrames(n=10), [late])
    assert [f.index for f in later] == [2, 3]  # group 1 (readouts 10..19) starts before the data
    for f in later:
        assert np.array_equal(f.i_s, early[f.index].i_s) and f.time_s == early[f.index].time_s


@pytest.mark.parametrize("size", [1, 7])
def test_preliminary_frames_chunk_independent(size):
    chunk = RmbReadout().apply(_random_pure_m(t=73, h=9))
    whole = _frames(PreliminaryFrames(n=10), [chunk])
    parts = _frames(PreliminaryFrames(n=10), _split(chunk, size))
    assert len(whole) == len(parts) == 7
    for a, b in zip(whole, parts):
        assert a.index == b.index and a.time_s == b.time_s
        assert np.array_equal(a.i_s, b.i_s) and np.array_equal(a.i_m, b.i_m)
        assert np.array_equal(a.m_valid, b.m_valid)


def test_preliminary_frames_pure_s_flags_rows():
    frames = _frames(PreliminaryFrames(n=10, upsampler=TemporalInterpolation(max_gap=8)),
                     [RmbReadout("pure-s").apply(_random_pure_m(t=30))])
    assert len(frames) == 3 and all((f.i_m == 0).all() and not f.m_valid.any() for f in frames)
    assert all(f.i_s.sum() > 0 for f in frames)


def test_centre_sums_are_the_central_readouts_whatever_the_chunking():
    data = _random_pure_m(t=60)
    whole = PreliminaryFrames(n=10)
    frames = whole.push(data) + whole.flush()
    assert centre_windows(10) == (2, 4, 6) and centre_windows(5) == () and centre_windows(8) == (2, 4, 6)
    for frame in frames:
        first = frame.index * 10
        for c, k in enumerate(centre_windows(10)):
            lo = first + (10 - k) // 2
            expected = data.multi[lo:lo + k].astype(np.float64).sum(axis=0)
            assert np.array_equal(frame.i_c[c], expected.astype(np.float32)), (frame.index, k)
    for size in (1, 3, 7):
        prelim = PreliminaryFrames(n=10)
        split = [f for c in _split(data, size) for f in prelim.push(c)] + prelim.flush()
        assert all(np.array_equal(a.i_c, b.i_c) for a, b in zip(frames, split)) and len(split) == len(frames)


def test_select_centre_picks_channels_and_names_what_is_missing():
    i_c = np.arange(3 * 2 * 2, dtype=np.float32).reshape(3, 2, 2)
    assert np.array_equal(select_centre(i_c, 10, (6, 2)), i_c[[2, 0]])
    with pytest.raises(ValueError, match="central sums over \\[4\\]"):
        select_centre(None, 10, (4,))
    with pytest.raises(ValueError, match="carry \\[\\]"):
        select_centre(np.zeros((0, 2, 2), np.float32), 5, (2,))


@pytest.mark.parametrize("size", [1, 4, 64])
def test_measured_and_upsampled_readouts_in_one_frame_sum_exactly(size):
    """An RMB stream mixes readouts whose rows were all measured (summed through one float32 running sum, exact for
    whole counts) with upsampled ones (float64 sums): every frame's sums are the float64 sums of its dense values."""
    data = _random_pure_m(t=80, h=12, w=5, seed=4)
    rmb = RmbReadout("rmb", band=4, shift=2).apply(data)
    rows = rmb.multi_rows.copy()
    rows[20:40] = True  # two frames measured throughout, the rest in the band
    mixed = _chunk(data.single, np.where(rows[:, :, None], data.multi, 0).astype(np.uint8), rows)
    dense, _, _ = _upsample(TemporalInterpolation(), _split(mixed, size))
    prelim = PreliminaryFrames(n=10)
    frames = [f for c in _split(mixed, size) for f in prelim.push(c)] + prelim.flush()
    assert [f.index for f in frames] == list(range(8))
    for frame in frames:
        block = dense[10 * frame.index : 10 * frame.index + 10].astype(np.float64)
        assert np.array_equal(frame.i_m, block.sum(axis=0).astype(np.float32))
        for c, k in enumerate(centre_windows(10)):
            lo = (10 - k) // 2
            assert np.array_equal(frame.i_c[c], block[lo : lo + k].sum(axis=0).astype(np.float32))
