"""Fitting the raw-interval gate (``rmbvideo.net.raw_gate``) to the shipped RMB-Net, on simulated 1-bit captures of
training seeds: panorama pans and the video kinds of the evaluation (fast, dark, fast-dark, spikezoo-fast,
low-contrast), each with both pixels (reset to zero, reset by subtraction). Every capture is run as the evaluation
runs it: RMB-Net on the binned stream, TFI on the raw planes (TFI-M over the gate's ``tfi_window``, and over its
``long_window``) read as light and 2x2-averaged; display-referred captures (spikezoo's 8-bit video values) of every
kind of motion join them. The gate is fitted on crops (pixels, for a per-pixel gate) drawn from every frame to the
mixed frame's mu-law error against the exact ground truth (the recipe can add the linear error of display-referred
captures, as real video is scored: tried, not shipped, ``models/experiments/raw-tfi-gate/results.md``), from several
initial weights: fits end either never mixing the long TFI or mixing it where nothing moves within its span, and the
one of lowest loss is kept.
About 25 minutes of simulation and 40 of fitting on one core; the same seeds give the same gate.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from rmbvideo.evaluate.harness import SATURATION, MethodSpec, run_frames, sequence_convention
from rmbvideo.evaluate.heldout import (FULL, VIDEO_KINDS, HeldoutConfig, Sequence, VideoHeldout, simulate_sequence,
                                       simulate_video_sequence)
from rmbvideo.evaluate.metrics import robust_scale
from rmbvideo.io.atomic import check_file_writable
from rmbvideo.mulaw import mu_law
from rmbvideo.net.raw_gate import RawGate, RawGateConfig, gate_features
from rmbvideo.net.weights import ModelCard, default_model_path, model_paths, model_readout, save_model
from rmbvideo.scenes.video import VideoSceneRanges

log = logging.getLogger(__name__)

#: mu of the loss's tone curve: the evaluation's mu-law PSNR.
LOSS_MU = 5000.0
#: What the gate is fitted to: "mu-law", the mu-law MSE of every pixel; "mu-law+display-linear", the sum of the logs
#: of that and of the linear MSE of the display-referred pixels (the two PSNRs the evaluation reports, weighed alike).
GATE_LOSSES = ("mu-law", "mu-law+display-linear")
#: Display-referred captures of the training scenes' own video ranges (camera speed log-uniform 0.005-1.2 raw px a
#: plane: mostly slow; the real-video streams move 0.12-0.19, ``models/experiments/raw-tfi-gate/slow_display.py``).
VIDEO_DISPLAY = VideoHeldout("video-display", VideoSceneRanges(), "spikezoo")
#: Display-referred captures of a still camera over a still scene (no camera motion, shake or movers): without them
#: the gate mixed TFI-4's grain into still texture (the development clips' still pans lost 5-7 dB to it).
STILL_DISPLAY = VideoHeldout("still-display", VideoSceneRanges(static_probability=1.0, max_objects=0, shake_px=0.0),
                             "spikezoo")


@dataclass(frozen=True)
class RawGateRecipe:
    """What the gate is fitted on and how: ``pans`` panorama pans and ``videos`` sequences of every video kind per
    pixel kind in ``resets`` (spikezoo's kind has no reset: once), then ``display_videos`` sequences of every other
    video kind simulated again in spikezoo's convention (display-referred streams of every kind of motion, not only
    fast), ``display_scenes`` of the training scenes' own video ranges in that convention (mostly slow, as video
    mostly is) and ``still_scenes`` of still scenes in it (``STILL_DISPLAY``), from training seed ``first_seed`` on,
    each of ``capture``'s size and length (the held-out set's); ``pixels`` drawn per frame for a per-pixel gate
    (``kernel`` 1), ``crops`` crops of ``crop`` pixels a side for one that reads neighbourhoods, fitted ``batch`` crops
    a step; ``steps`` of Adam at ``lr`` on ``loss`` (one of ``GATE_LOSSES``) from ``restarts`` initial weights (seeds
    ``seed`` on), the fit of lowest loss kept (``fit_gate``). The defaults are the shipped gate's: two 3x3
    convolutions over TFI over the whole intervals covering 4 central planes (TFI-4) and over 16 (TFI-16), read with
    the frame features (``rmbvideo.net.raw_gate.FRAME_FEATURES``), two display-referred twins of every physical video
    kind, six display-referred captures of the training scenes' video ranges and three of still scenes; two restarts
    of 32,000 steps of 16 crops. The per-pixel gate shipped before it is ``kernel=1, steps=2000, lr=1e-2, restarts=4``
    (500 pixels a frame)."""

    gate: RawGateConfig = RawGateConfig(tfi_window=4, long_window=16, frame_features=True, kernel=3)
    capture: HeldoutConfig = FULL
    pans: int = 6
    videos: int = 2
    resets: tuple[str, ...] = ("zero", "subtract")
    display_videos: int = 2
    display_scenes: int = 6
    still_scenes: int = 3
    first_seed: int = 700_000
    pixels: int = 500
    steps: int = 32_000
    lr: float = 3e-3
    restarts: int = 2
    loss: str = "mu-law"
    seed: int = 0
    crop: int = 48
    crops: int = 6
    batch: int = 16

    def __post_init__(self) -> None:
        if self.restarts < 1:
            raise ValueError(f"restarts must be >= 1, got {self.restarts}")
        if min(self.crop, self.crops, self.batch) < 1:
            raise ValueError(f"crop, crops and batch must be >= 1, got {self.crop}, {self.crops}, {self.batch}")
        if self.loss not in GATE_LOSSES:
            raise ValueError(f"loss must be one of {GATE_LOSSES}, got {self.loss!r}")


def training_sequences(recipe: RawGateRecipe) -> Iterator[Sequence]:
    """The recipe's simulated captures (held-out size and length, training seeds), one at a time."""
    for r, reset in enumerate(recipe.resets):
        config = replace(recipe.capture, reset=reset)
        for j in range(recipe.pans):
            yield simulate_sequence(recipe.first_seed + 1000 * r + j, config, training=True)
        for k, kind in enumerate(VIDEO_KINDS):
            if kind.convention != "physical" and r:
                continue
            for j in range(recipe.videos):
                seed = recipe.first_seed + 10_000 + 1000 * r + 100 * k + j
                yield simulate_video_sequence(seed, kind, replace(config, reset="zero") if kind.convention != "physical"
                                              else config, training=True)
    for k, kind in enumerate(VIDEO_KINDS):
        if kind.convention == "physical":
            for j in range(recipe.display_videos):
                seed = recipe.first_seed + 30_000 + 100 * k + j
                yield simulate_video_sequence(seed, replace(kind, name=f"{kind.name}-display", convention="spikezoo"),
                                              replace(recipe.capture, reset="zero"), training=True)
    for j in range(recipe.display_scenes):
        yield simulate_video_sequence(recipe.first_seed + 40_000 + j, VIDEO_DISPLAY,
                                      replace(recipe.capture, reset="zero"), training=True)
    for j in range(recipe.still_scenes):
        yield simulate_video_sequence(recipe.first_seed + 80_000 + j, STILL_DISPLAY,
                                      replace(recipe.capture, reset="zero"), training=True)


