"""Classical reconstructions (TFP, TFI, TFW): values, frame schedule, finiteness, chunk independence."""

from __future__ import annotations

import numpy as np
import pytest

from rmbvideo.chunks import RmbChunk, SpikeChunk
from rmbvideo.recon.classical import BlockScans, Tfi, Tfp, Tfw, push_by_block, tfw_l, tfw_s
from rmbvideo.sensor.compiled import COMPILED
from rmbvideo.sensor.readout import RmbReadout

RATE = 20000.0


def _spikes(planes: np.ndarray, size: int, start: int = 0) -> list[SpikeChunk]:
    return [SpikeChunk(planes[a:a + size], start + a, RATE) for a in range(0, len(planes), size)]


def _rmb(chunk: RmbChunk, size: int) -> list[RmbChunk]:
    n = len(chunk.single)
    return [
        RmbChunk(chunk.single[a:a + size], chunk.multi[a:a + size], chunk.multi_rows[a:a + size],
                 chunk.start + a, chunk.rate_hz)
        for a in range(0, n, size)
    ]


def _run(rec, chunks):
    return [f for c in chunks for f in rec.push(c)] + rec.flush()


def _same(a, b):
    assert [f.index for f in a] == [f.index for f in b]
    assert [f.time_s for f in a] == [f.time_s for f in b]
    for x, y in zip(a, b):
        assert np.array_equal(x.image, y.image)


def _random_planes(t=157, h=6, w=7, seed=3):
    rng = np.random.default_rng(seed)
    rate = rng.uniform(0.01, 0.9, (h, w))
    return (rng.random((t, h, w)) < rate).astype(np.uint8)


@pytest.mark.parametrize("factory", [Tfp, lambda: Tfp(window=7, step=3), Tfi, lambda: Tfi(step=3, max_reach=5),
                                     lambda: Tfi(step=3, max_reach=5, window=7), lambda: Tfi(window=30)])
@pytest.mark.parametrize("start", [0, 5])
def test_spike_methods_chunk_independent(factory, start):
    planes = _random_planes()
    whole = _run(factory(), _spikes(planes, len(planes), start))
    assert whole
    for size in (1, 13):
        _same(whole, _run(factory(), _spikes(planes, size, start)))


def _random_rmb(t=90, h=9, w=5, seed=4) -> RmbChunk:
    rng = np.random.default_rng(seed)
    chunk = RmbChunk(
        single=(rng.random((t, h, w)) < 0.3).astype(np.uint8),
        multi=rng.integers(0, 8, (t, h, w), dtype=np.uint8),
        multi_rows=np.ones((t, h), bool),
        start=0,
        rate_hz=RATE / 2,
    )
    return RmbReadout().apply(chunk)


@pytest.mark.parametrize(("factory", "count"), [(tfw_s, 9), (tfw_l, 9), (lambda: Tfw(window=3, step=4), 22)])
def test_tfw_chunk_independent(factory, count):
    chunk = _random_rmb()
    whole = _run(factory(), [chunk])
    assert len(whole) == count  # centres step/2 + i*step inside 90 readouts
    for size in (1, 11):
        _same(whole, _run(factory(), _rmb(chunk, size)))


def test_frame_schedule_and_clipping():
    planes = np.ones((100, 2, 2), np.uint8)
    frames = _run(Tfp(window=41, step=20), _spikes(planes, 100))
    assert [f.index for f in frames] == [0, 1, 2, 3, 4]  # centres 10, 30, ..., 90 lie in the data
    assert [f.time_s for f in frames] == pytest.approx([(20 * i + 10) / RATE for i in range(5)])
    late = _run(Tfp(window=41, step=20), _spikes(planes[25:], 75, start=25))
    assert [f.index for f in late] == [1, 2, 3, 4]  # frame 0 (centre 10) precedes the data
    assert all((f.image == 1).all() for f in frames + late)  # clipped windows are not diluted


