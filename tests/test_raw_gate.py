"""The raw-interval gate of 1-bit captures: RMB-Net's binned frames mixed with raw TFI (``rmbvideo.net.raw_gate``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from rmbvideo.errors import OutputError
from rmbvideo.evaluate.heldout import HeldoutConfig, simulate_sequence
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.net.raw_gate import (FEATURES, FRAME_FEATURES, LONG_FEATURES, RawGate, RawGateConfig, gate_features,
                                   tfi_light)
from rmbvideo.net.weights import ModelCard, save_model

TINY = HeldoutConfig(count=1, width=48, height=40, readouts=60, edge_readouts=20)


def _tiny_model(path: Path) -> Path:
    torch.manual_seed(0)
    return save_model(path, RmbNet(RmbNetConfig(w=1, width=0.25, convention_input=True)), ModelCard(name="tiny"))


def _mixing_gate(tfi_window: int = 0, long_window: int = 0, frame_features: bool = False) -> RawGate:
    """A gate that mixes (shares spread around a half, or a third each), so a fault in what it is given shows in the
    output."""
    torch.manual_seed(3)
    gate = RawGate(RawGateConfig(hidden=4, tfi_reach=30, tfi_window=tfi_window, long_window=long_window,
                                 frame_features=frame_features))
    with torch.no_grad():
        gate.body[-1].bias.zero_()
        gate.feature_mean.copy_(torch.tensor([-3.0, -3.0, 0.0, -2.0, -2.0, -3.0, 0.0, -3.0, 0.0, -2.0, -2.0, -2.0][
            :len(gate.feature_mean)]))
    return gate


def test_tfi_is_read_as_light_as_the_evaluation_reads_it() -> None:
    from rmbvideo.evaluate.harness import rate_as_light

    rates = np.linspace(0.0, 1.0, 101, dtype=np.float32)[None]
    for convention, code in (("physical", 0.0), ("spikezoo", 1.0)):
        ours = tfi_light(torch.from_numpy(rates), code, tabulated=True).numpy()
        np.testing.assert_allclose(ours, rate_as_light("tfi", rates, convention), rtol=1e-6, atol=1e-7)
    closed = tfi_light(torch.tensor([0.5]), 0.0, tabulated=False)
    assert closed.item() == pytest.approx(0.5 / 0.75)


def test_the_gate_mixes_between_its_two_images_and_never_passes_nan_or_inf() -> None:
    gate = _mixing_gate()
    binned, tfi = torch.rand(1, 1, 16, 20) * 0.5, torch.rand(1, 1, 16, 20) * 0.5
    out = gate(binned, tfi, binned, 0.0)
    low, high = torch.minimum(binned, tfi), torch.maximum(binned, tfi)
    assert (out >= low - 1e-6).all() and (out <= high + 1e-6).all()
    assert (out - binned).abs().max() > 0.01  # it mixes
    broken = binned.clone()
    broken[0, 0, 0, :3] = torch.tensor([float("nan"), float("inf"), -float("inf")])
    out = gate(broken, tfi, broken, 1.0)
    assert torch.isfinite(out).all() and (out >= 0).all()
    assert RawGate().share(torch.zeros(1, len(FEATURES), 2, 2)).max() < 0.05  # a new gate keeps RMB-Net's frame


def test_a_gate_with_a_long_window_mixes_three_images_by_shares_that_sum_to_at_most_one() -> None:
    gate = _mixing_gate(4, 16)
    binned, tfi, long_tfi = (torch.rand(1, 1, 16, 20) * 0.5 for _ in range(3))
    out = gate(binned, tfi, binned, 1.0, long_tfi)
    stack = torch.cat([binned, tfi, long_tfi], dim=1)
    assert (out >= stack.min(1, keepdim=True).values - 1e-6).all()
    assert (out <= stack.max(1, keepdim=True).values + 1e-6).all()
    share = gate.share(gate_features(binned, tfi, binned, 1.0, long_tfi))
    assert share.shape == (1, 2, 16, 20) and (share > 0.05).all() and (share.sum(1) < 1.0).all()
    # each candidate moves the output: the long one is read, not only its features
    assert (gate(binned, tfi, binned, 1.0, long_tfi * 2) - out).abs().max() > 0.01
    fresh = RawGate(RawGateConfig(tfi_window=4, long_window=16))
    assert fresh.share(torch.zeros(1, len(FEATURES) + len(LONG_FEATURES), 2, 2)).sum(1).max() < 0.1
    with pytest.raises(ValueError, match="long_tfi"):
        gate(binned, tfi, binned, 1.0)
    with pytest.raises(ValueError, match="long_tfi"):
        _mixing_gate()(binned, tfi, binned, 1.0, long_tfi)


def test_mix_gives_the_gates_frame_and_the_shares_it_was_made_of() -> None:
    """``mix`` (the engine's call: candidates stacked) gives ``forward``'s frame and the candidates' shares in it."""
    gate = _mixing_gate(4, 16)
    binned, tfi, long_tfi = (torch.rand(1, 1, 16, 20) * 0.5 for _ in range(3))
    mixed, share = gate.mix(binned, torch.cat([tfi, long_tfi], 1), binned, 1.0)
    torch.testing.assert_close(mixed, gate(binned, tfi, binned, 1.0, long_tfi), rtol=0, atol=0)
    torch.testing.assert_close(share, gate.share(gate_features(binned, tfi, binned, 1.0, long_tfi)))
    torch.testing.assert_close(mixed, (1 - share.sum(1, keepdim=True)) * binned
                               + share[:, :1] * tfi + share[:, 1:] * long_tfi)
    with pytest.raises(ValueError, match="2 TFI candidates, got 1"):
        gate.mix(binned, tfi, binned, 1.0)


@pytest.mark.parametrize("tfi_window, long_window, frame_features", [(0, 0, False), (8, 0, False), (0, 8, False),
                                                                     (4, 8, True)])
def test_full_resolution_mixes_each_binned_frame_as_the_fitting_reads_it(tmp_path: Path, tfi_window: int,
                                                                         long_window: int, frame_features: bool) -> None:
    """Streamed at full resolution, 2x2-averaged, the frames are the gate applied to exactly what the fitting reads:
    RMB-Net's binned frames and raw TFI (TFI-M with a ``tfi_window``: a search of its own beside the detail
    stage's plain TFI; with a ``long_window`` a second candidate of its own) read as light, with the previous binned
    frame (itself at the start); with ``frame_features`` each frame's own disagreement over the whole frame."""
    from rmbvideo.evaluate.harness import SIMULATED_RESPONSE, downsample_2x, sequence_convention
    from rmbvideo.recon.full_resolution import FullResolution
    from rmbvideo.recon.methods import make_reconstructor
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.recon.run import trained_readout
    from rmbvideo.sensor.readout import RmbReadout
    from rmbvideo.train.raw_gate import gate_frames

    seq = simulate_sequence(123, TINY, training=True)
    model = _tiny_model(tmp_path / "m.safetensors")
    gate = _mixing_gate(tfi_window, long_window, frame_features)
    convention = sequence_convention(seq)
    # fp32 on both sides: on a host with bf16 the two runs' frame batches would round differently
    engine = make_reconstructor("rmbnet", model=str(model), input_mode="binned", threads=1, convention=convention,
                                response=SIMULATED_RESPONSE, precision="fp32")
    sink = FrameCollector()
    readout = RmbReadout(trained_readout(engine))  # the one the fitting's binned frames are read through
    reconstruct_stream(seq, FullResolution(engine, readout, step=20, threads=1, raw_gate=gate), sink, chunk_planes=48)
    frames = gate_frames(seq, model, gate.config, precision="fp32")
    assert sorted(sink.frames) == list(range(len(frames))) and len(frames) >= 4
    assert (frames[0].long_tfi is not None) == bool(long_window)
    code = float(convention != "physical")
    previous = frames[0].binned
    tensor = lambda x: torch.from_numpy(np.ascontiguousarray(x, np.float32))[None, None]  # noqa: E731
    for i, frame in enumerate(frames):
        expected = gate(tensor(frame.binned), tensor(frame.tfi), tensor(previous), code,
                        *(tensor(x) for x in frame.candidates[1:]))[0, 0].detach().numpy()
        streamed = downsample_2x(sink.frames[i].image, seq.shape)
        assert np.isfinite(streamed).all()
        np.testing.assert_allclose(streamed, expected, rtol=2e-3, atol=1e-5)
        previous = frame.binned
    assert np.abs(expected - frame.binned).max() > 1e-3  # the gate did mix


def test_frame_features_are_each_frames_own_and_move_the_shares() -> None:
    """The frame features are one value over a frame, read from that frame alone (a batch of two frames gives each the
    features it has alone), and larger where TFI disagrees more with the binned frame; they change the shares."""
    torch.manual_seed(0)
    binned = torch.rand(2, 1, 12, 16) * 0.5 + 0.1
    tfi = binned * torch.tensor([1.0, 2.0]).reshape(2, 1, 1, 1) * (1 + 0.1 * torch.rand(2, 1, 12, 16))
    long_tfi = binned * (1 + 0.05 * torch.rand(2, 1, 12, 16))
    both = gate_features(binned, tfi, binned, 1.0, long_tfi, frame=True)
    assert both.shape[1] == len(FEATURES) + len(LONG_FEATURES) + len(FRAME_FEATURES)
    assert both.shape[1] == RawGateConfig(long_window=8, frame_features=True).feature_count
    for k in range(2):
        alone = gate_features(binned[k:k + 1], tfi[k:k + 1], binned[k:k + 1], 1.0, long_tfi[k:k + 1], frame=True)
        torch.testing.assert_close(both[k:k + 1], alone)
    frame = both[:, -len(FRAME_FEATURES):]
    assert (frame.amax(dim=(2, 3)) == frame.amin(dim=(2, 3))).all() and frame[1, 0, 0, 0] > frame[0, 0, 0, 0] + 1.0
    assert torch.equal(both[:, :-len(FRAME_FEATURES)], gate_features(binned, tfi, binned, 1.0, long_tfi))
    gate = _mixing_gate(4, 8, frame_features=True)
    with torch.no_grad():
        gate.body[0].weight[:, -2:] += 3.0  # lean on the frame features, so a change in them shows
        share = gate.share(both)
        changed = both.clone()
        changed[:, -len(FRAME_FEATURES):] += 2.0
        assert (gate.share(changed) - share).abs().max() > 0.01
        assert torch.isfinite(gate(binned, tfi, binned, 1.0, long_tfi)).all()


def test_fitting_writes_a_gate_that_loads_and_refuses_evaluation_seeds(tmp_path: Path) -> None:
    from rmbvideo.net.weights import load_raw_gate
    from rmbvideo.scenes.random_scenes import EVAL_SEED_START
    from rmbvideo.train.raw_gate import RawGateRecipe, fit_raw_gate

    recipe = RawGateRecipe(gate=RawGateConfig(hidden=4, tfi_reach=30, long_window=8, frame_features=True),
                           capture=TINY, pans=1, videos=0, resets=("zero",), display_videos=0, display_scenes=0,
                           still_scenes=0, pixels=200, steps=30)
    weights = fit_raw_gate(recipe, tmp_path / "gate.safetensors", model=_tiny_model(tmp_path / "m.safetensors"))
    gate, card = load_raw_gate(weights)
    assert gate.config == recipe.gate and len(card.data["captures"]) == 1 and "TFI-8" in card.description
    with pytest.raises(OutputError, match="exists; use --overwrite"):  # refused before the fit: no model is opened
        fit_raw_gate(recipe, weights, model=tmp_path / "absent.safetensors")
    (tmp_path / "other.json").write_text("{}")  # a card alone is somebody's too
    with pytest.raises(OutputError, match="other.json: exists"):
        fit_raw_gate(recipe, tmp_path / "other", model=tmp_path / "absent.safetensors")
    assert np.isfinite([card.metrics["fit_mse"], card.metrics["fit_mse_without_gate"]]).all()
    with pytest.raises(ValueError, match="evaluation seed"):
        simulate_sequence(EVAL_SEED_START, TINY, training=True)
    with pytest.raises(ValueError, match="training seed"):
        simulate_sequence(5, TINY, training=False)


def test_a_weight_file_of_another_kind_is_refused_as_a_gate(tmp_path: Path) -> None:
    from rmbvideo.errors import ModelError
    from rmbvideo.net.weights import load_raw_gate

    with pytest.raises(ModelError, match="raw-gate"):
        load_raw_gate(_tiny_model(tmp_path / "m.safetensors"))


def test_reconstruct_mixes_rmbnet_frames_of_a_1bit_capture_by_default_and_only_those(tmp_path: Path) -> None:
    from rmbvideo.errors import OptionError
    from rmbvideo.io.dat import DatGeometry, write_dat
    from rmbvideo.net.weights import default_raw_gate_path
    from rmbvideo.recon.run import prepare_run

    assert default_raw_gate_path().is_file()  # shipped
    dat = tmp_path / "c.dat"
    write_dat(dat, (np.random.default_rng(0).random((80, 48, 64)) < 0.3).astype(np.uint8), DatGeometry(64, 48))
    assert prepare_run(dat, extra_options={"threads": 1}).method.raw_gate is not None
    assert prepare_run(dat, extra_options={"threads": 1}, raw_gate="off").method.raw_gate is None
    assert prepare_run(dat, method="tfw").method.raw_gate is None  # fitted to RMB-Net's frames, not another method's
    binned = prepare_run(dat, resolution="binned", extra_options={"threads": 1}).method  # the gated frames, half size
    assert binned.raw_gate is not None and binned.output == "binned" and binned.detail is None
    assert not hasattr(prepare_run(dat, resolution="binned", raw_gate="off", extra_options={"threads": 1}).method,
                       "raw_gate")
    with pytest.raises(OptionError, match="--raw-gate"):
        prepare_run(dat, raw_gate="always")


def test_the_shipped_gate_gives_finite_frames_of_a_real_size(tmp_path: Path) -> None:
    """The shipped gate with the shipped models on a small capture: full-size, finite, non-negative frames that differ
    from the ungated ones only where the gate mixed (2x2 averages within TFI's and RMB-Net's range)."""
    from rmbvideo.io.dat import DatGeometry, write_dat
    from rmbvideo.recon.run import reconstruct_frames

    rng = np.random.default_rng(2)
    rate = np.clip(rng.gamma(0.5, 0.1, (48, 64)), 0.0, 0.9)
    dat = tmp_path / "c.dat"
    write_dat(dat, (rng.random((240, 48, 64)) < rate).astype(np.uint8), DatGeometry(64, 48))
    gated = list(reconstruct_frames(dat, width=64, height=48, threads=1))
    plain = list(reconstruct_frames(dat, width=64, height=48, threads=1, raw_gate="off"))
    assert [f.index for f in gated] == [f.index for f in plain] and len(gated) >= 8
    for frame in gated:
        assert frame.image.shape == (48, 64) and np.isfinite(frame.image).all() and (frame.image >= 0).all()
    pooled = [F.avg_pool2d(torch.from_numpy(f.image)[None, None], 2) for f in (gated[4], plain[4])]
    assert not torch.equal(*pooled)


def test_the_gate_loss_adds_the_linear_error_of_display_referred_pixels_only() -> None:
    """"mu-law" is the mu-law MSE of every pixel; "mu-law+display-linear" adds the log of the display-referred pixels'
    linear MSE to its log (the two PSNRs alike), and is the mu-law MSE alone without such pixels."""
    from rmbvideo.cli.train import train_raw_gate
    from rmbvideo.mulaw import mu_law
    from rmbvideo.train.raw_gate import GATE_LOSSES, LOSS_MU, RawGateRecipe, gate_loss

    truth = torch.tensor([0.01, 0.2, 0.5, 0.9])
    mixed = torch.tensor([0.02, 0.25, 0.4, 0.8])
    display = torch.tensor([False, False, True, True])
    mu_mse = ((mu_law(mixed, LOSS_MU) - mu_law(truth, LOSS_MU)) ** 2).mean()
    assert float(gate_loss(mixed, truth, display, "mu-law")) == pytest.approx(float(mu_mse))
    both = float(gate_loss(mixed, truth, display, "mu-law+display-linear"))
    assert both == pytest.approx(float(torch.log(mu_mse)) + np.log((0.1 ** 2 + 0.1 ** 2) / 2), rel=1e-5)
    assert float(gate_loss(mixed, truth, torch.zeros(4, dtype=torch.bool), "mu-law+display-linear")) == pytest.approx(
        float(mu_mse))
    assert tuple(next(p for p in train_raw_gate.params if p.name == "loss").type.choices) == GATE_LOSSES
    # the options' help states the recipe's defaults (written out there: the CLI does not import the recipe to list)
    recipe = RawGateRecipe()
    defaults = {"loss": recipe.loss, "steps": recipe.steps, "display_videos": recipe.display_videos,
                "display_scenes": recipe.display_scenes, "tfi_window": recipe.gate.tfi_window,
                "long_window": recipe.gate.long_window, "pixels": recipe.pixels, "restarts": recipe.restarts,
                "frame_features": "on" if recipe.gate.frame_features else "off"}
    for name, value in defaults.items():
        text = next(p for p in train_raw_gate.params if p.name == name).help
        assert text.rstrip("].").endswith(f" {value}"), (name, text)
    with pytest.raises(ValueError, match="loss"):
        RawGateRecipe(loss="linear")


def test_fitting_refuses_tfi_samples_not_shaped_by_the_gates_candidates() -> None:
    """Candidates as (pixels,) would broadcast against the (pixels, 1) shares into a (pixels, pixels) mix."""
    from rmbvideo.train.raw_gate import GateSamples, RawGateRecipe, fit_gate

    rng = np.random.default_rng(0)
    flat = GateSamples(rng.random((50, len(FEATURES))), rng.random(50), rng.random(50), rng.random(50),
                       np.zeros(50, bool), ("x",))
    recipe = RawGateRecipe(gate=RawGateConfig(hidden=4), steps=2)
    with pytest.raises(ValueError, match="samples.tfi"):
        fit_gate(flat, recipe)
    gate, metrics = fit_gate(GateSamples(flat.features, flat.binned, flat.tfi[:, None], flat.truth, flat.display,
                                         flat.captures), recipe)
    assert np.isfinite(metrics["fit_mse"])


def test_the_fit_keeps_the_restart_of_lowest_loss() -> None:
    """Fits from several initial weights can end in different places (one uses the long candidate, another never
    does): the restart kept is the one whose loss on the drawn pixels is lowest, and its gate is that fit's."""
    from rmbvideo.train.raw_gate import GateSamples, RawGateRecipe, fit_gate, gate_loss

    rng = np.random.default_rng(1)
    n, config = 400, RawGateConfig(hidden=3, long_window=8)
    truth = rng.random(n)
    samples = GateSamples(rng.standard_normal((n, config.feature_count)), truth + 0.3 * rng.standard_normal(n),
                          np.stack([truth + 0.2 * rng.standard_normal(n), truth + 0.1 * rng.standard_normal(n)], 1),
                          truth, np.zeros(n, bool), ("x",))
    gate, metrics = fit_gate(samples, RawGateRecipe(gate=config, steps=40, restarts=3))
    losses = [metrics[f"fit_loss_restart_{k}"] for k in range(3)]
    # the best fit is the middle one here, so keeping the first or the last restart would fail
    assert metrics["restart"] == int(np.argmin(losses)) == 1 and len(set(losses)) == 3
    with torch.no_grad():
        features = torch.from_numpy(samples.features.astype(np.float32)).T[None, :, :, None]
        share = gate.share(features)[0, :, :, 0].T
        mixed = (1 - share.sum(1)) * torch.from_numpy(samples.binned.astype(np.float32)) + (
            share * torch.from_numpy(samples.tfi.astype(np.float32))).sum(1)
        kept = float(gate_loss(mixed, torch.from_numpy(truth.astype(np.float32)), torch.zeros(n, dtype=torch.bool),
                               "mu-law"))
    assert kept == pytest.approx(min(losses), rel=1e-5)
    with pytest.raises(ValueError, match="restarts"):
        RawGateRecipe(restarts=0)


def test_display_referred_streams_are_spikezoo_simulator_streams_only() -> None:
    """The linear term's pixels: spikezoo's noise-free streams (the video kind and the recipe's display-referred
    captures), never a camera's pixel reset by subtraction, though its streams are in the same rate convention."""
    from dataclasses import replace

    from rmbvideo.evaluate.harness import sequence_convention
    from rmbvideo.evaluate.heldout import VIDEO_KINDS, simulate_video_sequence
    from rmbvideo.train.raw_gate import RawGateRecipe, display_referred, training_sequences

    fast = next(k for k in VIDEO_KINDS if k.name == "fast")
    twin = simulate_video_sequence(730_000, replace(fast, name="fast-display", convention="spikezoo"), TINY,
                                   training=True)
    subtract = simulate_sequence(700_000, replace(TINY, reset="subtract"), training=True)
    assert display_referred(twin) and not display_referred(subtract)
    assert sequence_convention(subtract) == "spikezoo" and not display_referred(simulate_sequence(700_000, TINY, True))
    recipe = RawGateRecipe(capture=TINY, pans=0, videos=0, resets=(), display_videos=1, display_scenes=1,
                           still_scenes=1)
    made = list(training_sequences(recipe))  # every physical kind's twin, the training scenes' ranges, a still scene
    assert [display_referred(seq) for seq in made] == [True] * 6 and made[-2].name.startswith("video-display")
    still = made[-1]
    assert still.name.startswith("still-display") and all(np.array_equal(still.gt[i], still.gt[0])
                                                          for i in range(1, len(still.gt)))


def test_train_raw_gate_refuses_a_long_window_not_longer_than_the_first(tmp_path: Path) -> None:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "train-raw-gate", "--tfi-window", "8", "--long-window",
                           "4", "-o", str(tmp_path / "g.safetensors"), "--quiet"], capture_output=True, text=True)
    assert proc.returncode == 2 and "long_window" in proc.stderr and "Traceback" not in proc.stderr
    assert not list(tmp_path.iterdir())


