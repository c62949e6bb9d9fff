"""Tone mapping: the mu-law curve and the streaming, temporally smoothed ToneMapper."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rmbvideo.io.tonemap import TONE_METHODS, ToneMapConfig, ToneMapper
from rmbvideo.mulaw import mu_law


def _texture(shape: tuple[int, int] = (24, 32), seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.01, 1.0, shape).astype(np.float32)


def test_mu_law_matches_the_paper_formula() -> None:
    x = np.array([0.0, 1e-4, 0.01, 0.5, 1.0, 4.0], dtype=np.float64)
    expected = np.log(1 + 5000 * x) / np.log(1 + 5000)
    np.testing.assert_allclose(mu_law(x), expected, rtol=1e-12)
    assert mu_law(1.0) == pytest.approx(1.0)
    assert mu_law(np.float32(0.0)) == 0.0


def test_mu_law_clips_negatives_and_stays_finite_for_huge_values() -> None:
    x = np.array([-5.0, -1e-9, 1e30, np.finfo(np.float32).max], dtype=np.float32)
    y = mu_law(x)
    assert y.dtype == np.float32
    assert np.all(np.isfinite(y))
    assert y[0] == 0.0 and y[1] == 0.0
    assert y[3] >= y[2] > 1.0
    assert np.isfinite(mu_law(np.array([1e308]))).all()


def test_mu_law_is_monotone() -> None:
    x = np.logspace(-8, 6, 200)
    assert np.all(np.diff(mu_law(x)) > 0)


def test_mu_law_on_torch_tensors_keeps_gradients() -> None:
    torch = pytest.importorskip("torch")
    x = torch.tensor([-1.0, 0.0, 0.5, 1.0, 3e38], requires_grad=True)
    y = mu_law(x)
    assert isinstance(y, torch.Tensor) and torch.isfinite(y).all()
    np.testing.assert_allclose(y.detach().numpy()[:4], mu_law(np.array([-1.0, 0.0, 0.5, 1.0])), rtol=1e-6)
    y.sum().backward()
    assert x.grad[2] > 0


@pytest.mark.parametrize("method", TONE_METHODS)
@pytest.mark.parametrize(
    "image",
    [
        np.zeros((16, 20), np.float32),
        np.full((16, 20), 1e30, np.float32),
        np.full((16, 20), np.finfo(np.float32).max, np.float32),
        _texture((16, 20)) * 1e3,
    ],
    ids=["zero", "huge", "float32max", "hdr"],
)
def test_tonemapper_output_is_valid_uint8(method: str, image: np.ndarray) -> None:
    out = ToneMapper(ToneMapConfig(method=method))(image)
    assert out.dtype == np.uint8 and out.shape == image.shape
    if not image.any():
        assert not out.any()  # black stays black, no amplified noise


@pytest.mark.parametrize("method", TONE_METHODS)
def test_tonemapper_treats_nan_and_inf_as_black(method: str) -> None:
    image = _texture((16, 20))
    image[0, :5] = np.nan
    image[1, :3] = np.inf
    image[2, :2] = -np.inf
    mapper = ToneMapper(ToneMapConfig(method=method))
    out = mapper(image)
    assert out.dtype == np.uint8
    assert mapper.nonfinite_pixels == 10
    assert math.isfinite(mapper.white)
    if method == "mulaw":
        assert not out[0, :5].any() and not out[1, :3].any()
        assert out[3:].mean() > 50


def test_tonemapper_uses_the_full_range_and_is_exposure_invariant_on_the_first_frame() -> None:
    scene = _texture()
    mulaw = ToneMapConfig(method="mulaw")
    dim = ToneMapper(mulaw)(scene * 1e-3)
    bright = ToneMapper(mulaw)(scene * 1e3)
    assert dim.max() == 255 and dim.min() < 130  # mu_law(0.01) is 0.46 of white
    np.testing.assert_array_equal(dim, bright)


def test_tonemapper_is_deterministic() -> None:
    frames = [_texture(seed=s) * (1 + s) for s in range(5)]
    first = [ToneMapper()(f) for f in frames]
    second = [ToneMapper()(f) for f in frames]
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)


def _background_brightness(config: ToneMapConfig) -> np.ndarray:
    """Mean output of a static scene's unchanged pixels, with a hot spot in frame 5 only."""
    scene = _texture((40, 50))
    hot = np.zeros(scene.shape, bool)
    hot[:4, :10] = True  # 2% of the pixels: moves the 99.5th percentile
    mapper = ToneMapper(config)
    means = []
    for i in range(12):
        frame = scene.copy()
        if i == 5:
            frame[hot] = 1000.0
        means.append(mapper(frame)[~hot].astype(np.float64).mean())
    return np.array(means)