def test_tfp_constant_rate():
    planes = np.zeros((200, 3, 4), np.uint8)
    planes[::4] = 1  # one spike every 4 planes: 0.25 spikes per plane
    planes[:, 0, 0] = 0
    frames = _run(Tfp(window=40, step=20), _spikes(planes, 64))
    for f in frames[1:-1]:  # full windows of 40 planes
        assert f.image[0, 0] == 0 and np.allclose(f.image.ravel()[1:], 0.25)
        assert f.image.dtype == np.float32


def test_tfi_regular_spikes_give_the_rate():
    planes = np.zeros((120, 2, 3), np.uint8)
    planes[2::5] = 1
    frames = _run(Tfi(step=10, max_reach=20), _spikes(planes, 9))
    assert all(np.allclose(f.image, 0.2) for f in frames[1:])


def test_tfi_finite_on_dark_and_single_spike():
    dark = np.zeros((80, 4, 4), np.uint8)
    frames = _run(Tfi(step=10, max_reach=8), _spikes(dark, 80))
    assert len(frames) == 8
    for f in frames:
        assert np.isfinite(f.image).all() and (f.image > 0).all()
    assert np.allclose(frames[4].image, 1 / 17)  # 2 * max_reach + 1 with no spike on either side
    single = dark.copy()
    single[40, 1, 2] = 1
    frames = _run(Tfi(step=10, max_reach=100), _spikes(single, 7))
    for f in frames:
        assert np.isfinite(f.image).all() and (f.image > 0).all() and f.image.max() <= 1
    assert frames[4].image[1, 2] == pytest.approx(1 / (80 - 40))  # next bounded by the end of data


@pytest.mark.parametrize("chunk", [9, 64, 1000])
def test_tfi_shorter_reaches_are_exactly_the_shorter_searches(chunk):
    """One search over the longest reach gives every shorter one's frames bit for bit, the clip's edges included."""
    rng = np.random.default_rng(4)
    rates = rng.uniform(0.0, 0.2, (5, 6))
    rates[0] = 0.0  # never fires
    planes = (rng.random((430, 5, 6)) < rates).astype(np.uint8)
    shared = _run(Tfi(step=20, max_reach=200, shorter=(7, 40)), _spikes(planes, chunk))
    alone = [_run(Tfi(step=20, max_reach=reach), _spikes(planes, chunk)) for reach in (7, 40, 200)]
    assert len(shared) == len(alone[0]) >= 20
    for k, frame in enumerate(shared):
        assert frame.image.shape == (3, 5, 6)
        for plane, frames in zip(frame.image, alone):
            assert frames[k].index == frame.index and np.array_equal(plane, frames[k].image)
    with pytest.raises(ValueError, match="shorter"):
        Tfi(step=20, max_reach=40, shorter=(40,))


def test_tfw_pools_single_and_multi():
    t, h, w = 40, 4, 3
    single = np.zeros((t, h, w), np.uint8)
    single[::2] = 1  # 0.5 per raw pixel-plane
    multi = np.full((t, h, w), 4, np.uint8)  # 4 of 8 pixel-planes per bin
    chunk = RmbChunk(single, multi, np.ones((t, h), bool), 0, RATE / 2)
    frames = _run(Tfw(window=10), [chunk])
    assert len(frames) == 4 and all(np.allclose(f.image, 0.5) for f in frames)
    assert frames[0].time_s == pytest.approx(10 / RATE)  # same time as TFP frame 0 on raw planes
    multi[:] = 7
    pure_s = RmbReadout("pure-s").apply(RmbChunk(single, multi, np.ones((t, h), bool), 0, RATE / 2))
    frames = _run(Tfw(window=10), [pure_s])
    assert all(np.allclose(f.image, 0.5) for f in frames)  # 1-bit evidence only


