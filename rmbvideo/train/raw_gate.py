"""Fitting the raw-interval gate (``rmbvideo.net.raw_gate``) to the shipped RMB-Net, on simulated 1-bit captures of
training seeds: panorama pans and the video kinds of the evaluation (fast, dark, fast-dark, spikezoo-fast,
low-contrast), each with both pixels (reset to zero, reset by subtraction). Every capture is run as the evaluation
runs it: RMB-Net on the binned stream, TFI on the raw planes read as light and 2x2-averaged; the gate is fitted to
the mu-law error of the mixed frame against the exact ground truth on pixels drawn from every frame. A few minutes
of simulation and fitting on one core; the same seeds give the same gate.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from rmbvideo.evaluate.harness import SATURATION, MethodSpec, run_frames, sequence_convention
from rmbvideo.evaluate.heldout import (FULL, VIDEO_KINDS, HeldoutConfig, Sequence, simulate_sequence,
                                       simulate_video_sequence)
from rmbvideo.evaluate.metrics import robust_scale
from rmbvideo.mulaw import mu_law
from rmbvideo.net.raw_gate import FEATURES, RawGate, RawGateConfig, gate_features
from rmbvideo.net.weights import ModelCard, default_model_path, model_readout, save_model

log = logging.getLogger(__name__)

#: mu of the loss's tone curve: the evaluation's mu-law PSNR.
LOSS_MU = 5000.0


@dataclass(frozen=True)
class RawGateRecipe:
    """What the gate is fitted on and how: ``pans`` panorama pans and ``videos`` sequences of every video kind per
    pixel kind in ``resets`` (spikezoo's kind has no reset: once), from training seed ``first_seed`` on, each of
    ``capture``'s size and length (the held-out set's); ``pixels`` drawn per frame, ``steps`` of Adam at ``lr``,
    initial weights from ``seed``."""

    gate: RawGateConfig = RawGateConfig()
    capture: HeldoutConfig = FULL
    pans: int = 6
    videos: int = 2
    resets: tuple[str, ...] = ("zero", "subtract")
    first_seed: int = 700_000
    pixels: int = 2000
    steps: int = 2000
    lr: float = 3e-3
    seed: int = 0


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


def frame_triples(seq: Sequence, model: Path, reach: int,
                  precision: str = "auto") -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per frame of ``seq`` (in order): RMB-Net's binned frame (at ``precision``, ``reconstruct``'s policy by default),
    raw TFI read as light and 2x2-averaged, and the ground truth, as the evaluation makes them."""
    network = MethodSpec("RMB-Net", "rmbnet", {"model": str(model), "input_mode": "binned", "threads": 1,
                                               "precision": precision}, model_readout(model))
    tfi = MethodSpec("TFI (raw)", "tfi", {"step": 20, "max_reach": reach}, raw=True)
    binned = {f.index: f.image for f in run_frames(network, seq)[0]}
    raw = {f.index: f.image for f in run_frames(tfi, seq)[0]}
    return [(binned[i], raw[i], np.minimum(seq.gt[i], SATURATION)) for i in sorted(set(binned) & set(raw))]


def _samples(seq: Sequence, triples: list, recipe: RawGateRecipe,
             rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Features, binned, TFI and truth at ``recipe.pixels`` pixels of every frame, the images divided by the truth's
    robust scale (as the evaluation's metrics divide them)."""
    convention = float(sequence_convention(seq) != "physical")
    out: list[list[np.ndarray]] = [[], [], [], []]
    previous = triples[0][0]
    for binned, tfi, truth in triples:
        images = [torch.from_numpy(np.ascontiguousarray(x, np.float32))[None, None] for x in (binned, tfi, previous)]
        features = gate_features(*images, convention)[0].reshape(len(FEATURES), -1).numpy()
        pick = rng.integers(0, binned.size, recipe.pixels)
        scale = robust_scale(truth)
        out[0].append(features[:, pick].T)
        for k, image in enumerate((binned, tfi, truth), start=1):
            out[k].append((image / scale).ravel()[pick].astype(np.float32))
        previous = binned
    return tuple(np.concatenate(x) for x in out)


def fit_raw_gate(recipe: RawGateRecipe, out: Path, model: Path | None = None, progress: bool = False) -> Path:
    """Simulate the recipe's captures, fit the gate to ``model`` (the shipped binned RMB-Net when None) and save it
    as ``out`` (.safetensors + card); returns the weights path."""
    model = model or default_model_path("binned")
    began = time.perf_counter()
    rng = np.random.default_rng(recipe.seed)
    parts: list[tuple[np.ndarray, ...]] = []
    names = []
    for seq in tqdm(training_sequences(recipe), desc="captures", unit="capture", disable=not progress):
        parts.append(_samples(seq, frame_triples(seq, model, recipe.gate.tfi_reach), recipe, rng))
        names.append(seq.name)
    features, binned, tfi, truth = (torch.from_numpy(np.concatenate(x)) for x in zip(*parts))
    torch.manual_seed(recipe.seed)
    gate = RawGate(recipe.gate)
    with torch.no_grad():
        gate.feature_mean.copy_(features.mean(0))
        gate.feature_std.copy_(features.std(0))
    optimiser = torch.optim.Adam(gate.body.parameters(), lr=recipe.lr)
    x = features.T[None, :, :, None]  # the pixels as a (1, F, P, 1) image: the gate's 1x1 convolutions per pixel
    tone = lambda v: mu_law(v.clamp(0.0, 1.0), LOSS_MU)  # noqa: E731
    target = tone(truth)
    for _ in tqdm(range(recipe.steps), desc="fitting", unit="step", disable=not progress):
        share = gate.share(x)[0, 0, :, 0]
        loss = ((tone((1.0 - share) * binned + share * tfi) - target) ** 2).mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        share = gate.share(x)[0, 0, :, 0]
        fitted = float(((tone((1.0 - share) * binned + share * tfi) - target) ** 2).mean())
        kept = float(((tone(binned) - target) ** 2).mean())
    minutes = (time.perf_counter() - began) / 60
    log.info("raw gate: mu-law MSE %.3g with the gate, %.3g without (%d pixels, %.1f min)", fitted, kept,
             len(truth), minutes)
    card = ModelCard(
        name=out.stem,
        description="Raw-interval gate of 1-bit captures: RMB-Net's binned frame mixed per pixel with raw TFI "
                    "(rmbvideo.net.raw_gate), fitted to the binned RMB-Net named in data.",
        training={**{k: v for k, v in asdict(recipe).items() if k not in ("gate", "capture")},
                  "capture": {k: v for k, v in asdict(recipe.capture).items() if k in ("width", "height", "readouts")}, "loss": "mu-law MSE (mu 5000)",
                  "optimizer": "Adam", "wall_minutes": round(minutes, 1)},
        data={"model": model.name, "captures": names, "pixels": len(truth)},
        metrics={"fit_mse": fitted, "fit_mse_without_gate": kept},
    )
    return save_model(out, gate, card)
