"""Training of the full-resolution detail stage (``rmbvideo.net.detail``) on simulated video scenes.

A sample is one frame of a video scene (``rmbvideo.scenes.video``) captured as 1-bit planes at the
camera's resolution (the physical emission model with a real camera's noise, or spikezoo's rate
convention): the raw TFP rates over the stage's windows, centred on the frame, the exact
full-resolution ground truth at the frame's centre, and, as the binned input, the ground truth's 2x2
block means. The stage only learns how a block's level is shared among its pixels, so it does not need
the binned network in the loop. Loss: L1 of mu-law tone-mapped frames after dividing by the ground
truth's 99.9th percentile (the evaluation's domain). Checkpoints (weights and Adam state) every
``checkpoint_every`` steps; ``resume`` continues from them.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.mulaw import mu_law
from rmbvideo.net.detail import DetailConfig, DetailNet
from rmbvideo.errors import InputError
from rmbvideo.io.atomic import signals_deferred
from rmbvideo.net.weights import ModelCard, load_detail_model, save_model
from rmbvideo.recon.classical import Tfi
from rmbvideo.recon.full_resolution import DEFAULT_DETAIL_WINDOW, relative_detail, to_block_levels, upsample
from rmbvideo.scenes.random_scenes import EVAL_SEED_START
from rmbvideo.scenes.video import VideoScene
from rmbvideo.simulate.capture import capture_planes
from rmbvideo.train.checkpoint import (
    CheckpointState,
    checkpoint_paths,
    checkpointed_on_stop,
    load_checkpoint,
    refuse_to_restart_over,
    save_checkpoint,
)
from rmbvideo.train.dataset import RAW_RATE_HZ
from rmbvideo.train.loop import machine_description

log = logging.getLogger(__name__)

MU = 5000.0
#: TFI's reach (raw planes each side of the frame centre) for a new detail stage: two frames' worth.
INTERVAL_REACH = 40


@dataclass(frozen=True)
class DetailTrainConfig:
    """``crop``: binned size of a sample (the capture is twice that); a pool of ``pool`` samples is
    kept and ``new_per_step`` of them replaced every step (simulation is the slow part). Training stops
    at ``minutes`` of wall time or after ``steps`` steps in all (None: no step limit); the learning rate's
    cosine runs over ``steps`` when it is given (the same schedule however busy the machine), else over
    ``minutes``."""

    detail: DetailConfig = field(default_factory=lambda: DetailConfig(interval_reach=INTERVAL_REACH))
    crop: int = 48
    batch: int = 8
    pool: int = 64
    new_per_step: int = 1
    lr: float = 1e-3
    lr_final: float = 1e-4
    minutes: float = 25.0
    steps: int | None = None
    seed: int = 5
    spikezoo_fraction: float = 0.3
    #: the physical captures' threshold mismatch (their fixed pattern) per sample, drawn uniformly between these
    #: multiples of the paper's (a real camera's may be weaker: ``models/experiments/camera-fixed-pattern``)
    mismatch: tuple[float, float] = (1.0, 1.0)
    val_count: int = 12
    val_every: int = 200
    checkpoint_every: int = 50


@dataclass
class DetailSample:
    """``binned`` (h, w) ground-truth block means; ``rates`` (K, 2h, 2w) raw TFP rates (then TFI when the
    stage reads it); ``gt`` (2h, 2w)."""

    binned: np.ndarray
    rates: np.ndarray
    gt: np.ndarray


def simulate_detail_sample(seed: int, crop: int, windows: tuple[int, ...], spikezoo_fraction: float,
                           interval_reach: int = 0, mismatch: tuple[float, float] = (1.0, 1.0),
                           interval_windows: tuple[int, ...] = ()) -> DetailSample:
    """The sample of ``seed``: a frame at raw plane time ``max(windows)/2 + 10`` (at least
    ``interval_reach`` + 1), every window centred on it; TFI there (``Tfi`` itself) when
    ``interval_reach`` > 0, then TFI over each of ``interval_windows`` central planes; a physical capture's threshold
    mismatch drawn in ``mismatch`` (times the paper's)."""
    rng = np.random.default_rng([seed, 0xDE7A])
    convention = "spikezoo" if rng.random() < spikezoo_fraction else "physical"
    centre = max(max(windows) // 2 + 10, interval_reach + 1)
    planes = 2 * centre
    scene = VideoScene(seed, 2 * crop, 2 * crop, planes, convention=convention)
    # drawn last from ``rng``, so the samples are as before the mismatch was drawn (uniform(1, 1) is exactly 1)
    chunks = list(capture_planes(scene, planes, RAW_RATE_HZ, mismatch=float(rng.uniform(*mismatch))))
    raw = np.concatenate([c.planes for c in chunks]).astype(np.float32)
    rates = [raw[centre - w // 2: centre - w // 2 + w].mean(axis=0) for w in windows]
    for window in (0, *interval_windows) if interval_reach else ():
        # frame 0 is centred on plane time `centre`
        tfi = Tfi(step=2 * centre, max_reach=interval_reach, window=window)
        frames = [f for c in chunks for f in tfi.push(c)] + tfi.flush()
        rates.append(frames[0].image)
    rates = np.stack(rates)
    gt = scene.render(float(centre)).astype(np.float32)
    binned = gt.reshape(crop, 2, crop, 2).mean(axis=(1, 3))
    return DetailSample(binned=binned, rates=rates, gt=gt)


def detail_description(detail: DetailConfig) -> str:
    """The model card's one-line description of a stage of ``detail``."""
    tfi = (f", TFI at a {detail.interval_reach}-plane reach" if detail.interval_reach else "") + "".join(
        f", TFI-{w}" for w in detail.interval_windows)
    return ("Detail stage for --resolution full: how each 2x2 block's level is shared among its pixels, from the raw "
            "TFP rates over " + "/".join(map(str, detail.windows)) + " planes" + tfi)


def detail_loss(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Mean L1 of mu-law frames after dividing both by each ground truth's 99.9th percentile."""
    scale = torch.quantile(gt.flatten(1), 0.999, dim=1).clamp(min=1e-6).reshape(-1, 1, 1, 1)
    return (mu_law(pred / scale, MU) - mu_law(gt / scale, MU)).abs().mean()


def _batch(samples: list[DetailSample]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    def stack(name: str) -> torch.Tensor:
        return torch.from_numpy(np.stack([getattr(s, name) for s in samples]))

    binned, rates, gt = stack("binned"), stack("rates"), stack("gt")
    return binned[:, None], rates, gt[:, None]


@torch.no_grad()
def validate(model: DetailNet, samples: list[DetailSample], windows: tuple[int, ...]) -> dict[str, float]:
    """mu-law PSNR of the stage, of bilinear upsampling and of the classical Wiener detail
    (``rmbvideo.recon.full_resolution``, TFP over its window when the stage reads it, else the
    shortest) on ``samples``."""
    model.eval()
    scores: dict[str, list[float]] = {"learned": [], "bilinear": [], "classical": []}
    k = windows.index(DEFAULT_DETAIL_WINDOW) if DEFAULT_DETAIL_WINDOW in windows else 0
    for s in samples:
        binned, rates, _ = _batch([s])
        scores["learned"].append(mu_law_psnr(model(binned, rates)[0, 0].numpy(), s.gt))
        scores["bilinear"].append(mu_law_psnr(upsample(s.binned), s.gt))
        detail = relative_detail(s.rates[k], windows[k])
        scores["classical"].append(mu_law_psnr(to_block_levels(upsample(s.binned) * detail, s.binned), s.gt))
    model.train()
    return {k: float(np.mean(v)) for k, v in scores.items()}


def train_detail(config: DetailTrainConfig, out_dir: Path, name: str = "detail-binned",
                 resume: bool = False, progress: bool = False, init: Path | None = None, overwrite: bool = False) -> Path:
    """Train for ``config.minutes`` of wall time (a progress bar in seconds when ``progress``); write
    ``out_dir/<name>.safetensors`` + card and return it. ``init``: a detail stage's weights to start from (a fine-tune,
    with a fresh optimizer; its architecture must be ``config.detail``, or that with fewer ``interval_windows``:
    then the new inputs start with zero weights, ``DetailNet.widened``). A checkpoint in ``out_dir`` is refused
    unless ``resume`` or ``overwrite``."""
    out_dir = Path(out_dir)
    if not resume and not overwrite:
        refuse_to_restart_over(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(config.seed)
    model = DetailNet(config.detail)
    if init is not None and not resume:
        start, _ = load_detail_model(init)
        try:
            model.load_state_dict(start.widened(config.detail).state_dict())
        except ValueError:
            raise InputError(f"{init}: a detail stage of another architecture ({start.config}, not "
                             f"{config.detail})") from None
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    state = load_checkpoint(out_dir, model, optimizer) if resume else CheckpointState(0, 0.0)
    windows = config.detail.windows
    rng = np.random.default_rng([config.seed, state.step])
    base = (config.seed % 9) * 100_000  # training seeds, below the evaluation seeds
    next_seed = iter(range(base + config.pool + state.step * config.new_per_step, EVAL_SEED_START))

    def simulate(seed: int) -> DetailSample:
        return simulate_detail_sample(seed, config.crop, windows, config.spikezoo_fraction,
                                      config.detail.interval_reach, config.mismatch, config.detail.interval_windows)

    val = [simulate(EVAL_SEED_START + 500_000 + k) for k in range(config.val_count)]
    pool = [simulate(base + k) for k in range(config.pool)]
    log_path = out_dir / "loss.csv"
    first = not (resume and log_path.exists())
    handle = log_path.open("w" if first else "a", newline="")
    writer = csv.writer(handle)
    if first:
        writer.writerow(["step", "elapsed_s", "lr", "loss", "val_learned", "val_bilinear", "val_classical"])
    budget = config.minutes * 60.0
    start = time.monotonic() - state.elapsed_s
    step, metrics = state.step, {}
    bar = tqdm(total=round(budget), initial=round(state.elapsed_s), disable=not progress, unit="s", desc=name)
    with checkpointed_on_stop(out_dir, model, optimizer, lambda: CheckpointState(step, time.monotonic() - start)):
        try:
            while time.monotonic() - start < budget and (config.steps is None or step < config.steps):
                progress = min(step / config.steps if config.steps else (time.monotonic() - start) / budget, 1.0)
                lr = config.lr_final + 0.5 * (config.lr - config.lr_final) * (1 + math.cos(math.pi * progress))
                for group in optimizer.param_groups:
                    group["lr"] = lr
                for _ in range(config.new_per_step):
                    pool[int(rng.integers(len(pool)))] = simulate(next(next_seed))
                chosen = [pool[int(k)] for k in rng.choice(len(pool), config.batch, replace=False)]
                binned, rates, gt = _batch(chosen)
                if rng.random() < 0.5:  # flips: the same statistics, more variety
                    binned, rates, gt = binned.flip(-1), rates.flip(-1), gt.flip(-1)
                loss = detail_loss(model(binned, rates), gt)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                with signals_deferred():  # a stop lands before or after a whole step, never inside one
                    optimizer.step()
                    step += 1
                row = [step, f"{time.monotonic() - start:.1f}", f"{lr:.3g}", f"{float(loss.detach()):.5g}", "", "", ""]
                if step % config.val_every == 0:
                    metrics = validate(model, val, windows)
                    row[4:] = [f"{metrics[k]:.3f}" for k in ("learned", "bilinear", "classical")]
                    log.info("detail step %d: val mu-PSNR learned %.2f, bilinear %.2f, classical %.2f dB",
                             step, metrics["learned"], metrics["bilinear"], metrics["classical"])
                writer.writerow(row)
                bar.update(round(time.monotonic() - start) - bar.n)
                if step % config.checkpoint_every == 0:
                    handle.flush()
                    save_checkpoint(out_dir, model, optimizer, CheckpointState(step, time.monotonic() - start))
        finally:
            handle.close()
            bar.close()
        save_checkpoint(out_dir, model, optimizer, CheckpointState(step, time.monotonic() - start))
    metrics = validate(model, val, windows)
    card = ModelCard(
        name=name,
        description=detail_description(config.detail),
        training={"config": {k: v for k, v in asdict(config).items() if k != "detail"}, "steps_done": step,
                  **({"init": str(init)} if init is not None else {}),
                  "wall_time_s": round(time.monotonic() - start, 1), "machine": machine_description(torch.device("cpu")),
                  "optimizer": f"Adam, lr {config.lr} cosine to {config.lr_final} over the "
                               + (f"{config.steps}-step budget" if config.steps else "wall-time budget"),
                  "loss": "L1 of mu-law (mu=5000) frames after dividing by the ground truth's 99.9th percentile",
                  "checkpoint": str(checkpoint_paths(out_dir)[0].name)},
        data={"description": "video scenes (rmbvideo.scenes.video), 1-bit captures at twice the binned size "
                             f"({100 * (1 - config.spikezoo_fraction):.0f} % physical emission with a camera's noise, "
                             + (f"threshold mismatch {config.mismatch[0]:g}-{config.mismatch[1]:g}x the paper's, "
                                if config.mismatch != (1.0, 1.0) else "")
                             + f"{100 * config.spikezoo_fraction:.0f} % spikezoo's rate convention), ground truth "
                             "at the frame's centre, binned input = its 2x2 block means",
              "val_seeds": f"{EVAL_SEED_START + 500_000}..{EVAL_SEED_START + 500_000 + config.val_count - 1}"},
        metrics={f"val_mu_psnr_{k}": round(v, 3) for k, v in metrics.items()},
    )
    return save_model(out_dir / name, model, card)