def test_tfw_on_every_bin_count_is_tfp_of_the_raw_capture():
    """Pure-M binned data: the 1-bit value is one of its bin's 8 trials, so TFW uses the counts alone,
    and equals TFP over the same raw planes, 2x2-averaged, exactly."""
    from rmbvideo.sensor.binning import bin_2x2x2

    rng = np.random.default_rng(5)
    planes = (rng.random((80, 8, 10)) < rng.uniform(0.01, 0.4, (8, 10))).astype(np.uint8)
    single, multi = bin_2x2x2(planes)
    assert planes.reshape(40, 2, 4, 2, 5, 2).sum(axis=(1, 3, 5)).max() < 8  # no bin clamped at level 7
    chunk = RmbChunk(single, multi, np.ones(single.shape[:2], bool), 0, RATE / 2)
    tfw = _run(Tfw(window=10), [chunk])
    tfp = _run(Tfp(window=20, step=20), _spikes(planes, 80))
    assert len(tfw) == len(tfp) == 4
    for a, b in zip(tfw, tfp):
        assert a.time_s == pytest.approx(b.time_s)
        assert np.allclose(a.image, b.image.reshape(4, 2, 5, 2).mean(axis=(1, 3)), atol=1e-6)
    rmb = _run(Tfw(window=10), [RmbReadout("rmb", band=1, shift=1).apply(chunk)])  # a band: pooled as before
    assert not np.allclose(rmb[1].image, tfw[1].image)