def test_the_gates_tfi_window_is_kept_in_its_card_and_absent_at_zero() -> None:
    """A gate's TFI-M window survives its card; a card from before the window existed (no key) reads 0; the recipe's
    defaults make the shipped gate: its architecture and what it was fitted on (``rmbvideo train-raw-gate`` with no
    options refits it)."""
    from dataclasses import asdict

    from rmbvideo.net.weights import default_raw_gate_path, load_raw_gate
    from rmbvideo.train.raw_gate import RawGateRecipe

    gate, card = load_raw_gate(default_raw_gate_path())
    recipe = RawGateRecipe()
    assert recipe.gate == gate.config
    recorded = {k: v for k, v in card.training.items() if k in asdict(recipe) and k not in ("gate", "capture")}
    assert len(recorded) >= 10 and recorded == {k: (list(v) if isinstance(v, tuple) else v)
                                                for k, v in asdict(recipe).items() if k in recorded}
    config = RawGateConfig(hidden=4, tfi_reach=30, tfi_window=8)
    assert RawGateConfig.from_dict(config.to_dict()) == config
    assert "tfi_window" not in RawGateConfig().to_dict() and RawGateConfig.from_dict({"hidden": 16}).tfi_window == 0
    with pytest.raises(ValueError, match="tfi_window"):
        RawGateConfig(tfi_window=-1)
    config = RawGateConfig(tfi_window=4, long_window=16, frame_features=True)
    assert RawGateConfig.from_dict(config.to_dict()) == config and "long_window" not in RawGateConfig().to_dict()
    assert "frame_features" not in RawGateConfig(tfi_window=4, long_window=16).to_dict()
    with pytest.raises(ValueError, match="long_window"):
        RawGateConfig(tfi_window=8, long_window=8)


