"""Video-like training scenes (dead leaves, independent motion, HDR), the rate convention of other
simulators, training samples made from them, and the real-video evaluation set."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from rmbvideo.errors import InputError
from rmbvideo.evaluate.real_video import (
    BEST_RAW,
    RealRow,
    RealStream,
    find_streams,
    open_stream,
    reconstruct_frame,
    reference_plane,
    scaled_psnr,
    score_stream,
)
from rmbvideo.io.dat import DatGeometry, DatReader, write_dat
from rmbvideo.sensor.conventions import CONVENTIONS
from rmbvideo.sensor.emission import RateIntegrateFire
from rmbvideo.train.dataset import SampleSpec, simulate_sample
from rmbvideo.scenes.video import SPIKEZOO_RATE, VideoScene, VideoSceneRanges
from rmbvideo.simulate.capture import capture_planes

STILL = VideoSceneRanges(camera_speed=(0.0, 0.0), static_probability=1.0, max_objects=0, zoom_rate=0.0,
                         shake_px=0.0)


def test_scenes_are_pure_functions_of_their_seed():
    a, b, c = (VideoScene(seed, 64, 48, 200) for seed in (3, 3, 4))
    assert np.array_equal(a.render(17.5), b.render(17.5))
    assert not np.array_equal(a.render(17.5), c.render(17.5))
    image = a.render(0.0)
    assert image.shape == (48, 64) and image.dtype == np.float32 and np.isfinite(image).all() and image.min() >= 0


def test_a_still_scene_is_still_and_textured_at_many_scales():
    scene = VideoScene(5, 128, 128, 300, STILL)
    first, later = scene.render(0.5), scene.render(250.5)
    np.testing.assert_array_equal(first, later)
    log = np.log(first + 1e-6)
    assert log.std() > 0.3  # real contrast, not a flat field
    # edges at every scale: the gradient energy of the image and of its 4x-reduced version are both substantial
    small = cv2.resize(first, (32, 32), interpolation=cv2.INTER_AREA)
    for image in (first, small):
        gy, gx = np.gradient(np.log(image + 1e-6))
        assert np.mean(np.hypot(gx, gy) > 0.1) > 0.02


def test_low_contrast_option_compresses_the_background_and_leaves_other_scenes_alone():
    plain = dict(camera_speed=(0.0, 0.0), static_probability=1.0, max_objects=0, zoom_rate=0.0, shake_px=0.0,
                 shadow_probability=0.0)
    for seed in (5, 6, 7):
        base = VideoScene(seed, 96, 96, 50, VideoSceneRanges(**plain)).render(10.0)
        off = VideoScene(seed, 96, 96, 50, VideoSceneRanges(**plain, low_contrast_probability=0.0)).render(10.0)
        low = VideoScene(seed, 96, 96, 50, VideoSceneRanges(**plain, low_contrast_probability=1.0,
                                                            low_contrast_gamma=(0.3, 0.3))).render(10.0)
        np.testing.assert_array_equal(base, off)
        log_base, log_low = np.log(base + 1e-6), np.log(low + 1e-6)
        # the log-contrast about the median shrinks by the factor, the median stays
        assert np.std(log_low) == pytest.approx(0.3 * np.std(log_base), rel=0.05)
        assert np.median(low) == pytest.approx(np.median(base), rel=0.05)


def test_camera_speed_is_raw_pixels_per_plane():
    ranges = VideoSceneRanges(camera_speed=(1.0, 1.0), static_probability=0.0, max_objects=0, zoom_rate=0.0,
                              shake_px=0.0)
    scene = VideoScene(11, 128, 128, 300, ranges)
    a, b = scene.render(100.0), scene.render(110.0)
    (dx, dy), _ = cv2.phaseCorrelate(np.log(a + 1e-6).astype(np.float64), np.log(b + 1e-6).astype(np.float64))
    assert math.hypot(dx, dy) == pytest.approx(10.0, abs=0.75)


def test_rigid_pans_move_as_one_piece_at_their_speed_and_leave_other_scenes_alone():
    """A rigid pan is the background alone under a constant velocity in ``pan_speed``: frame k + 10 is frame k
    shifted by ten times that, everywhere; a scene not drawn as a pan is the same as without the option."""
    ranges = VideoSceneRanges(pan_probability=1.0, pan_speed=(0.4, 0.4), shadow_probability=0.0)
    for seed in (4, 5, 7):
        scene = VideoScene(seed, 128, 128, 300, ranges)
        assert len(scene.layers) == 1 and scene.layers[0].shake.size == 0
        assert scene.layers[0].zoom_rate == 0.0 and scene.layers[0].spin == 0.0
        assert not np.any(scene.layers[0].acceleration)
        assert float(np.hypot(*scene.layers[0].velocity)) == pytest.approx(0.4)
        a, b = scene.render(100.0), scene.render(110.0)
        (dx, dy), _ = cv2.phaseCorrelate(np.log(a + 1e-6).astype(np.float64), np.log(b + 1e-6).astype(np.float64))
        np.testing.assert_allclose((dx, dy), 10 * scene.layers[0].velocity, atol=0.3)
    plain = next(s for s in range(50) if np.random.default_rng([s, 0x9A11]).random() >= 0.5)
    for k in (0.0, 40.0):
        np.testing.assert_array_equal(VideoScene(plain, 32, 32, 100, VideoSceneRanges(pan_probability=0.5)).render(k),
                                      VideoScene(plain, 32, 32, 100).render(k))
    with pytest.raises(ValueError, match="pan_fraction"):
        SampleSpec(mode="binned", readout="pure-m", scenes="video", pan_fraction=1.5)


def test_hdr_range_and_lights():
    levels = []
    for seed in range(12):
        scene = VideoScene(seed, 96, 96, 100)
        image = scene.render(50.0)
        levels.append(float(np.median(image)))
        assert np.isfinite(image).all()
    assert min(levels) < 0.02 and max(levels) > 0.05  # dark and bright scenes both occur
    lit = VideoScene(0, 96, 96, 100, VideoSceneRanges(light_probability=1.0, max_objects=6))
    images = [lit.render(k) for k in (0.0, 50.0, 99.0)]
    assert max(float(im.max() / max(np.median(im), 1e-9)) for im in images) > 5.0  # HDR within one frame


def test_spikezoo_convention_rate_and_exact_firing():
    scene = VideoScene(2, 64, 64, 400, STILL, convention="spikezoo")
    value = scene.render(0.5)
    assert value.max() <= SPIKEZOO_RATE + 1e-6
    planes = np.concatenate([c.planes for c in capture_planes(scene, 400, 20000.0)])
    counts = planes.sum(axis=0)
    # accumulate-and-subtract without noise: the count over 400 planes is 400 x rate to within one spike
    assert np.abs(counts - 400 * value).max() <= 1.0 + 1e-3
    emitter = RateIntegrateFire((4, 4), seed=0)
    fired = sum(emitter.emit_one(np.full((4, 4), 0.25)) for _ in range(1000))
    assert np.abs(fired - 250).max() <= 1


def test_video_training_sample_is_binned_with_exact_ground_truth():
    spec = SampleSpec(scenes="video", spikezoo_fraction=0.5, crop=32, frames=4)
    sample = simulate_sample(spec, 7)
    again = simulate_sample(spec, 7)
    assert np.array_equal(sample.i_s, again.i_s) and np.array_equal(sample.gt, again.gt)
    assert sample.i_s.shape == sample.i_m.shape == sample.gt.shape == (4, 32, 32)
    assert np.isfinite(sample.gt).all() and sample.gt.min() >= 0
    assert sample.i_s.max() <= spec.n and sample.i_m.max() <= 7 * spec.n
    with pytest.raises(ValueError):
        SampleSpec(scenes="video", mode="native", readout="rmb")
    with pytest.raises(ValueError):
        SampleSpec(scenes="movies")


def test_training_samples_of_a_pixel_reset_by_subtraction_are_in_the_rate_convention():
    """``subtract_fraction``: the physical scene's spikes from a pixel that keeps the charge past its threshold (a
    real camera's such as car.dat's), labelled with the rate convention; the same scene and ground truth."""
    zero = SampleSpec(scenes="video", crop=32, frames=4)
    subtract = SampleSpec(scenes="video", crop=32, frames=4, subtract_fraction=1.0)
    assert subtract.key() != zero.key() and SampleSpec(scenes="video", crop=32, frames=4, subtract_fraction=0.0).key() == zero.key()
    a, b = simulate_sample(zero, 11), simulate_sample(subtract, 11)
    assert a.convention == CONVENTIONS.index("physical") and b.convention == CONVENTIONS.index("spikezoo")
    assert np.array_equal(a.gt, b.gt) and not np.array_equal(a.i_m, b.i_m)
    # rate = light for this pixel (the reset-to-zero pixel reads less): the mean binned rate of the pixels below half
    # a threshold per plane follows their light
    light = b.gt.mean(axis=0)
    below = light < 0.5
    rate_b, rate_a = (s.i_m.mean(axis=0)[below].mean() / (8 * subtract.n) for s in (b, a))
    assert below.mean() > 0.3 and abs(rate_b / light[below].mean() - 1) < 0.05 and rate_a < 0.95 * rate_b
    with pytest.raises(ValueError):
        SampleSpec(scenes="video", subtract_fraction=1.5)


def test_reference_plane_from_the_name_or_the_middle(tmp_path):
    assert reference_plane(Path("a_key_id151.png"), 301) == 150
    assert reference_plane(Path("clip.png"), 301) == 150
    with pytest.raises(InputError):
        reference_plane(Path("a_key_id999.png"), 301)
    with pytest.raises(InputError):
        find_streams(tmp_path)


def _spikezoo_pair(folder: Path, name: str, seed: int, width: int = 400, height: int = 250) -> RealStream:
    """A spikezoo-like stream (rate 0.6 x intensity, 121 planes) and its reference PNG (``key_id61``: the light at
    time 61)."""
    scene = VideoScene(seed, width, height, 121, VideoSceneRanges(camera_speed=(0.1, 0.1), static_probability=0.0,
                                                                  object_speed=(0.05, 0.2)), convention="spikezoo")
    planes = np.concatenate([c.planes for c in capture_planes(scene, 121, 20000.0)])
    write_dat(folder / f"{name}.dat", planes, DatGeometry(width, height))
    intensity = np.clip(scene.render(61.0) / SPIKEZOO_RATE, 0, 1)
    cv2.imwrite(str(folder / f"{name}.png"), np.round(intensity * 255).astype(np.uint8))
    return next(s for s in find_streams(folder) if s.name == name)


def test_each_real_stream_takes_its_size_from_its_reference(tmp_path):
    """A folder of pairs of different sizes (a user's own camera beside spikezoo's 400x250) is scored pair by pair at
    each one's binned size, and the comparison figure holds both; a reference that does not fit its capture, one
    with an odd side and a file that is no PNG each fail naming the file."""
    from rmbvideo.evaluate.real_video import comparison_image

    small = _spikezoo_pair(tmp_path, "small_key_id61", seed=22, width=160, height=96)
    large = _spikezoo_pair(tmp_path, "large_key_id61", seed=21)
    assert [s.name for s in find_streams(tmp_path)] == ["large_key_id61", "small_key_id61"]
    assert (small.geometry.width, small.geometry.height) == (160, 96) and large.geometry == DatGeometry(400, 250)
    rows = [RealRow("TFW-S", "tfw", {"window": 10, "step": 10}), RealRow("TFP-80", "tfp", {"window": 80, "step": 20},
                                                                          raw=True)]
    results = {s.name: score_stream(s, rows) for s in (large, small)}
    assert results[small.name]["TFP-80"].image.shape == (48, 80)
    assert results[small.name]["TFP-80"].psnr > results[small.name]["TFW-S"].psnr + 3  # a slow scene: see above
    references = {s.name: np.zeros((s.geometry.height // 2, s.geometry.width // 2), np.float32) for s in (large, small)}
    figure = comparison_image(results, references, ["TFW-S", "TFP-80"])
    assert figure.shape[:2] == ((2 * 125 + 4) + (2 * 48 + 4), 3 * (2 * 200 + 4))  # tiles shown 2x, 2 px borders

    cv2.imwrite(str(tmp_path / "small_key_id61.png"), np.zeros((90, 160), np.uint8))  # 160x90 planes: 1,800 bytes
    with pytest.raises(InputError, match=r"small_key_id61\.dat: not a whole number of 160x90 planes"):
        find_streams(tmp_path)
    cv2.imwrite(str(tmp_path / "small_key_id61.png"), np.zeros((96, 161), np.uint8))
    with pytest.raises(InputError, match=r"small_key_id61\.png: .*even sides"):
        find_streams(tmp_path)
    (tmp_path / "small_key_id61.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match=r"small_key_id61\.png: not a PNG"):
        find_streams(tmp_path)


def test_the_scored_frame_is_made_at_the_references_moment(tmp_path):
    """``key_id151`` shows the light at time 151 (the end of plane 150): with only planes 150 and 151 lit, TFP over
    2 planes reads them fully in the scored frame (read from plane 1 on, numbered from 0), and the binned stream read
    that way is the capture without its first plane, binned."""
    planes = np.zeros((301, 250, 400), np.uint8)
    planes[150:152] = 1
    planes[::7, ::3, ::5] = 1  # texture for the binned comparison, away from the lit planes' values
    write_dat(tmp_path / "lit_key_id151.dat", planes, DatGeometry(400, 250))
    cv2.imwrite(str(tmp_path / "lit_key_id151.png"), np.full((250, 400), 200, np.uint8))
    (stream,) = find_streams(tmp_path)
    assert (stream.plane, stream.moment, stream.skip, stream.frame) == (150, 151, 1, 7)
    image = reconstruct_frame(stream, RealRow("TFP-2", "tfp", {"window": 2, "step": 20}, raw=True))
    assert np.array_equal(image, np.ones_like(image))

    later = tmp_path / "later"
    later.mkdir()
    write_dat(later / "c.dat", planes[1:], DatGeometry(400, 250))
    shifted = list(DatReader(later / "c.dat", DatGeometry(400, 250)).binned_chunks(64))
    read = list(open_stream(stream).binned_chunks(64))
    assert [c.start for c in read] == [c.start for c in shifted]
    for a, b in zip(read, shifted):
        assert np.array_equal(a.single, b.single) and np.array_equal(a.multi, b.multi)


def test_real_video_scoring_at_equal_resolution(tmp_path):
    stream = _spikezoo_pair(tmp_path, "scene_key_id61", seed=21)
    assert stream.plane == 60 and stream.moment == 61 and stream.skip == 11 and stream.frame == 2
    rows = [RealRow("TFW-S", "tfw", {"window": 10, "step": 10}),
            RealRow("TFP-20", "tfp", {"window": 20, "step": 20}, raw=True),
            RealRow("TFP-80", "tfp", {"window": 80, "step": 20}, raw=True)]
    scores = score_stream(stream, rows)
    assert set(scores) == {"TFW-S", "TFP-20", "TFP-80", BEST_RAW}
    for score in scores.values():
        assert score.image.shape == (125, 200) and np.isfinite(score.image).all()
    # the raw capture holds 8x the RMB stream's single-bit samples: TFP beats TFW-S on a slow scene
    assert scores["TFP-80"].psnr > scores["TFW-S"].psnr + 3
    assert scores[BEST_RAW].psnr == max(scores["TFP-20"].psnr, scores["TFP-80"].psnr)


def test_scaled_psnr_ignores_scale_and_sees_noise():
    rng = np.random.default_rng(0)
    reference = rng.random((20, 30))
    assert scaled_psnr(7.0 * reference, reference) > 100
    assert scaled_psnr(reference + rng.normal(0, 0.1, reference.shape), reference) < 25


def test_spikezoo_streams_orientation(shared_data: Path):
    """TFP over 20 raw planes of spikezoo's 200_part3, 2x2-averaged, matches its reference frame (a wrong bit
    order or row flip would fall far below)."""
    stream = next(s for s in find_streams(shared_data / "spikezoo-base") if s.name.startswith("200_part3"))
    scores = score_stream(stream, [RealRow("TFP-20", "tfp", {"window": 20, "step": 20}, raw=True)])
    assert scores["TFP-20"].psnr > 32.0


@pytest.mark.parametrize("prefix", ["200_part3", "203_part2", "203_part3"])
def test_shipped_model_beats_the_rmb_baselines_on_real_video(shared_data: Path, prefix: str):
    """The default model, through the streaming engine, against TFW-L over the same 70 readouts of the same
    input (the readout the model was trained on) on spikezoo's REDS streams (an independent simulator the
    model never trained on; their rate convention)."""
    from rmbvideo.net.weights import default_model_path, model_readout

    readout = model_readout(default_model_path("binned"))
    stream = next(s for s in find_streams(shared_data / "spikezoo-base") if s.name.startswith(prefix))
    rows = [RealRow("TFW-L", "tfw", {"window": 70, "step": 10}, readout=readout),
            RealRow("RMB-Net", "rmbnet", {"device": "cpu", "threads": 1, "convention": "spikezoo"}, readout=readout)]
    scores = score_stream(stream, rows)
    assert scores["RMB-Net"].psnr > scores["TFW-L"].psnr + 2.0, {k: v.psnr for k, v in scores.items()}


def test_the_default_on_a_1_bit_capture_beats_the_best_classical_method_on_real_video(shared_data: Path):
    """The issue's real-video target, as `evaluate --real-video` scores it: the default job's frame of each 1-bit
    capture (RMB-Net and the raw gate, at the binned size) above the best classical method on the raw capture (the
    best of TFP and TFI per stream) on average, and never more than 2 dB behind it."""
    from rmbvideo.evaluate.real_video import GATED_ROW, real_video_rows

    rows = [row for row in real_video_rows() if row.name == GATED_ROW or row.raw]
    assert GATED_ROW in [row.name for row in rows]
    scores = [score_stream(stream, rows) for stream in find_streams(shared_data / "spikezoo-base")]
    gaps = [s[GATED_ROW].psnr - s[BEST_RAW].psnr for s in scores]
    assert len(gaps) == 3 and np.mean(gaps) > 0 and min(gaps) > -2.0, gaps


def test_band_oscillation_amplitude_is_measured_at_its_period():
    from rmbvideo.evaluate.video_checks import band_oscillation_db, band_period_frames

    assert band_period_frames(125) == pytest.approx(6.25)
    t = np.arange(60)
    series = 20 + 0.01 * t + 0.5 * np.sin(2 * np.pi * t / 6.25 + 1.0)
    assert band_oscillation_db(series, 6.25) == pytest.approx(0.5, abs=1e-6)
    assert band_oscillation_db(20 + 0.01 * t, 6.25) < 1e-9


def test_oscillation_floor_reads_noise_not_the_band():
    """The floor (amplitude at periods away from the band's) stays near zero for a pure band sinusoid
    and matches the band-period amplitude's order for white noise, where nothing oscillates."""
    from rmbvideo.evaluate.video_checks import band_oscillation_db, oscillation_floor_db

    t = np.arange(58)
    band = 20 + 0.3 * np.sin(2 * np.pi * t / 6.25)
    assert oscillation_floor_db(band, 6.25) < 0.05 < 0.29 < band_oscillation_db(band, 6.25)
    noise = 20 + 0.1 * np.random.default_rng(3).standard_normal(t.size)
    floor = oscillation_floor_db(noise, 6.25)
    assert 0.005 < floor < 0.06 and band_oscillation_db(noise, 6.25) < 3 * floor


def test_flat_field_and_dark_bias_of_a_classical_method():
    from rmbvideo.evaluate.video_checks import dark_bias, flat_field_chunks

    chunks = flat_field_chunks(0.2, 16, 12, 100)
    counts = np.concatenate([c.multi for c in chunks]).astype(np.float64)
    # 8 raw pixel-planes per binned value; reset to zero loses the charge left over at each spike,
    # so the firing rate is below the charge level (a network learns that map; TFW reads it as is)
    assert 0.1 < counts.mean() / 8 <= 0.2
    bias = dark_bias("tfw", {"window": 70, "step": 10}, levels=(0.2,), size=(16, 12), frames=20)
    relative, cv = bias[0.2]
    assert -0.5 < relative < 0 and 0 < cv < 1


def test_flat_fields_are_static_nearly_flat_and_only_for_training_seeds():
    ranges = VideoSceneRanges(flat_probability=1.0)
    scene = VideoScene(7, 64, 48, 200, ranges)
    first, later = scene.render(0.0), scene.render(150.0)
    assert np.array_equal(first, later) and len(scene.layers) == 1
    assert first.max() / first.min() < (1 + ranges.flat_gradient) / (1 - ranges.flat_gradient)
    assert ranges.flat_rate[0] <= float(np.median(first)) * 1.4 and float(np.median(first)) <= ranges.flat_rate[1] * 1.4
    # the draw is apart from the main random stream: a scene that is not flat is the same as without the option
    plain = next(s for s in range(50) if np.random.default_rng([s, 0xF1A7]).random() >= 0.5)
    np.testing.assert_array_equal(VideoScene(plain, 32, 32, 100, VideoSceneRanges(flat_probability=0.5)).render(3.0),
                                  VideoScene(plain, 32, 32, 100).render(3.0))
    from rmbvideo.scenes.random_scenes import EVAL_SEED_START

    spec = SampleSpec(mode="binned", readout="pure-m", scenes="video", crop=16, frames=3, flat_fraction=1.0)
    train = simulate_sample(spec, 11)
    assert np.ptp(train.gt) <= train.gt.max() * 0.5  # flat: +-30 % at most
    held_out = simulate_sample(spec, EVAL_SEED_START + 1)
    held_out_plain = simulate_sample(SampleSpec(mode="binned", readout="pure-m", scenes="video", crop=16, frames=3),
                                     EVAL_SEED_START + 1)
    np.testing.assert_array_equal(held_out.gt, held_out_plain.gt)  # validation seeds are never flat


def test_flat_min_rate_lowers_the_floor_of_the_training_flat_fields():
    """The flat fields' levels are log-uniform from the spec's floor: with 1e-4 some fall below 1e-3 (the
    dark-end check's level), with the default none does."""
    lowered = SampleSpec(mode="binned", readout="pure-m", scenes="video", crop=16, frames=3, flat_fraction=1.0,
                         flat_min_rate=1e-4)
    default = SampleSpec(mode="binned", readout="pure-m", scenes="video", crop=16, frames=3, flat_fraction=1.0)
    low = [float(np.median(simulate_sample(lowered, seed).gt)) for seed in range(8)]
    usual = [float(np.median(simulate_sample(default, seed).gt)) for seed in range(8)]
    assert min(low) < 1e-3 and min(low) >= 0.7e-4
    assert min(usual) >= 0.7e-3


def test_a_clip_cut_from_a_sequence_keeps_its_frames_streams_and_truth_aligned():
    """The clip-edge cost runs a method on the stream cut to start or end at a frame: the binned readouts,
    the raw planes (two per readout) and the ground truth must be cut at the same moment."""
    from rmbvideo.evaluate.heldout import FRAME_STEP, Sequence
    from rmbvideo.evaluate.video_checks import clip_frames

    rng = np.random.default_rng(5)
    frames, h, w = 6, 4, 8
    readouts = frames * FRAME_STEP
    seq = Sequence(name="cut", seed=0, rate_hz=10_000.0,
                   single=rng.integers(0, 2, (readouts, h, w), dtype=np.uint8),
                   multi=rng.integers(0, 8, (readouts, h, w), dtype=np.uint8),
                   raw_packed=rng.integers(0, 256, (2 * readouts, 2 * h, 2 * w // 8), dtype=np.uint8),
                   gt=rng.random((frames, h, w), dtype=np.float32), edge_readouts=0)
    clip = clip_frames(seq, 2, 5)
    assert clip.readouts == 3 * FRAME_STEP and len(clip.gt) == 3
    np.testing.assert_array_equal(clip.multi[0], seq.multi[2 * FRAME_STEP])
    np.testing.assert_array_equal(clip.single[-1], seq.single[5 * FRAME_STEP - 1])
    np.testing.assert_array_equal(clip.raw_packed[0], seq.raw_packed[4 * FRAME_STEP])
    np.testing.assert_array_equal(clip.raw_packed[-1], seq.raw_packed[10 * FRAME_STEP - 1])
    np.testing.assert_array_equal(clip.gt, seq.gt[2:5])
    assert seq.readouts == readouts  # the original is left whole


def test_edge_cost_cuts_the_stream_where_the_frames_are_and_scores_the_same_moment():
    """The edge check's cut clip shows each frame's own moment (a fast scene: a frame one step off matches
    worse), and its edge costs are the mid-clip frame's PSNR minus that frame's made at a cut."""
    from rmbvideo.evaluate.heldout import VIDEO_KINDS, VIDEO_SEED_START, HeldoutConfig, simulate_video_sequence
    from rmbvideo.evaluate.metrics import mu_law_psnr
    from rmbvideo.evaluate.video_checks import clip_frames, edge_report, run_rmb

    fast = next(k for k in VIDEO_KINDS if k.name == "fast")
    seq = simulate_video_sequence(VIDEO_SEED_START + 3, fast, HeldoutConfig(count=1, width=32, height=24,
                                                                          readouts=120, edge_readouts=20))
    options = {"window": 10, "step": 10}
    mid = len(seq.gt) // 2
    cut = run_rmb("tfw", options, clip_frames(seq, mid, len(seq.gt)))
    for j in range(1, 5):
        scores = [mu_law_psnr(cut[j], np.minimum(seq.gt[mid + j + d], 1.0)) for d in (-1, 0, 1)]
        assert int(np.argmax(scores)) == 1, (j, scores)
    report = edge_report(seq, "tfw", options)
    as_first = mu_law_psnr(cut[0], np.minimum(seq.gt[mid], 1.0))
    assert report.first_edge_cost_db == pytest.approx(report.psnr[mid] - as_first)
    assert np.isfinite(report.last_edge_cost_db) and report.first_edge_cost_db != 0.0


def test_long_still_clips_hold_one_scene_in_either_convention_and_report_early_and_late_quality():
    """The state-age check's clips: the ground truth never changes (a still scene), the convention is the one asked
    for, the spikes differ between conventions, and the report's means are those of frames 3-8 and the second half."""
    import json

    from rmbvideo.evaluate.video_checks import band_sequence, state_age_report

    physical = band_sequence(32, 24, 12, static=True, seed=1_700_000)
    spikezoo = band_sequence(32, 24, 12, static=True, seed=1_700_000, convention="spikezoo")
    for seq, convention in ((physical, "physical"), (spikezoo, "spikezoo")):
        assert json.loads(seq.description)["convention"] == convention
        assert np.allclose(seq.gt, seq.gt[:1], rtol=1e-6)
    assert physical.name != spikezoo.name and not np.array_equal(physical.multi, spikezoo.multi)
    report = state_age_report("tfw", {"window": 10, "step": 10}, spikezoo)
    assert len(report.psnr) == 12 and report.sequence == spikezoo.name
    assert report.early_db == pytest.approx(np.mean(report.psnr[3:9]))
    assert report.late_db == pytest.approx(np.mean(report.psnr[6:]))