@dataclass(frozen=True)
class GateFrame:
    """One frame as the gate reads it: RMB-Net's binned frame, raw TFI (and the long-window TFI when the gate has
    one) read as light and 2x2-averaged, and the ground truth (clipped at saturation)."""

    binned: np.ndarray
    tfi: np.ndarray
    truth: np.ndarray
    long_tfi: np.ndarray | None = None

    @property
    def candidates(self) -> tuple[np.ndarray, ...]:
        """The TFI images the gate mixes in, in its order."""
        return (self.tfi,) if self.long_tfi is None else (self.tfi, self.long_tfi)


def gate_frames(seq: Sequence, model: Path, gate: RawGateConfig, precision: str = "auto") -> list[GateFrame]:
    """Per frame of ``seq`` (in order), what ``gate`` reads, as the evaluation makes it: RMB-Net's binned frame (at
    ``precision``, ``reconstruct``'s policy by default) and raw TFI over the gate's windows."""
    network = MethodSpec("RMB-Net", "rmbnet", {"model": str(model), "input_mode": "binned", "threads": 1,
                                               "precision": precision}, model_readout(model))
    binned = {f.index: f.image for f in run_frames(network, seq)[0]}
    raws = []
    for window in (gate.tfi_window, gate.long_window)[:gate.candidates]:
        tfi = MethodSpec("TFI (raw)", "tfi", {"step": 20, "max_reach": gate.tfi_reach, "window": window}, raw=True)
        raws.append({f.index: f.image for f in run_frames(tfi, seq)[0]})
    shared = sorted(set(binned).intersection(*raws))
    return [GateFrame(binned[i], raws[0][i], np.minimum(seq.gt[i], SATURATION), raws[1][i] if len(raws) > 1 else None)
            for i in shared]