def test_temporal_smoothing_reduces_flicker_from_an_outlier_frame() -> None:
    smoothed = _background_brightness(ToneMapConfig(method="mulaw", smoothing_frames=8.0))
    unsmoothed = _background_brightness(ToneMapConfig(method="mulaw", smoothing_frames=0.0))
    baseline = unsmoothed[0]
    assert smoothed[0] == baseline  # the first frame initialises the exposure
    unsmoothed_jump = np.abs(unsmoothed - baseline).max()
    smoothed_jump = np.abs(smoothed - baseline).max()
    assert unsmoothed_jump > 50  # the outlier darkens the whole frame without smoothing
    assert smoothed_jump < unsmoothed_jump / 2
    # without smoothing the frame right after the outlier is back to normal at once; with
    # smoothing it recovers gradually but monotonically
    assert unsmoothed[6] == baseline
    assert np.all(np.diff(smoothed[5:]) >= 0)


def test_all_dark_frames_do_not_disturb_the_exposure() -> None:
    mapper = ToneMapper()
    mapper(_texture())
    white = mapper.white
    mapper(np.zeros((24, 32), np.float32))
    assert mapper.white == white


@pytest.mark.parametrize(
    "kwargs",
    [{"method": "filmic"}, {"percentile": 0.0}, {"smoothing_frames": -1.0}, {"min_white": 0.0}, {"mu": 0.0}],
)
def test_bad_config_is_rejected(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        ToneMapConfig(**kwargs)


def test_tonemapper_rejects_non_2d_input() -> None:
    with pytest.raises(ValueError):
        ToneMapper()(np.zeros((2, 3, 4), np.float32))


def test_default_exposure_follows_the_absolute_level_and_looks_normal() -> None:
    """The default operator: a normally exposed capture gets a normal picture (median luma 60-190, the
    1st-99th percentiles >= 150 levels apart), a dark capture stays dark, and exposure moves slowly."""
    scene = _texture()
    normal = ToneMapper()(scene * (0.2 / np.median(scene)))
    p1, p99 = np.percentile(normal, [1, 99])
    assert 60 <= np.median(normal) <= 190 and p99 - p1 >= 150
    dark = ToneMapper()(scene * (1e-3 / np.median(scene)))
    assert np.median(dark) < 40
    tone = ToneMapper()
    steady = [tone(scene * 0.1) for _ in range(10)]
    flash = tone(scene * 1.0)  # one frame 10x brighter: brighter, but the exposure does not jump to it
    assert flash.mean() > steady[-1].mean() and tone._log_key < np.log(np.exp(np.mean(np.log(scene + 1e-4))) * 0.5)


@pytest.mark.parametrize("method", ["reinhard", "drago", "mantiuk"])
def test_a_frame_is_mapped_the_same_however_many_came_before(method: str) -> None:
    """The same linear frame, fed repeatedly, maps to the same 8-bit frame each time (its white point is steady):
    OpenCV's Reinhard operator keeps state between calls, which made a frame's tones depend on how many frames had
    been mapped before it (up to 8 levels), so a resumed run could not continue a video's tones."""
    rng = np.random.default_rng(3)
    frame = (0.1 + rng.random((48, 64))).astype(np.float32)
    mapper = ToneMapper(ToneMapConfig(method=method))
    outputs = [mapper(frame) for _ in range(6)]
    for out in outputs[1:]:
        np.testing.assert_array_equal(out, outputs[0])