def test_a_gate_of_3x3_convolutions_reads_its_neighbourhood_and_a_per_pixel_gate_does_not() -> None:
    """TFI changed at one pixel moves a per-pixel gate's output within the reach of its features' 3x3 roughness (one
    pixel); a gate of two 3x3 convolutions two pixels further and nothing beyond, and it still mixes between its
    images."""
    binned, tfi = torch.rand(1, 1, 16, 20) * 0.5 + 0.1, torch.rand(1, 1, 16, 20) * 0.5 + 0.1
    changed = tfi.clone()
    changed[0, 0, 8, 10] *= 3.0
    for kernel, reach in ((1, 1), (3, 3)):
        torch.manual_seed(3)
        gate = RawGate(RawGateConfig(hidden=4, kernel=kernel))
        with torch.no_grad():
            gate.body[-1].bias.zero_()
        moved = (gate(binned, changed, binned, 0.0) - gate(binned, tfi, binned, 0.0)).abs()[0, 0] > 0
        rows, cols = torch.nonzero(moved, as_tuple=True)
        assert moved[8, 10] and (rows - 8).abs().max() == reach and (cols - 10).abs().max() == reach
        out = gate(binned, tfi, binned, 0.0)
        assert (out >= torch.minimum(binned, tfi) - 1e-6).all() and (out <= torch.maximum(binned, tfi) + 1e-6).all()
    with pytest.raises(ValueError, match="kernel"):
        RawGateConfig(kernel=2)
    config = RawGateConfig(long_window=8, kernel=3)
    assert RawGateConfig.from_dict(config.to_dict()) == config and "kernel" not in RawGateConfig().to_dict()