@dataclass(frozen=True)
class GateSamples:
    """Pixels the gate is fitted on: ``features`` (N, the gate's feature count); ``binned`` and ``truth`` (N,) and
    ``tfi`` (N, candidates) divided by their frame's robust truth scale; ``display`` (N,) True on display-referred
    captures; ``captures`` their names. For a gate that reads neighbourhoods (``kernel`` > 1) each of the N samples is
    a crop: ``features`` (N, count, S, S), ``binned`` and ``truth`` (N, S, S), ``tfi`` (N, candidates, S, S)."""

    features: np.ndarray
    binned: np.ndarray
    tfi: np.ndarray
    truth: np.ndarray
    display: np.ndarray
    captures: tuple[str, ...]


def display_referred(seq: Sequence) -> bool:
    """Whether ``seq`` is a display-referred stream (spikezoo's noise-free simulator: 8-bit video values); a camera's
    pixel reset by subtraction is in the same rate convention but sees radiance."""
    return sequence_convention(seq) == "spikezoo" and json.loads(seq.description or "{}").get("reset") != "subtract"


def _samples(seq: Sequence, frames: list[GateFrame], recipe: RawGateRecipe,
             rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Features, binned, TFI candidates and truth at ``recipe.pixels`` pixels of every frame (a gate of ``kernel``
    1), or in ``recipe.crops`` crops of ``recipe.crop`` pixels a side (a gate that reads neighbourhoods: each crop's
    features computed on the whole frame), the images divided by the truth's robust scale (as the evaluation's
    metrics divide them)."""
    convention = float(sequence_convention(seq) != "physical")
    tensor = lambda x: torch.from_numpy(np.ascontiguousarray(x, np.float32))[None, None]  # noqa: E731
    out: list[list[np.ndarray]] = [[], [], [], []]
    previous = frames[0].binned
    for frame in frames:
        features = gate_features(tensor(frame.binned), tensor(frame.tfi), tensor(previous), convention,
                                 *(tensor(x) for x in frame.candidates[1:]), frame=recipe.gate.frame_features)[0]
        features = features.numpy()
        scale = robust_scale(frame.truth)
        images = [frame.binned / scale, np.stack(frame.candidates) / scale, frame.truth / scale]
        if recipe.gate.kernel == 1:
            pick = rng.integers(0, frame.binned.size, recipe.pixels)
            out[0].append(features.reshape(features.shape[0], -1)[:, pick].T)
            out[1].append(images[0].ravel()[pick].astype(np.float32))
            out[2].append(images[1].reshape(len(frame.candidates), -1)[:, pick].T.astype(np.float32))
            out[3].append(images[2].ravel()[pick].astype(np.float32))
        else:
            height, width = frame.binned.shape
            size = min(recipe.crop, height, width)
            for _ in range(recipe.crops):
                y, x = int(rng.integers(0, height - size + 1)), int(rng.integers(0, width - size + 1))
                window = (..., slice(y, y + size), slice(x, x + size))
                for k, image in enumerate((features, *images)):
                    out[k].append(image[window][None].astype(np.float32))
        previous = frame.binned
    return tuple(np.concatenate(x) for x in out)


def gather_samples(recipe: RawGateRecipe, model: Path, progress: bool = False) -> GateSamples:
    """Simulate the recipe's captures, run ``model`` and raw TFI on each and draw the recipe's pixels."""
    rng = np.random.default_rng(recipe.seed)
    parts: list[tuple[np.ndarray, ...]] = []
    display: list[np.ndarray] = []
    names = []
    for seq in tqdm(training_sequences(recipe), desc="captures", unit="capture", disable=not progress):
        parts.append(_samples(seq, gate_frames(seq, model, recipe.gate), recipe, rng))
        display.append(np.full(len(parts[-1][1]), display_referred(seq)))
        names.append(seq.name)
    features, binned, tfi, truth = (np.concatenate(x) for x in zip(*parts))
    return GateSamples(features, binned, tfi, truth, np.concatenate(display), tuple(names))


def gate_loss(mixed: torch.Tensor, truth: torch.Tensor, display: torch.Tensor, loss: str) -> torch.Tensor:
    """The recipe's ``loss`` (``GATE_LOSSES``) of mixed pixels against the truth (both divided by the truth's robust
    scale); without display-referred pixels, the mu-law MSE alone."""
    tone = lambda v: mu_law(v.clamp(0.0, 1.0), LOSS_MU)  # noqa: E731
    mu_mse = ((tone(mixed) - tone(truth)) ** 2).mean()
    if loss == "mu-law" or not bool(display.any()):
        return mu_mse
    linear_mse = ((mixed[display] - truth[display]) ** 2).mean()
    return torch.log(mu_mse) + torch.log(linear_mse)


def _mix(gate: RawGate, features: torch.Tensor, binned: torch.Tensor, tfi: torch.Tensor) -> torch.Tensor:
    """The gate's mixture of samples: pixels (``features`` (N, F)) through its 1x1 convolutions as one (1, F, N, 1)
    image, or crops (``features`` (N, F, S, S)) as they are."""
    if features.dim() == 2:
        share = gate.share(features.T[None, :, :, None])[0, :, :, 0].T
    else:
        share = gate.share(features)
    return (1.0 - share.sum(1)) * binned + (share * tfi).sum(1)


def fit_gate(samples: GateSamples, recipe: RawGateRecipe, progress: bool = False) -> tuple[RawGate, dict[str, float]]:
    """A gate fitted to ``samples`` by the recipe's Adam steps and loss, from ``recipe.restarts`` initial weights
    (seeds ``recipe.seed`` on), keeping the fit of lowest loss on the samples; also the mu-law and display-referred
    linear MSE with and without it, and each restart's final loss. A per-pixel gate (``kernel`` 1) takes every
    pixel at each step at a constant rate; a gate that reads neighbourhoods takes ``recipe.batch`` crops drawn at
    each step, its rate falling along a cosine to a tenth."""
    features, binned, tfi, truth = (torch.from_numpy(np.ascontiguousarray(x, np.float32))
                                    for x in (samples.features, samples.binned, samples.tfi, samples.truth))
    expected = (len(truth), recipe.gate.candidates, *truth.shape[1:])
    if tfi.shape != expected:  # (N,) would broadcast against the shares into (N, N)
        raise ValueError(f"samples.tfi must be {expected}, got {tuple(tfi.shape)}")
    crops = recipe.gate.kernel > 1
    if crops != (features.dim() == 4):
        raise ValueError(f"a gate of kernel {recipe.gate.kernel} is fitted on "
                         f"{'crops' if crops else 'pixels'}, got features of shape {tuple(features.shape)}")
    display = torch.from_numpy(samples.display).reshape(-1, *[1] * (truth.dim() - 1)).expand_as(truth)

    def whole(gate: RawGate) -> torch.Tensor:
        """The gate's mixture of every sample (crops a few hundred at a time)."""
        if not crops:
            return _mix(gate, features, binned, tfi)
        return torch.cat([_mix(gate, features[k:k + 256], binned[k:k + 256], tfi[k:k + 256])
                          for k in range(0, len(truth), 256)])

    fits: list[tuple[float, RawGate]] = []
    for restart in range(recipe.restarts):
        torch.manual_seed(recipe.seed + restart)
        draw = np.random.default_rng([recipe.seed, restart])
        gate = RawGate(recipe.gate)
        with torch.no_grad():
            axes = (0, 2, 3) if crops else (0,)
            gate.feature_mean.copy_(features.mean(axes))
            gate.feature_std.copy_(features.std(axes))
        optimiser = torch.optim.Adam(gate.body.parameters(), lr=recipe.lr)
        for step in tqdm(range(recipe.steps), desc=f"fitting ({restart + 1}/{recipe.restarts})", unit="step",
                         disable=not progress):
            if crops:
                for group in optimiser.param_groups:
                    group["lr"] = recipe.lr * (0.55 + 0.45 * math.cos(math.pi * step / recipe.steps))
                pick = torch.from_numpy(draw.integers(0, len(truth), recipe.batch))
                mixed = _mix(gate, features[pick], binned[pick], tfi[pick])
                loss = gate_loss(mixed.flatten(), truth[pick].flatten(), display[pick].flatten(), recipe.loss)
            else:
                loss = gate_loss(_mix(gate, features, binned, tfi), truth, display, recipe.loss)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        with torch.no_grad():
            final = gate_loss(whole(gate).flatten(), truth.flatten(), display.flatten(), recipe.loss)
            fits.append((float(final), gate))
        log.info("raw gate: restart %d of %d, loss %.6g", restart + 1, recipe.restarts, fits[-1][0])
    best = min(range(len(fits)), key=lambda k: fits[k][0])
    gate = fits[best][1]
    metrics = {"restart": float(best), **{f"fit_loss_restart_{k}": loss for k, (loss, _) in enumerate(fits)}}
    shown = display.flatten()
    with torch.no_grad():
        for suffix, image in (("", whole(gate).flatten()), ("_without_gate", binned.flatten())):
            metrics[f"fit_mse{suffix}"] = float(gate_loss(image, truth.flatten(), shown, "mu-law"))
            if bool(shown.any()):
                metrics[f"fit_display_linear_mse{suffix}"] = float(((image - truth.flatten())[shown] ** 2).mean())
    return gate, metrics


