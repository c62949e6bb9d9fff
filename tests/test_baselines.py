"""GC20 and MG20 baselines on synthetic streams drawn from the exact reading model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar
from scipy.stats import binom

from rmbvideo.chunks import RmbChunk
from rmbvideo.recon.gc20 import (
    Gc20Config,
    Gc20Reconstructor,
    JotModel,
    ReadingStats,
    readings_stats,
    solve_exposure,
)
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.recon.mg20 import Mg20Config, Mg20Reconstructor

BAND, SHIFT = 4, 2


def rolling_rows(start: int, count: int, height: int) -> np.ndarray:
    """RMB band rows: ``BAND`` rows from row (t * SHIFT) % H at readout t, wrapping."""
    t = np.arange(start, start + count)[:, None]
    return (np.arange(height)[None, :] - t * SHIFT) % height < BAND


def draw_stream(theta: np.ndarray, rng: np.random.Generator, start: int = 0) -> RmbChunk:
    """Binned RMB readings of exposure ``theta`` (T, H, W) from the 'poisson' jot model."""
    p = -np.expm1(-theta)
    count, height, _ = theta.shape
    rows = rolling_rows(start, count, height)
    single = (rng.random(theta.shape) < p).astype(np.uint8)
    multi = np.minimum(rng.binomial(8, p), 7).astype(np.uint8)
    multi = np.where(rows[:, :, None], multi, 0).astype(np.uint8)
    return RmbChunk(single=single, multi=multi, multi_rows=rows, start=start, rate_hz=10_000.0)


def run(reconstructor, stream: RmbChunk, chunk_size: int) -> list:
    frames = []
    for lo in range(0, len(stream.single), chunk_size):
        hi = min(lo + chunk_size, len(stream.single))
        frames += reconstructor.push(RmbChunk(
            single=stream.single[lo:hi], multi=stream.multi[lo:hi], multi_rows=stream.multi_rows[lo:hi],
            start=stream.start + lo, rate_hz=stream.rate_hz,
        ))
    return frames + reconstructor.flush()


def static_scene(levels: list[float], count: int, height: int = 16, width: int = 16) -> np.ndarray:
    """Vertical stripes of constant exposure, one per level, constant in time."""
    image = np.repeat(np.asarray(levels, dtype=np.float64), width)[None, :].repeat(height, axis=0)
    return np.broadcast_to(image, (count, *image.shape))


def test_solver_matches_numerical_maximum_of_the_exact_likelihood() -> None:
    rng = np.random.default_rng(0)
    model = JotModel(multi_jots=8, clamp=7, response="poisson")
    shape = (1, 6)
    stats = ReadingStats(
        single_ones=rng.integers(0, 40, shape).astype(np.float32),
        single_zeros=rng.integers(0, 40, shape).astype(np.float32),
        multi_sum=np.zeros(shape, np.float32),
        multi_below=rng.integers(0, 10, shape).astype(np.float32),
        multi_clamped=rng.integers(1, 10, shape).astype(np.float32),
    )
    stats.multi_sum[:] = stats.multi_below * rng.integers(0, 7, shape)
    estimate = solve_exposure(stats, model)
    for k in range(shape[1]):
        s1, s0, ks, mb, mc = (float(a[0, k]) for a in stats.arrays())

        def negative_log_likelihood(theta: float) -> float:
            p = -math.expm1(-theta)
            return -(s1 * math.log(p) - s0 * theta + ks * math.log(p) - (8 * mb - ks) * theta
                     + mc * binom.logsf(6, 8, p))

        best = minimize_scalar(negative_log_likelihood, bounds=(1e-4, 20.0), method="bounded",
                               options={"xatol": 1e-9})
        assert estimate[0, k] == pytest.approx(best.x, rel=1e-4)


def test_gc20_recovers_static_exposures_and_stays_finite_at_the_extremes() -> None:
    levels = [0.0, 0.1, 0.3, 1.0, 60.0]
    stream = draw_stream(static_scene(levels, 90), np.random.default_rng(1))
    frames = run(Gc20Reconstructor(), stream, 90)
    assert [f.index for f in frames] == list(range(9))
    image = frames[4].image  # window [10, 80): fully inside the data
    assert np.isfinite(image).all() and image.dtype == np.float32
    means = image.reshape(16, len(levels), 16).mean(axis=(0, 2))
    for level, mean in zip(levels[1:4], means[1:4]):
        assert mean == pytest.approx(level, rel=0.03)
    assert 0.0 < means[0] < 0.01
    assert means[4] > 4.0  # all saturated: clamped at the pseudo-count bound ln(2E), not Inf
    assert frames[-1].time_s == pytest.approx(85 / 10_000.0)


def test_gc20_beats_the_window_mean_where_one_bit_readings_saturate() -> None:
    levels = [0.05, 0.2, 0.5, 1.5, 2.5, 3.5]
    theta = static_scene(levels, 90)
    stream = draw_stream(theta, np.random.default_rng(2))
    image = run(Gc20Reconstructor(), stream, 45)[4].image
    model = JotModel(multi_jots=8, clamp=7, response="poisson")
    window = readings_stats(stream, 10, 80, model)
    window_mean = window.fires(model) / window.jots(model)
    bright = slice(3 * 16, None)
    truth = theta[0][:, bright]
    assert mu_law_psnr(image[:, bright], truth) > mu_law_psnr(window_mean[:, bright], truth) + 6.0


def test_rate_response_is_unbiased_for_rate_data() -> None:
    rng = np.random.default_rng(3)
    theta = np.full((70, 16, 16), 0.6)
    rows = rolling_rows(0, 70, 16)
    multi = np.where(rows[:, :, None], np.minimum(rng.binomial(8, theta), 7), 0).astype(np.uint8)
    stream = RmbChunk(single=(rng.random(theta.shape) < theta).astype(np.uint8), multi=multi,
                      multi_rows=rows, start=0, rate_hz=10_000.0)
    frames = run(Gc20Reconstructor(Gc20Config(response="rate")), stream, 70)
    assert frames[3].image.mean() == pytest.approx(0.6, rel=0.02)
    assert frames[3].image.max() < 1.0


@pytest.mark.parametrize("make", [lambda: Gc20Reconstructor(), lambda: Mg20Reconstructor()])
def test_frames_do_not_depend_on_chunking(make) -> None:
    rng = np.random.default_rng(4)
    theta = rng.uniform(0.0, 2.0, (1, 24, 32)).repeat(57, axis=0)
    stream = draw_stream(theta, rng, start=13)  # starts and ends mid-block
    reference = run(make(), stream, 57)
    assert [f.index for f in reference] == [1, 2, 3, 4, 5, 6]
    for size in (1, 7):
        frames = run(make(), stream, size)
        assert [f.index for f in frames] == [f.index for f in reference]
        for a, b in zip(frames, reference):
            assert a.time_s == b.time_s
            np.testing.assert_array_equal(a.image, b.image)


def translating_scene(count: int, height: int, width: int, speed: float, rng: np.random.Generator) -> np.ndarray:
    """A smooth random texture moving right by ``speed`` pixels per readout; exposure in [0.03, 1.5]."""
    import cv2

    wide = cv2.GaussianBlur(rng.random((height, width + int(speed * count) + 8)), (0, 0), 2.0)
    wide = (wide - wide.min()) / (wide.max() - wide.min())
    columns = np.arange(width, dtype=np.float64)
    frames = np.empty((count, height, width))
    for t in range(count):
        shifted = columns + speed * (count - t)  # content at x moves to x + speed * t
        for y in range(height):
            frames[t, y] = np.interp(shifted, np.arange(wide.shape[1]), wide[y])
    return 0.03 + 1.47 * frames**2


def test_mg20_alignment_beats_the_unaligned_merge_on_motion() -> None:
    rng = np.random.default_rng(5)
    theta = translating_scene(90, 64, 96, speed=0.3, rng=rng)
    stream = draw_stream(theta, rng)
    aligned = run(Mg20Reconstructor(), stream, 90)[4].image
    unaligned = run(Mg20Reconstructor(Mg20Config(align=False)), stream, 90)[4].image
    gc20 = run(Gc20Reconstructor(), stream, 90)[4].image
    np.testing.assert_array_equal(unaligned, gc20)
    truth = 0.5 * (theta[44] + theta[45])  # frame 4 is centred at readout 45
    inner = (slice(8, -8), slice(16, -16))
    aligned_psnr = mu_law_psnr(aligned[inner], truth[inner])
    unaligned_psnr = mu_law_psnr(unaligned[inner], truth[inner])
    assert np.isfinite(aligned).all()
    assert aligned_psnr > unaligned_psnr + 1.0


def test_frame_schedule_matches_tfw_l() -> None:
    from rmbvideo.recon.classical import tfw_l

    rng = np.random.default_rng(6)
    stream = draw_stream(rng.uniform(0.0, 1.0, (1, 16, 16)).repeat(57, axis=0), rng, start=13)
    ours = run(Gc20Reconstructor(), stream, 57)
    theirs = run(tfw_l(), stream, 57)
    assert [(f.index, f.time_s) for f in ours] == [(f.index, f.time_s) for f in theirs]


def test_the_convention_picks_the_response_unless_one_is_given() -> None:
    from rmbvideo.recon.gc20 import make_gc20
    from rmbvideo.recon.mg20 import make_mg20

    assert make_gc20().response == "poisson" and make_gc20(convention="spikezoo").response == "rate"
    assert make_mg20(convention="physical").response == "poisson"
    assert make_mg20(convention="spikezoo", response="poisson").response == "poisson"  # an explicit response wins
    with pytest.raises(ValueError, match="convention"):
        make_gc20(convention="sideways")


def test_gc20_takes_any_step_and_window_and_mg20_names_the_ones_it_needs(tmp_path) -> None:
    """GC20's blocks only group its sums: a step or window they do not tile (a frame a readout, a 15-readout window)
    gets smaller blocks, with TFW's frame schedule and the same frames as blocks of one readout; MG20 aligns its
    blocks, so there such options are one line naming the steps and windows it takes (they were a traceback)."""
    import subprocess
    import sys

    from rmbvideo.io.dat import DatGeometry, write_dat
    from rmbvideo.recon.classical import Tfw

    rng = np.random.default_rng(8)
    stream = draw_stream(rng.uniform(0.0, 1.0, (1, 16, 16)).repeat(57, axis=0), rng, start=13)
    for step, window in ((1, 70), (15, 15), (10, 20)):
        frames = run(Gc20Reconstructor(Gc20Config(step=step, window=window)), stream, 57)
        single = run(Gc20Reconstructor(Gc20Config(step=step, window=window, block=1)), stream, 57)
        schedule = run(Tfw(window=window, step=step), stream, 57)
        assert [(f.index, f.time_s) for f in frames] == [(f.index, f.time_s) for f in schedule] != []
        for a, b in zip(frames, single):
            np.testing.assert_allclose(a.image, b.image, rtol=1e-5)
    with pytest.raises(Exception, match="--step that is a multiple of 20"):
        Mg20Reconstructor(Mg20Config(step=1))
    capture = tmp_path / "c.dat"
    write_dat(capture, (rng.random((200, 16, 16)) < 0.3).astype(np.uint8), DatGeometry(16, 16))
    for method, extra, code in (("gc20", ["--step", "2"], 0), ("mg20", ["--window", "15"], 2)):
        proc = subprocess.run([sys.executable, "-m", "rmbvideo", "reconstruct", str(capture), "-o",
                               str(tmp_path / method), "--width", "16", "--height", "16", "--method", method,
                               "--format", "null", "-q", *extra], capture_output=True, text=True)
        assert proc.returncode == code and "Traceback" not in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == code // 2, proc.stderr