def test_a_gate_of_3x3_convolutions_is_fitted_on_crops_and_saved_and_loaded(tmp_path: Path) -> None:
    """The recipe draws crops for a gate that reads neighbourhoods, fits it on batches of them (its loss on the
    crops below the binned frame's where TFI is right), and the gate it writes loads with its kernel."""
    from rmbvideo.net.weights import load_raw_gate
    from rmbvideo.train.raw_gate import GateSamples, RawGateRecipe, fit_gate, fit_raw_gate

    rng = np.random.default_rng(0)
    config = RawGateConfig(hidden=4, kernel=3)
    truth = rng.random((12, 10, 10)).astype(np.float32) * 0.5
    samples = GateSamples(rng.standard_normal((12, config.feature_count, 10, 10)),
                          truth + 0.2 * rng.standard_normal(truth.shape), truth[:, None] + 0.01, truth,
                          np.zeros(12, bool), ("x",))
    recipe = RawGateRecipe(gate=config, steps=60, restarts=2, batch=4, lr=3e-2)
    gate, metrics = fit_gate(samples, recipe)
    assert metrics["fit_mse"] < metrics["fit_mse_without_gate"] and metrics["restart"] in (0.0, 1.0)
    with pytest.raises(ValueError, match="crops"):
        fit_gate(GateSamples(samples.features[:, :, 0, 0], samples.binned[:, 0, 0], samples.tfi[:, :, 0, 0],
                             truth[:, 0, 0], samples.display, ("x",)), recipe)
    tiny = RawGateRecipe(gate=RawGateConfig(hidden=4, tfi_reach=30, long_window=8, frame_features=True, kernel=3),
                         capture=TINY, pans=1, videos=0, resets=("zero",), display_videos=0, display_scenes=0,
                         still_scenes=0, crop=16, crops=2, batch=2, steps=5, restarts=1)
    loaded, card = load_raw_gate(fit_raw_gate(tiny, tmp_path / "gate.safetensors",
                                              model=_tiny_model(tmp_path / "m.safetensors")))
    assert loaded.config == tiny.gate and card.training["crops"] == 2
    assert np.isfinite(card.metrics["fit_mse"])


