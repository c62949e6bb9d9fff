"""``--resolution full``: a binned method's frames at the camera's size with the raw stream's detail,
streaming and chunk-size invariant, never inventing texture where the raw counts cannot resolve it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rmbvideo.io.dat import DatGeometry, write_dat
from rmbvideo.recon.full_resolution import (block_mean, relative_detail, to_block_levels, upsample,
                                           with_candidate_detail)
from rmbvideo.recon.run import prepare_run, reconstruct_frames


def test_detail_keeps_every_block_mean_and_ignores_pure_noise() -> None:
    rng = np.random.default_rng(0)
    window = 20
    # A texture inside every block (checkerboard of rates 0.1 / 0.7, contrast 0.25 : 1.75 of the block
    # mean): kept, shrunk only by the share of the spread that Bernoulli noise could explain (13 %).
    checker = np.where((np.indices((40, 40)).sum(axis=0) % 2) == 0, 0.1, 0.7)
    detail = relative_detail(checker, window)
    np.testing.assert_allclose(block_mean(detail.astype(np.float64)), 1.0, atol=1e-6)
    expected = 1 + (1 - 0.4 * 0.6 / window / 0.09) * (checker / 0.4 - 1)
    np.testing.assert_allclose(detail, expected, rtol=1e-5)
    # A flat scene seen through Bernoulli noise: the block variance is what the noise explains, no texture.
    flat = rng.binomial(window, 0.3, size=(200, 200)) / window
    noise_detail = relative_detail(flat, window)
    np.testing.assert_allclose(block_mean(noise_detail.astype(np.float64)), 1.0, atol=1e-6)
    assert np.median(np.abs(noise_detail - 1)) < 0.02
    # No spikes at all: factor 1, finite.
    assert np.array_equal(relative_detail(np.zeros((8, 8)), window), np.ones((8, 8), np.float32))


def test_candidate_detail_keeps_the_gated_levels_and_takes_a_trusted_candidates_own_pixels() -> None:
    """Where the gate took a TFI candidate's level, ``with_candidate_detail`` puts that share of the candidate's own
    pixels inside the block in place of the detail stage's shape: every block keeps the gated level, a block taken
    wholly from a candidate at full strength is the candidate's pixels, no share or no strength changes nothing, and
    dark blocks and candidates stay finite and >= 0."""
    rng = np.random.default_rng(3)
    h, w = 6, 8
    candidates = rng.uniform(0.0, 1.0, (2, 2 * h, 2 * w)).astype(np.float32)
    candidates[0, :4, :4] = 0.0  # a candidate that never fired there
    levels = candidates.reshape(2, h, 2, w, 2).mean(axis=(2, 4))
    network = rng.uniform(0.0, 1.0, (h, w)).astype(np.float32)
    network[0, 0] = 0.0
    shares = rng.uniform(0.0, 0.5, (2, h, w)).astype(np.float32)
    shares[:, 1, 1] = (1.0, 0.0)  # block (1, 1) wholly from the first candidate
    shares[:, 0, 0] = (0.0, 0.0)  # block (0, 0) black in the network's frame and kept
    gated = (1 - shares.sum(0)) * network + (shares * levels).sum(0)
    full = to_block_levels(upsample(gated) * rng.uniform(0.5, 1.5, (2 * h, 2 * w)).astype(np.float32), gated)
    for strength in (0.25, 0.5, 1.0):
        out = with_candidate_detail(full, gated, shares, candidates, strength)
        assert np.isfinite(out).all() and (out >= 0).all()
        np.testing.assert_allclose(out.reshape(h, 2, w, 2).mean(axis=(1, 3)), gated, rtol=1e-5, atol=1e-6)
        assert not np.allclose(out, full)
    np.testing.assert_allclose(with_candidate_detail(full, gated, shares, candidates, 1.0)[2:4, 2:4],
                               candidates[0, 2:4, 2:4], rtol=1e-5)
    np.testing.assert_array_equal(with_candidate_detail(full, gated, shares, candidates, 0.0), full)
    np.testing.assert_allclose(with_candidate_detail(full, gated, 0 * shares, candidates, 1.0), full)
    assert (with_candidate_detail(full, gated, shares, candidates, 1.0)[:2, :2] == 0).all()


def test_block_levels_keep_each_binned_level_where_bilinear_upsampling_blurs_it() -> None:
    """An edge between two binned columns and a bright point among dark blocks: bilinear upsampling moves
    each block's mean towards its neighbours'; the block-exact base gives every 2x2 block its binned level
    back (black blocks stay black) and stays >= 0, and the torch twin used by the learned stage agrees."""
    import torch

    from rmbvideo.net.detail import to_block_levels as to_block_levels_torch, upsample as upsample_torch

    binned = np.zeros((6, 8), np.float32)
    binned[:, 4:] = 1.0
    binned[2, 1] = 50.0
    means = lambda image: image.reshape(6, 2, 8, 2).mean(axis=(1, 3))  # noqa: E731
    assert np.abs(means(upsample(binned)) - binned).max() > 0.1
    exact = to_block_levels(upsample(binned), binned)
    assert exact.shape == (12, 16) and (exact >= 0).all()
    np.testing.assert_allclose(means(exact), binned, rtol=1e-5, atol=1e-6)
    tensor = torch.from_numpy(binned)[None, None]
    np.testing.assert_allclose(to_block_levels_torch(upsample_torch(tensor), tensor)[0, 0].numpy(), exact,
                               rtol=1e-5, atol=1e-5)


def test_fast_detail_copy_agrees_with_the_stage_and_leaves_it_unchanged() -> None:
    """The inference copy (channels-last; bf16 convolutions where the precision policy says so) gives the
    stage's frames: to float rounding in fp32, within 1 % in bf16; the stage keeps its fp32 weights."""
    import torch

    from rmbvideo.net.detail import DetailConfig, DetailNet
    from rmbvideo.recon.full_resolution import detail_inference_copy

    torch.manual_seed(2)
    stage = DetailNet(DetailConfig(windows=(20, 40), channels=8, layers=3)).eval()
    torch.nn.init.normal_(stage.body[-1].weight, std=0.3)
    binned, rates = torch.rand(1, 1, 12, 16) * 3, torch.rand(1, 2, 24, 32)
    with torch.inference_mode():
        expected = stage(binned, rates)
        fp32 = detail_inference_copy(stage, "fp32")(binned, rates)
        with torch.autocast("cpu", torch.bfloat16):
            bf16 = detail_inference_copy(stage, "bf16")(binned, rates)
    assert all(p.dtype == torch.float32 for p in stage.parameters())
    assert bf16.dtype == torch.float32 and not torch.equal(bf16, expected)
    torch.testing.assert_close(fp32, expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(bf16, expected, rtol=1e-2, atol=1e-3)


def test_detail_features_are_each_windows_deviation_and_count_in_the_convolutions_layout() -> None:
    """The stage's inputs: the bilinear deviation, then per rate plane its deviation from the block mean (one spike's
    worth added below) and its block mean rate mu-law compressed, in that order; channels-last, and in bf16 the
    float32 planes rounded as autocast would round them."""
    import torch

    from rmbvideo.mulaw import mu_law
    from rmbvideo.net.detail import DetailConfig, DetailNet, block_mean, upsample

    stage = DetailNet(DetailConfig(windows=(6, 20), channels=4, layers=2))
    up, rates = upsample(torch.rand(2, 1, 6, 8)), torch.rand(2, 2, 12, 16) * torch.tensor([0.0, 1.0]).reshape(1, 2, 1, 1)
    features = stage.features(up, rates)
    assert features.shape == (2, 5, 12, 16) and features.is_contiguous(memory_format=torch.channels_last)
    for k, window in enumerate((6, 20)):
        mean = block_mean(rates[:, k : k + 1])
        torch.testing.assert_close(features[:, 1 + 2 * k : 2 + 2 * k],
                                   ((rates[:, k : k + 1] - mean) / (mean + 1.0 / (4 * window))).clamp(-1.0, 3.0))
        torch.testing.assert_close(features[:, 2 + 2 * k : 3 + 2 * k], mu_law(mean, 255.0))
    assert torch.equal(features[:, 1:3], torch.zeros_like(features[:, 1:3]))  # a window that never fired
    assert torch.equal(stage.features(up, rates, torch.bfloat16), features.to(torch.bfloat16))


def _capture(path: Path, planes: int = 400) -> Path:
    """64x48 raw, a bright vertical stripe every other column on the left half: detail finer than a bin."""
    rng = np.random.default_rng(1)
    rate = np.full((48, 64), 0.2)
    rate[:, :32:2] = 0.8
    write_dat(path, (rng.random((planes, 48, 64)) < rate).astype(np.uint8), DatGeometry(64, 48))
    return path


@pytest.mark.parametrize("method", ["tfw", "rmbnet"])
def test_full_resolution_frames_are_full_size_finite_and_chunk_invariant(tmp_path: Path, method: str) -> None:
    dat = _capture(tmp_path / "c.dat")
    runs = []
    for chunk in (64, 1000):
        frames = list(reconstruct_frames(dat, method, width=64, height=48, chunk_planes=chunk, resolution="full",
                                         **({"threads": 1} if method == "rmbnet" else {})))
        runs.append(frames)
    assert len(runs[0]) == len(runs[1]) >= 10
    for a, b in zip(*runs):
        assert a.index == b.index and a.image.shape == (48, 64) and np.isfinite(a.image).all()
        # the network batches frames by chunk: float32 sums in another order (bit-equal for tfw); the binned
        # frames agree to ~1e-6, and the detail stage and per-block rescaling amplify that rounding in dark
        # pixels (measured up to 8e-5 relative on an AVX2-only CPU, and 3.2e-7 absolute at a level of 1.4e-4 with stage
        # 17: a millionth of the frame's range, where a chunking fault would differ by whole levels)
        rmbnet = method == "rmbnet"
        np.testing.assert_allclose(a.image, b.image, rtol=3e-4 if rmbnet else 0, atol=1e-6 if rmbnet else 1e-7)
    # The stripes (one raw column wide) are there at full resolution: alternate columns differ.
    middle = runs[0][len(runs[0]) // 2].image
    left, right = middle[:, 4:28], middle[:, 36:60]
    assert left[:, 0::2].mean() > 1.5 * left[:, 1::2].mean()
    assert abs(right[:, 0::2].mean() / right[:, 1::2].mean() - 1) < 0.15


def test_the_gpu_configuration_forced_onto_the_cpu_gives_the_default_frames(tmp_path: Path, monkeypatch) -> None:
    """Everything a GPU run changes, forced here: batched passes of whole runs, aligned means batched in torch, the
    detail stage in batches and the raw rates in a thread of their own, made by torch. The full-resolution frames are the CPU
    default's, to the batched means' precision."""
    import rmbvideo.recon.full_resolution as full_module
    import rmbvideo.recon.rmbnet as engine_module
    from rmbvideo.recon.aligned_batched import BatchedAlignedWorker

    dat = _capture(tmp_path / "c.dat", planes=600)
    options = dict(width=64, height=48, chunk_planes=128, resolution="full", threads=1, precision="fp32")
    default = list(reconstruct_frames(dat, "rmbnet", **options))
    monkeypatch.setattr(engine_module, "aligned_worker_for",
                        lambda device, config, workers: BatchedAlignedWorker(config, device, 2))
    monkeypatch.setattr(full_module, "detail_batch", lambda device, size: 4)
    monkeypatch.setattr(full_module, "rates_beside_by_default", lambda device: True)
    monkeypatch.setattr(full_module, "rates_on_device_by_default", lambda device: True)
    forced = list(reconstruct_frames(dat, "rmbnet", frame_batch=8, **options))
    assert [f.index for f in forced] == [f.index for f in default] and len(default) >= 25
    images, reference = np.stack([f.image for f in forced]), np.stack([f.image for f in default])
    assert np.isfinite(images).all() and (images >= 0).all()
    relative = np.abs(images - reference) / np.maximum(reference, 1e-3)
    assert relative.mean() < 1e-3 and np.quantile(relative, 0.99) < 1e-2


@pytest.mark.parametrize("resolution", ["full", "binned"])
def test_the_finishing_thread_gives_the_inline_frames_bit_for_bit(tmp_path: Path, monkeypatch, resolution: str) -> None:
    """The default on a CPU with a core to spare: each chunk's raw rates, raw-interval gate and detail stage made in a
    thread of their own a chunk behind the network. Every frame is the inline one, bit for bit, whatever the chunks
    (the gate's previous frame, the TFI scans and the stores are that thread's alone); at the binned size too."""
    import rmbvideo.recon.full_resolution as full_module

    dat = _capture(tmp_path / "c.dat", planes=700)
    options = dict(width=64, height=48, resolution=resolution, threads=1, precision="fp32")
    runs = {}
    for beside in (False, True):
        monkeypatch.setattr(full_module, "finish_beside_by_default", lambda device, threads, beside=beside: beside)
        for chunk in (64, 300):
            run = prepare_run(dat, method="rmbnet", capture=dict(width=64, height=48), resolution=resolution,
                              extra_options=dict(threads=1, precision="fp32"))
            assert (run.method._behind is not None) == beside and run.method.raw_gate is not None
            runs[beside, chunk] = list(reconstruct_frames(dat, "rmbnet", chunk_planes=chunk, **options))
    reference = runs[False, 64]
    assert len(reference) >= 30
    for frames in runs.values():
        assert [f.index for f in frames] == [f.index for f in reference]
    for chunk in (64, 300):  # the same chunks: the same frames bit for bit
        for a, b in zip(runs[False, chunk], runs[True, chunk]):
            assert a.time_s == b.time_s and np.array_equal(a.image, b.image)


def test_binned_output_of_a_1bit_capture_is_the_gated_frame_the_full_frames_average_to(tmp_path: Path) -> None:
    """``--resolution binned`` on a 1-bit capture: RMB-Net's frames mixed with the raw intervals by the gate, at half
    the size; the full-resolution frames average back to them over 2x2 blocks. ``--raw-gate off``: the network's own."""
    from rmbvideo.recon.full_resolution import FullResolution
    from rmbvideo.recon.rmbnet import RmbNetReconstructor
    from rmbvideo.sensor.readout import RmbReadout

    dat = _capture(tmp_path / "c.dat", planes=500)
    options = dict(width=64, height=48, threads=1, precision="fp32")
    binned = list(reconstruct_frames(dat, "rmbnet", resolution="binned", **options))
    full = list(reconstruct_frames(dat, "rmbnet", resolution="full", **options))
    plain = list(reconstruct_frames(dat, "rmbnet", resolution="binned", raw_gate="off", **options))
    assert [f.index for f in binned] == [f.index for f in full] == [f.index for f in plain] and len(binned) >= 20
    for gated, shaped in zip(binned, full):
        assert gated.image.shape == (24, 32) and gated.time_s == shaped.time_s
        assert np.isfinite(gated.image).all() and (gated.image >= 0).all()
        means = shaped.image.reshape(24, 2, 32, 2).mean(axis=(1, 3))
        np.testing.assert_allclose(means, gated.image, rtol=1e-5, atol=1e-7)
    assert not all(np.array_equal(a.image, b.image) for a, b in zip(binned, plain))  # the gate mixed something
    assert isinstance(prepare_run(dat, resolution="binned", raw_gate="off", capture=dict(width=64, height=48),
                                  extra_options=dict(threads=1)).method, RmbNetReconstructor)
    from rmbvideo.net.weights import default_model_path

    engine = RmbNetReconstructor.from_file(default_model_path(), device="cpu", threads=1)
    with pytest.raises(ValueError, match="raw-interval gate"):
        FullResolution(engine, RmbReadout("pure-m"), output="binned")
    with pytest.raises(ValueError, match="output must be"):
        FullResolution(engine, RmbReadout("pure-m"), output="half")
    with pytest.raises(ValueError, match="candidate_detail must lie in 0..1"):
        FullResolution(engine, RmbReadout("pure-m"), candidate_detail=1.5)


def test_the_finishing_thread_runs_where_a_core_is_free_beside_a_cpu_network(monkeypatch) -> None:
    import torch

    import rmbvideo.recon.full_resolution as full_module

    monkeypatch.setattr(full_module, "work_beside", lambda threads: threads is None or threads >= 2)
    monkeypatch.setattr(full_module, "default_threads", lambda: 1)  # the policy on 2 cores
    assert full_module.finish_beside_by_default(torch.device("cpu"), None)
    assert full_module.finish_beside_by_default(torch.device("cpu"), 2)
    assert not full_module.finish_beside_by_default(torch.device("cpu"), 1)
    assert not full_module.finish_beside_by_default(torch.device("cpu"), 3)  # measured on two cores only
    assert not full_module.finish_beside_by_default(torch.device("cuda"), None)  # its rates have a thread already
    monkeypatch.setattr(full_module, "default_threads", lambda: 8)  # the policy on an idle many-core machine
    assert not full_module.finish_beside_by_default(torch.device("cpu"), None)


def test_the_readout_follows_the_model_and_native_captures_keep_their_size(tmp_path: Path) -> None:
    from rmbvideo.net.weights import MODELS_DIR

    dat = _capture(tmp_path / "c.dat", planes=200)
    pure_m = MODELS_DIR / "ablations" / "rmbnet-binned-pure-m.safetensors"
    geometry = {"width": 64, "height": 48}
    run = prepare_run(dat, capture=geometry, extra_options={"model": pure_m, "threads": 1})
    assert run.readout is None and run.method.readout.mode.value == "pure-m"  # full resolution: inside the wrapper
    run = prepare_run(dat, capture=geometry, resolution="binned", extra_options={"model": pure_m, "threads": 1})
    assert run.readout is None and run.method.readout.mode.value == "pure-m"  # binned and gated: inside it too
    run = prepare_run(dat, capture=geometry, resolution="binned", raw_gate="off",
                      extra_options={"model": pure_m, "threads": 1})
    assert run.readout is not None and run.readout.mode.value == "pure-m"
    run = prepare_run(dat, capture=geometry, resolution="binned", raw_gate="off", extra_options={"threads": 1})
    assert run.readout.mode.value == "rmb" or run.readout.mode.value == run.method.network.config.readout
    run = prepare_run(dat, capture=geometry, resolution="binned", readout="pure-s", raw_gate="off",
                      extra_options={"threads": 1})
    assert run.readout.mode.value == "pure-s"
    run = prepare_run(dat, method="tfw", capture=geometry, resolution="binned")
    assert run.readout is not None and type(run.method).__name__ == "Tfw"  # no gate for the other methods


@pytest.mark.parametrize("fmt", ["exr", "mp4", "png", "hdr10"])
def test_cli_writes_full_resolution_frames(tmp_path: Path, fmt: str) -> None:
    from click.testing import CliRunner

    from rmbvideo.cli import main

    dat = _capture(tmp_path / "c.dat", planes=200)
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["reconstruct", str(dat), "-o", str(out), "--width", "64", "--height", "48",
                                       "--method", "tfw", "--resolution", "full", "--format", fmt, "-q"])
    assert result.exit_code == 0, result.output
    if fmt == "exr":
        from rmbvideo.io.exr import read_exr

        image, _ = read_exr(sorted(out.glob("*.exr"))[0])
        assert image.shape == (48, 64) and np.isfinite(image).all()
    elif fmt == "png":
        import cv2

        assert cv2.imread(str(sorted(out.glob("*.png"))[0]), cv2.IMREAD_UNCHANGED).shape == (48, 64)
    else:
        import imageio_ffmpeg

        reader = imageio_ffmpeg.read_frames(str(out / "frames.mp4"))
        assert next(reader)["size"] == (64, 48)
        reader.close()


def test_full_resolution_evaluation_against_exact_full_size_ground_truth(tmp_path: Path) -> None:
    """A panorama and a video held-out sequence (tiny): the full-size ground truth is rendered again
    from the seed and matches the binned one after 2x2 averaging; every row is scored, full and binned
    RMB-Net agree at the binned size (adding detail costs nothing there; the raw gate's row mixes in raw
    intervals, which is meant to change the binned-size image, so it is only required to be finite here; what it
    mixes is checked exactly in tests/test_raw_gate.py)."""
    import torch

    from rmbvideo.evaluate.full_resolution import (BINNED_UP, FULL, FullScores, full_ground_truth, full_rows,
                                                   markdown, score_sequences)
    from rmbvideo.evaluate.heldout import (VIDEO_KINDS, VIDEO_SEED_START, HeldoutConfig, load_heldout_config,
                                           simulate_video_sequence)
    from rmbvideo.net.config import RmbNetConfig
    from rmbvideo.net.model import RmbNet
    from rmbvideo.net.weights import ModelCard, save_model
    from rmbvideo.scenes.render import bin_image

    tiny = HeldoutConfig(count=1, width=48, height=40, readouts=60, edge_readouts=20)
    sequences = [load_heldout_config(tiny, tmp_path / "cache")[0],
                 simulate_video_sequence(VIDEO_SEED_START + 300, VIDEO_KINDS[3], tiny)]
    for seq in sequences:
        for i, truth in full_ground_truth(seq).items():
            assert truth.shape == seq.raw_shape
            np.testing.assert_allclose(bin_image(truth), seq.gt[i], rtol=1e-4, atol=1e-6)
    torch.manual_seed(0)
    model = save_model(tmp_path / "m.safetensors", RmbNet(RmbNetConfig(w=1, width=0.25, convention_input=True)),
                       ModelCard(name="tiny"))
    scores = FullScores()
    rows = full_rows(model)
    gated = {row.name for row in rows if row.raw_gate}
    score_sequences(sequences, rows, scores)
    table = markdown(scores, [s.name for s in sequences], [])
    for name in (FULL, BINNED_UP, "TFP-20", "TFI", "best classical on the raw capture"):
        assert name in table
    for checks in scores.binned_check.values():
        assert FULL in checks and BINNED_UP in checks
        for name, value in checks.items():
            assert np.isfinite(value) and (name in gated or abs(value - checks[BINNED_UP]) < 0.3), name


@pytest.mark.parametrize("reach", [0, 30])
def test_learned_detail_stage_starts_as_bilinear_stays_finite_and_streams(tmp_path: Path, reach: int, monkeypatch) -> None:
    """A new detail stage is plain bilinear upsampling; any stage (with or without the TFI input) gives
    finite, non-negative frames of the camera's size, the same for every chunk size; weights round-trip
    through the safe loader, which refuses an RMB-Net card."""
    import torch

    from rmbvideo.errors import ModelError
    from rmbvideo.net.detail import DetailConfig, DetailNet
    from rmbvideo.net.weights import ModelCard, load_detail_model, load_model, save_model
    from rmbvideo.recon.classical import Tfw
    from rmbvideo.recon.full_resolution import FullResolution
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.io.dat import DatReader
    from rmbvideo.sensor.readout import RmbReadout

    config = DetailConfig(windows=(20, 40), channels=8, layers=3, interval_reach=reach)
    assert config.rate_channels == 2 + bool(reach) and DetailConfig.from_dict(config.to_dict()) == config
    assert ("interval_reach" in config.to_dict()) == bool(reach)
    fresh = DetailNet(config)
    binned = torch.rand(1, 1, 12, 16) * 3
    rates = torch.rand(1, config.rate_channels, 24, 32)
    with torch.inference_mode():
        plain = binned[0, 0].numpy()
        np.testing.assert_allclose(fresh(binned, rates)[0, 0].numpy(), to_block_levels(upsample(plain), plain),
                                   rtol=1e-5, atol=1e-6)
    torch.manual_seed(1)
    stage = DetailNet(config)
    torch.nn.init.normal_(stage.body[-1].weight, std=0.3)
    with torch.inference_mode():
        hard = stage(torch.tensor([[[[0.0, 1e30], [float("nan"), 5.0]]]]), torch.ones(1, config.rate_channels, 4, 4))
    assert torch.isfinite(hard).all() and (hard >= 0).all()
    with torch.inference_mode():  # with detail added, every 2x2 block still averages to its binned pixel
        shaped = stage(binned, rates)
    assert not torch.allclose(shaped, fresh(binned, rates))
    torch.testing.assert_close(torch.nn.functional.avg_pool2d(shaped, 2), binned, rtol=1e-5, atol=1e-6)
    path = save_model(tmp_path / "detail.safetensors", stage, ModelCard(name="detail"))
    loaded, card = load_detail_model(path)
    assert card.name == "detail" and loaded.config == config
    for key, tensor in stage.state_dict().items():
        assert torch.equal(tensor, loaded.state_dict()[key])
    with pytest.raises(ModelError, match="not an RMB-Net model card"):
        load_model(path)
    dat = _capture(tmp_path / "c.dat", planes=300)
    runs = []
    import rmbvideo.recon.full_resolution as full_module

    # a GPU's batches of frames and raw rates made beside the binned method and on its device (forced here, on the
    # CPU) change nothing
    for chunk, batch, beside, device in ((50, 1, False, False), (1000, 1, False, False), (1000, 3, False, False),
                                         (50, 3, True, False), (50, 3, True, True), (1000, 1, False, True)):
        monkeypatch.setattr(full_module, "detail_batch", lambda device, size, batch=batch: batch)
        recon = FullResolution(Tfw(window=10, step=10), RmbReadout("pure-m"), step=20, detail=loaded,
                               rates_beside=beside, rates_on_device=device)
        sink = FrameCollector()
        reconstruct_stream(DatReader(dat, DatGeometry(64, 48)), recon, sink, chunk_planes=chunk)
        runs.append(sink.frames)
    assert all(sorted(run) == sorted(runs[0]) for run in runs) and len(runs[0]) >= 10
    for index, frame in runs[0].items():
        assert frame.image.shape == (48, 64) and np.isfinite(frame.image).all() and (frame.image >= 0).all()
        for other in runs[1:]:
            np.testing.assert_allclose(frame.image, other[index].image, rtol=1e-5, atol=1e-7)


def test_the_detail_stage_reads_the_same_rates_stacked_on_their_device_or_from_numpy() -> None:
    """The detail stage's (F, R, H, W) input: device tensors stacked where they are, numpy images (float32 or float64,
    cast as ``astype`` casts) copied once; the values are the same bit for bit."""
    import torch

    from rmbvideo.recon.full_resolution import _stacked_rates

    rng = np.random.default_rng(3)
    images = [[rng.random((6, 8)) for _ in range(3)] for _ in range(4)]  # float64, as a rate may come
    stacked = _stacked_rates(images)
    expected = np.stack([np.stack(frame) for frame in images]).astype(np.float32)
    assert stacked.dtype == torch.float32 and np.array_equal(stacked.numpy(), expected)
    on_device = _stacked_rates([[torch.from_numpy(i.astype(np.float32))[:5] for i in frame] for frame in images])
    assert on_device.shape == (4, 3, 5, 8) and np.array_equal(on_device.numpy(), expected[:, :, :5])


def test_detail_training_writes_a_loadable_stage_and_resumes(tmp_path: Path) -> None:
    import torch

    from rmbvideo.net.detail import DetailConfig
    from rmbvideo.net.weights import load_detail_model
    from rmbvideo.errors import OutputError
    from rmbvideo.train.detail import DetailTrainConfig, train_detail

    from dataclasses import replace

    config = DetailTrainConfig(detail=DetailConfig(windows=(20, 40), channels=4, layers=2, interval_reach=12), crop=16,
                               batch=2,
                               pool=3, val_count=1, val_every=2, checkpoint_every=1, minutes=60.0, steps=3)
    path = train_detail(config, tmp_path)
    model, card = load_detail_model(path)
    assert card.training["steps_done"] == 3 and np.isfinite(card.metrics["val_mu_psnr_learned"])
    assert model.config.interval_reach == 12
    path = train_detail(replace(config, steps=5), tmp_path, resume=True)  # continues from step 3
    resumed, card = load_detail_model(path)
    assert card.training["steps_done"] == 5
    assert any(not torch.equal(a, b) for a, b in zip(model.state_dict().values(), resumed.state_dict().values()))
    with pytest.raises(OutputError, match="holds the checkpoint of an earlier run at step 5"):
        train_detail(config, tmp_path)  # without resume, the checkpoint is not replaced
    assert load_detail_model(train_detail(replace(config, steps=1), tmp_path, overwrite=True))[1].training[
        "steps_done"] == 1


def test_train_detail_cli_refuses_to_resume_a_checkpoint_of_another_width(tmp_path: Path) -> None:
    """``train-detail --resume --channels 6`` on a 4-channel checkpoint: refused in one line naming the mismatch,
    before any scene is simulated."""
    from click.testing import CliRunner

    from rmbvideo.cli import main
    from rmbvideo.net.detail import DetailConfig
    from rmbvideo.train.detail import INTERVAL_REACH, DetailTrainConfig, train_detail

    config = DetailTrainConfig(detail=DetailConfig(channels=4, layers=2, interval_reach=INTERVAL_REACH), crop=16,
                               batch=2, pool=3, val_count=1, val_every=2, checkpoint_every=1, steps=2)
    train_detail(config, tmp_path)
    result = CliRunner().invoke(main, ["train-detail", "-o", str(tmp_path), "--resume", "--channels", "6",
                                       "--layers", "2", "--quiet"])
    assert result.exit_code != 0 and "does not fit" in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_a_weaker_threshold_mismatch_gives_a_weaker_fixed_pattern() -> None:
    """``capture_planes(mismatch=...)`` scales the camera's threshold mismatch: over a flat field the pixels' rates
    spread about their 2x2 block's mean less with none than with the paper's, the scene and every other noise the
    same; the training samples draw it in ``DetailTrainConfig.mismatch``, and the default draws nothing (the shipped
    recipe's samples unchanged)."""
    from rmbvideo.scenes.video import VideoScene, VideoSceneRanges
    from rmbvideo.simulate.capture import capture_planes
    from rmbvideo.train.detail import simulate_detail_sample

    flat = VideoSceneRanges(flat_probability=1.0, flat_rate=(0.3, 0.3), flat_gradient=0.0)  # a lit wall
    scene = VideoScene(3, 32, 32, 400, flat)

    def spread(mismatch: float) -> float:
        rate = np.concatenate([c.planes for c in capture_planes(scene, 400, 20000.0, mismatch=mismatch)]).mean(0)
        block = np.repeat(np.repeat(rate.reshape(16, 2, 16, 2).mean(axis=(1, 3)), 2, 0), 2, 1)
        lit = block > 0.05
        return float((rate[lit] / block[lit] - 1).std())

    none, paper = spread(0.0), spread(1.0)
    assert paper > 2 * none, (none, paper)
    default = simulate_detail_sample(11, 16, (20, 80), 0.0)
    assert np.array_equal(default.rates, simulate_detail_sample(11, 16, (20, 80), 0.0, mismatch=(1.0, 1.0)).rates)
    assert not np.array_equal(default.rates, simulate_detail_sample(11, 16, (20, 80), 0.0, mismatch=(0.0, 0.0)).rates)


def test_train_detail_fine_tunes_from_a_stage(tmp_path: Path) -> None:
    """``train-detail --init W``: the stage starts from W's weights (its shape taken from W, widened by
    ``--interval-window``), and the card says so."""
    from dataclasses import replace

    import torch
    from click.testing import CliRunner

    from rmbvideo.cli import main
    from rmbvideo.net.detail import DetailConfig, DetailNet
    from rmbvideo.net.weights import ModelCard, load_detail_model, save_model
    from rmbvideo.train.detail import DetailTrainConfig, train_detail

    config = DetailConfig(windows=(20, 40), channels=4, layers=2, interval_reach=12)
    torch.manual_seed(3)
    start = save_model(tmp_path / "start", DetailNet(config), ModelCard(name="start"))
    train = DetailTrainConfig(detail=config, crop=16, batch=2, pool=3, val_count=1, val_every=2, steps=1, lr=1e-9)
    tuned, card = load_detail_model(train_detail(train, tmp_path / "tuned", init=start))
    first, _ = load_detail_model(start)
    assert card.training["init"] == str(start)
    for a, b in zip(first.state_dict().values(), tuned.state_dict().values()):
        assert torch.allclose(a, b, atol=1e-6)  # one step at a negligible rate: still the start's weights
    # a start without interval windows is widened to read them: its weights kept, the new inputs' at zero
    wide = replace(config, interval_windows=(4,))
    widened, _ = load_detail_model(train_detail(replace(train, detail=wide), tmp_path / "wide", init=start))
    assert widened.config == wide
    first_layer = widened.state_dict()["body.0.weight"]
    assert torch.allclose(first_layer[:, :-2], first.state_dict()["body.0.weight"], atol=1e-6)
    assert first_layer[:, -2:].abs().max() < 1e-6
    result = CliRunner().invoke(main, ["train-detail", "-o", str(tmp_path / "bad"), "--init", str(start),
                                       "--mismatch", "1", "0", "--quiet"])
    assert result.exit_code == 2 and "--mismatch" in result.output


def test_detail_sample_reads_tfi_at_the_frame_centre() -> None:
    """The TFI plane of a training sample is 1 / the interval between the spikes around the centre: a
    value in (0, 1] on every pixel, and on a bright static scene close to the 80-plane TFP rate."""
    from rmbvideo.train.detail import simulate_detail_sample

    sample = simulate_detail_sample(11, 16, (20, 80), 0.0, interval_reach=30)
    tfi = sample.rates[-1]
    assert sample.rates.shape == (3, 32, 32) and tfi.min() > 0 and tfi.max() <= 1
    assert 1 / tfi.max() == int(round(1 / tfi.max()))  # intervals are whole planes
    bright = sample.rates[1] > 0.2
    assert bright.mean() > 0.5  # this seed's scene is mostly bright
    assert abs(float(np.median(tfi[bright] / sample.rates[1][bright])) - 1.0) < 0.1


def test_the_detail_stage_batches_frames_on_a_gpu_only() -> None:
    import torch

    from rmbvideo.recon.classical import Tfw
    from rmbvideo.recon.full_resolution import DETAIL_BATCH_PIXELS, FullResolution, detail_batch
    from rmbvideo.sensor.readout import RmbReadout

    assert detail_batch(torch.device("cpu"), (250, 400)) == 1
    assert detail_batch(torch.device("cuda"), (250, 400)) == DETAIL_BATCH_PIXELS // (250 * 400) > 1
    assert detail_batch(torch.device("cuda"), (8000, 8000)) == 1
    # the raw rates go beside the binned method only when it leaves the CPU idle (on a GPU)
    assert FullResolution(Tfw(window=10, step=10), RmbReadout("pure-m"), step=20)._beside is None


def test_a_stage_widened_with_interval_windows_starts_as_itself_and_reads_them_in_the_engine(tmp_path: Path) -> None:
    """``DetailConfig.interval_windows``: TFI over whole intervals covering 4 or 8 central planes as more inputs. A
    stage widened with them (zero weights on the new inputs) makes its frames exactly; the engine feeds it the
    planes (weights on them change the frames); a training sample reads them; the card keeps them."""
    from dataclasses import replace

    import torch

    from rmbvideo.net.detail import DetailConfig, DetailNet
    from rmbvideo.recon.classical import Tfw
    from rmbvideo.recon.full_resolution import FullResolution
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.io.dat import DatReader
    from rmbvideo.sensor.readout import RmbReadout
    from rmbvideo.train.detail import simulate_detail_sample

    config = DetailConfig(windows=(20, 40), channels=4, layers=2, interval_reach=12)
    wide_config = replace(config, interval_windows=(4, 8))
    assert wide_config.rate_channels == 5 and DetailConfig.from_dict(wide_config.to_dict()) == wide_config
    assert "interval_windows" not in config.to_dict() and wide_config.to_dict()["interval_windows"] == [4, 8]
    with pytest.raises(ValueError, match="interval_reach"):
        DetailConfig(interval_windows=(4,))
    torch.manual_seed(2)
    stage = DetailNet(config)
    torch.nn.init.normal_(stage.body[-1].weight, std=0.3)
    wide = stage.widened(wide_config)
    with pytest.raises(ValueError, match="widens only"):
        stage.widened(replace(wide_config, channels=8))
    binned, rates = torch.rand(1, 1, 12, 16), torch.rand(1, 5, 24, 32)
    with torch.inference_mode():
        torch.testing.assert_close(wide(binned, rates), stage(binned, rates[:, :3]))

    dat = _capture(tmp_path / "c.dat", planes=300)

    def frames(detail: DetailNet) -> list[np.ndarray]:
        recon = FullResolution(Tfw(window=10, step=10), RmbReadout("pure-m"), step=20, detail=detail, threads=1,
                               precision="fp32")  # on a host with bf16 the widths would round differently
        sink = FrameCollector()
        reconstruct_stream(DatReader(dat, DatGeometry(64, 48)), recon, sink, chunk_planes=64)
        return [sink.frames[i].image for i in sorted(sink.frames)]

    for a, b in zip(frames(stage), frames(wide)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    with torch.no_grad():
        wide.body[0].weight[:, -4:] = 0.5
    assert not all(np.allclose(a, b, rtol=1e-3) for a, b in zip(frames(stage), frames(wide)))

    sample = simulate_detail_sample(11, 16, (20, 80), 0.0, interval_reach=30, interval_windows=(4, 16))
    assert sample.rates.shape == (5, 32, 32) and sample.rates[2:].min() > 0 and sample.rates[2:].max() <= 1
    bright = sample.rates[1] > 0.2
    assert abs(float(np.median(sample.rates[4][bright] / sample.rates[1][bright])) - 1.0) < 0.1
    # TFI-16 spans more planes than one interval: finer than whole-plane intervals, and as close to the TFP-80 rate
    error = [np.abs(sample.rates[k] - sample.rates[1])[bright].mean() for k in (2, 4)]
    assert error[1] < error[0]


def test_the_shipped_detail_stage_reads_the_gates_tfi_searches_and_its_own_without_a_gate() -> None:
    """The shipped detail stage reads TFI-4 and TFI-16, as the shipped gate does: with the gate it reads the gate's two
    searches (no search of its own), with the gate off it searches at its own reach."""
    from rmbvideo.net.weights import default_model_path
    from rmbvideo.recon.classical import Tfi
    from rmbvideo.recon.full_resolution import FullResolution, detail_stage, raw_gate_stage
    from rmbvideo.recon.rmbnet import RmbNetReconstructor
    from rmbvideo.sensor.readout import RmbReadout

    detail, gate = detail_stage("learned"), raw_gate_stage("auto")
    assert detail.config.interval_windows == (gate.config.tfi_window, gate.config.long_window)
    engine = RmbNetReconstructor.from_file(default_model_path(), device="cpu", threads=1)
    gated = FullResolution(engine, RmbReadout("pure-m"), detail=detail, raw_gate=gate, threads=1)
    windowed = [(r.max_reach, r.window) for r in gated._rates if isinstance(r, Tfi) and r.window]
    assert windowed == [(gate.config.tfi_reach, 4), (gate.config.tfi_reach, 16)]
    assert gated._detail_planes[-2:] == gated._gate_planes
    alone = FullResolution(engine, RmbReadout("pure-m"), detail=detail, threads=1)
    assert [(r.max_reach, r.window) for r in alone._rates if isinstance(r, Tfi) and r.window] == [
        (detail.config.interval_reach, 4), (detail.config.interval_reach, 16)]
    assert len(alone._detail_planes) == detail.config.rate_channels