def test_tfp_matches_ground_truth(shared_data):
    from rmbvideo.io.dat import DatReader

    stem = shared_data / "spikezoo-base" / "200_part3_key_id151"
    if not stem.with_suffix(".dat").exists():
        pytest.skip("spikezoo sample not present")
    import cv2

    truth = cv2.imread(str(stem.with_suffix(".png")), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    reader = DatReader(stem.with_suffix(".dat"))
    frames = _run(Tfp(window=41, step=1), reader.chunks(16, 120, 181))
    frame = next(f for f in frames if f.index == 150)
    assert frame.time_s == pytest.approx(150.5 / reader.rate_hz)
    x = frame.image.astype(np.float64)
    scale = (x * truth).sum() / (x * x).sum()
    mse = ((scale * x - truth) ** 2).mean()
    psnr = 10 * np.log10(255.0**2 / mse)
    assert psnr >= 28.0


def _tfi_m_reference(planes: np.ndarray, start: int, step: int, reach: int, window: int) -> dict[int, np.ndarray]:
    """TFI-M written out per pixel as its docstring says, on the whole data (planes start..start+T-1)."""
    end = start + len(planes)
    out = {}
    for i in range(max(0, start // step - 1), start // step + 1000):
        centre2 = (2 * i + 1) * step
        if centre2 < 2 * start:
            continue
        if centre2 >= 2 * end:
            break
        p = (centre2 - window + 1) // 2 - 1  # the central planes p+1..p+window: TFP's window
        image = np.empty(planes.shape[1:], np.float32)
        for y, x in np.ndindex(*planes.shape[1:]):
            times = start + np.flatnonzero(planes[:, y, x])
            before = times[(times <= p) & (times >= p - reach + 1)]
            after = times[(times > p + window) & (times <= p + window + reach)]
            prev = before.max() if len(before) else max(p - reach + 1, start) - 1
            nxt = after.min() if len(after) else min(p + window + reach, end - 1) + 1
            central = ((times > p) & (times <= p + window)).sum()
            image[y, x] = (central + 1) / max(nxt - prev, 1)
        out[i] = image
    return out


@pytest.mark.parametrize("window", [0, 1, 6, 9, 40])
@pytest.mark.parametrize("start", [0, 7])
def test_tfi_window_counts_the_spikes_between_the_spikes_around_the_central_planes(window, start):
    """TFI-M, per pixel: (spikes in the central planes + 1) / (first spike after them - last spike before them),
    every chunking, the data's edges and the reach's bounds included; window 0 is plain TFI."""
    planes = _random_planes(t=143, h=3, w=4, seed=window)
    planes[:, 0, 0] = 0  # never fires: the bounds stand in for both spikes
    expected = _tfi_m_reference(planes, start, step=11, reach=13, window=window)
    for size in (1, 17, len(planes)):
        frames = _run(Tfi(step=11, max_reach=13, window=window), _spikes(planes, size, start))
        assert [f.index for f in frames] == sorted(expected)
        for f in frames:
            assert np.array_equal(f.image, expected[f.index]), (size, f.index)
    if window == 0:
        _same(_run(Tfi(step=11, max_reach=13), _spikes(planes, 17, start)),
              _run(Tfi(step=11, max_reach=13, window=0), _spikes(planes, 17, start)))


@pytest.mark.parametrize("window, start", [(0, 2**31 - 60), (6, 2**31 - 60), (254, 0)])
def test_tfi_plane_numbers_and_counts_hold_at_the_limits_of_their_types(window, start):
    """The search keeps plane numbers in int32 and counts in the narrowest type that holds window + 1: past 2**31
    planes (30 hours at 20 kHz) its plane numbers widen mid-stream, and a pixel firing at every one of 254 central
    planes fills uint8 with the + 1; each gives the reference's frames bit for bit."""
    planes = _random_planes(t=143 if window < 200 else 600, h=3, w=4, seed=5)
    planes[:, 1, 1] = 1  # fires every plane
    expected = _tfi_m_reference(planes, start, step=11, reach=13, window=window)
    frames = _run(Tfi(step=11, max_reach=13, window=window), _spikes(planes, 17, start))
    assert [f.index for f in frames] == sorted(expected)
    for f in frames:
        assert np.array_equal(f.image, expected[f.index]), f.index


@pytest.mark.parametrize("window", [0, 4, 16])
@pytest.mark.parametrize("method", ["tfi", "tfp"])
def test_tfi_and_tfp_frames_are_centred_on_the_frame_time(method, window):
    """Played backwards about a frame's centre (the data ending at twice its time), a centred method reads the same
    planes, so the frame is unchanged: TFI-M's central planes are TFP's window of M planes, and plain TFI's
    interval straddles the frame time, neither a plane late."""
    if method == "tfp" and window == 0:
        window = 2  # (an odd window cannot be centred on a frame time between two planes)
    step, frame = 20, 3
    planes = _random_planes(t=(2 * frame + 1) * step, h=4, w=5, seed=11)
    make = (lambda: Tfi(step=step, max_reach=50, window=window)) if method == "tfi" else (
        lambda: Tfp(window=window, step=step))
    forward, backward = (next(f for f in _run(make(), _spikes(data, 32)) if f.index == frame)
                         for data in (planes, planes[::-1].copy()))
    assert np.array_equal(forward.image, backward.image)
    later = next(f for f in _run(make(), _spikes(planes[1:], 32)) if f.index == frame)  # one plane later
    assert not np.array_equal(forward.image, later.image)


@pytest.mark.parametrize("size", [1, 50, 143])
def test_tfi_windows_sharing_block_scans_give_their_own_frames_and_scan_each_block_once(size):
    """TFI searches of other windows and reaches fed the same chunks block by block read one ``BlockScans``: each
    gives the reference's frames bit for bit, and every block of planes is scanned once between them."""
    planes = _random_planes(t=143, h=3, w=4, seed=3)
    planes[:, 0, 0] = 0
    scans = BlockScans()
    searches = [Tfi(step=11, max_reach=13, window=w, scans=scans) for w in (0, 4, 9)]
    searches.append(Tfi(step=11, max_reach=30, shorter=(13,), window=4, scans=scans))
    frames = [[] for _ in searches]
    for chunk in _spikes(planes, size, 7):
        for out, new in zip(frames, push_by_block(searches, chunk)):
            out += new
        scans.clear()
    for out, tfi in zip(frames, searches):
        out += tfi.flush()
    for window, out in zip((0, 4, 9), frames):
        expected = _tfi_m_reference(planes, 7, step=11, reach=13, window=window)
        assert [f.index for f in out] == sorted(expected)
        assert all(np.array_equal(f.image, expected[f.index]) for f in out)
    _same(frames[3], _run(Tfi(step=11, max_reach=30, shorter=(13,), window=4), _spikes(planes, size, 7)))
    blocks = sum(-(-len(c.planes) // 64) for c in _spikes(planes, size, 7))
    assert scans.computed == blocks


def test_tfi_window_reads_a_regular_pixel_exactly_where_one_interval_cannot():
    """A noise-free rate-convention pixel at 0.4 spikes a plane: single intervals read 1/2 or 1/3, the spikes over
    the whole intervals covering 10 central planes read 0.4 to within one spike over their 12-13 planes (5/13 or
    5/12), whatever its phase."""
    light, planes = 0.4, np.zeros((300, 1, 5), np.uint8)
    for x, phase in enumerate(np.linspace(0.0, 0.9, 5)):
        charge = phase + light * np.arange(1, 301)
        planes[:, 0, x] = np.diff(np.floor(np.concatenate([[phase], charge]))).astype(np.uint8)
    single = np.stack([f.image for f in _run(Tfi(step=20, max_reach=50), _spikes(planes, 64))[3:-3]])
    wide = np.stack([f.image for f in _run(Tfi(step=20, max_reach=50, window=10), _spikes(planes, 64))[3:-3]])
    assert (np.isclose(single, 1 / 2) | np.isclose(single, 1 / 3)).all()
    assert np.abs(wide - light).max() <= light / 24 + 1e-6 < np.abs(single - light).max() / 4
    with pytest.raises(ValueError, match="window"):
        Tfi(window=-1)


@pytest.mark.skipif(not COMPILED, reason="no compiled kernel built")
@pytest.mark.parametrize("count", [1, 2, 63, 64, 255])
@pytest.mark.parametrize("dtype", [np.uint8, np.bool_])
def test_tfi_block_scan_kernel_gives_the_numpy_forms_bytes(count: int, dtype) -> None:
    """The compiled block scan (``_packed.c``'s ``scan_block``) against its numpy form: every offset, from blocks with
    no spike to a spike on every plane, uint8 and bool planes, a strided view."""
    from rmbvideo.recon.classical import block_scan

    rng = np.random.default_rng(count)
    planes = (rng.random((count, 9, 14)) < rng.choice([0.0, 0.05, 0.5, 1.0], size=(1, 9, 14))).astype(dtype)
    for block in (planes, planes[:, ::2, 1::3]):
        compiled, numpy_form = block_scan(block), block_scan(block, compiled=False)
        for a, b in zip(compiled, numpy_form):
            assert a.dtype == b.dtype == np.uint8 and a.shape == b.shape == block.shape and np.array_equal(a, b)


@pytest.mark.skipif(not COMPILED, reason="no compiled kernel built")
def test_tfi_frames_are_the_same_with_the_kernel_or_without(monkeypatch) -> None:
    import rmbvideo.recon.classical as classical
    from rmbvideo.sensor.compiled import KERNELS

    rng = np.random.default_rng(5)
    planes = (rng.random((300, 12, 16)) < rng.random((12, 16)) * 0.3).astype(np.uint8)
    runs = []
    for kernels in (KERNELS, None):
        monkeypatch.setattr(classical, "KERNELS", kernels)
        tfi = Tfi(step=20, max_reach=100, shorter=(30,), window=4)
        frames = tfi.push(SpikeChunk(planes, 0, 20_000.0)) + tfi.flush()
        runs.append(frames)
    assert len(runs[0]) == len(runs[1]) >= 10
    for a, b in zip(*runs):
        assert a.index == b.index and np.array_equal(a.image, b.image)
    with pytest.raises(ValueError, match="count must be"):
        KERNELS.scan_block(np.zeros(256 * 4, np.uint8), np.zeros(256 * 4, np.uint8), np.zeros(256 * 4, np.uint8), 256, 4)
    with pytest.raises(ValueError, match="buffer sizes"):
        KERNELS.scan_block(np.zeros(8, np.uint8), np.zeros(8, np.uint8), np.zeros(7, np.uint8), 2, 4)