def test_a_model_the_gate_was_not_fitted_to_is_gated_with_one_warning(tmp_path: Path,
                                                                     caplog: pytest.LogCaptureFixture) -> None:
    """The shipped gate was fitted to the shipped network's frames: with another model ``reconstruct`` still gates its
    frames, and says once that the gate was fitted to another network; the shipped model gets no warning."""
    import logging

    from rmbvideo.io.dat import DatGeometry, write_dat
    from rmbvideo.net.weights import default_model_path
    from rmbvideo.recon.run import prepare_run

    dat = tmp_path / "c.dat"
    write_dat(dat, (np.random.default_rng(0).random((80, 48, 64)) < 0.3).astype(np.uint8), DatGeometry(64, 48))
    model = _tiny_model(tmp_path / "mine.safetensors")
    with caplog.at_level(logging.WARNING, logger="rmbvideo.recon.full_resolution"):
        assert prepare_run(dat, extra_options={"threads": 1, "model": str(default_model_path("binned"))}
                           ).method.raw_gate is not None
        gate_warnings = lambda: [r.getMessage() for r in caplog.records  # noqa: E731
                                 if r.name == "rmbvideo.recon.full_resolution"]
        assert not gate_warnings()
        for _ in range(2):
            assert prepare_run(dat, extra_options={"threads": 1, "model": str(model)}).method.raw_gate is not None
    warned = gate_warnings()
    assert len(warned) == 1 and "mine.safetensors" in warned[0] and "rmbnet-binned.safetensors" in warned[0]