def fit_raw_gate(recipe: RawGateRecipe, out: Path, model: Path | None = None, progress: bool = False,
                 overwrite: bool = False) -> Path:
    """Simulate the recipe's captures, fit the gate to ``model`` (the shipped binned RMB-Net when None) and save it
    as ``out`` (.safetensors + card); returns the weights path. Existing weights or card at ``out`` are refused
    before the fit unless ``overwrite``."""
    for path in model_paths(out):
        check_file_writable(path, overwrite)
    model = model or default_model_path("binned")
    began = time.perf_counter()
    samples = gather_samples(recipe, model, progress)
    gate, metrics = fit_gate(samples, recipe, progress)
    minutes = (time.perf_counter() - began) / 60
    log.info("raw gate: mu-law MSE %.3g with the gate, %.3g without (%d pixels, %.1f min)", metrics["fit_mse"],
             metrics["fit_mse_without_gate"], len(samples.truth), minutes)
    card = ModelCard(
        name=out.stem,
        description="Raw-interval gate of 1-bit captures: RMB-Net's binned frame mixed per pixel "
                    + (f"(two {recipe.gate.kernel}x{recipe.gate.kernel} convolutions reading its neighbourhood) "
                       if recipe.gate.kernel > 1 else "")
                    + "with raw TFI "
                    + (f"over the whole intervals covering {recipe.gate.tfi_window} central planes (TFI-"
                       f"{recipe.gate.tfi_window}) " if recipe.gate.tfi_window else "")
                    + (f"and TFI-{recipe.gate.long_window} " if recipe.gate.long_window else "")
                    + "(rmbvideo.net.raw_gate), fitted to the binned RMB-Net named in data.",
        training={**{k: v for k, v in asdict(recipe).items() if k not in ("gate", "capture")},
                  "capture": {k: v for k, v in asdict(recipe.capture).items() if k in ("width", "height", "readouts")},
                  "loss_mu": LOSS_MU,
                  "optimizer": "Adam", "wall_minutes": round(minutes, 1)},
        data={"model": model.name, "captures": list(samples.captures),
              ("crops" if recipe.gate.kernel > 1 else "pixels"): len(samples.truth)},
        metrics=metrics,
    )
    return save_model(out, gate, card)
