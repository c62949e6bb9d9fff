"""The RMB-Net training loop: cached random-scene samples, Adam, truncated back-propagation
through time over the ConvLSTM, a wall-time budget, resumable checkpoints, a CSV loss log, and a
model card with held-out validation at the end.

Each sample has F = 2w + K preliminary frames; the network makes K consecutive outputs (frames
w .. w+K-1, every window inside the sample), carrying its ConvLSTM state from one to the next.
The K outputs are cut into segments of ``tbptt`` outputs: each segment encodes only the frames
its windows need, back-propagates its own loss, and hands the state to the next segment detached,
so the autograd graph never spans more than ``tbptt`` steps. Gradients of all segments are
accumulated into one Adam step per batch.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import os
import platform
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from rmbvideo.errors import InputError
from rmbvideo.io.atomic import atomic_write_text, signals_deferred
from rmbvideo.net.decoder import DecoderState
from rmbvideo.net.model import RmbNet, priming_frames, window_indices, window_reach, window_valid
from rmbvideo.net.weights import (ModelCard, bundled_path, default_model_path, load_model, save_model, widen_model,
                                   without_window)
from rmbvideo.recon.precision import uses_bf16
from rmbvideo.scenes.random_scenes import (
    EVAL_SEED_START,
    HELD_OUT_PANORAMA,
    TRAIN_PANORAMAS,
)
from rmbvideo.sensor.effects import REALISTIC_EFFECTS
from rmbvideo.threads import default_threads
from rmbvideo.train.checkpoint import (
    CheckpointState,
    checkpoint_paths,
    checkpointed_on_stop,
    load_checkpoint,
    refuse_to_restart_over,
    save_checkpoint,
)
from rmbvideo.train.batch import Batch, output_range
from rmbvideo.train.config import TrainConfig
from rmbvideo.train.dataset import Sample, SampleCache, SamplePrefetcher
from rmbvideo.train.loss import LossConfig, reconstruction_loss, temporal_loss
from rmbvideo.train.validation import validate

log = logging.getLogger(__name__)

LOG_COLUMNS = ("step", "elapsed_s", "lr", "loss", "l2", "ssim", "edge", "val_mu_psnr", "val_mu_ssim",
               "val_tfw_mu_psnr", "linear", "regional", "temporal")
#: The training loss and its parts, as ``train_batch`` reports them.
LOSS_PARTS = ("loss", "l2", "ssim", "edge", "linear", "regional", "temporal")


@dataclass(frozen=True)
class TrainResult:
    """What a run produced: the weight file, steps done, wall time, why it stopped, final metrics."""

    weights: Path
    steps: int
    elapsed_s: float
    stopped_by: str
    metrics: dict[str, float]


def detach_state(state: DecoderState | None) -> DecoderState | None:
    """The ConvLSTM state cut from the autograd graph (the truncation point of TBPTT)."""
    if state is None:
        return None
    return tuple((h.detach(), c.detach()) for h, c in state)  # type: ignore[return-value]


@dataclass
class SegmentLoss:
    """One TBPTT segment: its share of the batch loss (sum over its outputs / K), the loss parts
    summed over its outputs, and the recurrent state it started from (detached, or None)."""

    loss: torch.Tensor
    parts: dict[str, float]
    state_in: DecoderState | None


def _encode_all(model: RmbNet, batch: Batch, lo: int, hi: int) -> list:
    """The encodings of the batch's frames ``lo .. hi-1``."""
    return model.encode(batch.i_s[:, lo:hi].transpose(0, 1).flatten(0, 1),
                        batch.i_m[:, lo:hi].transpose(0, 1).flatten(0, 1), range(lo, hi),
                        None if batch.i_c is None else batch.i_c[:, lo:hi].transpose(0, 1).flatten(0, 1))


def aged_state(model: RmbNet, batch: Batch, outputs: range, passes: int) -> DecoderState | None:
    """The state a sample's supervised run starts from after ``passes`` runs over its ``outputs`` without gradients,
    alternately backwards and forwards and ending backwards at the first (``RmbNet.step_backward``): a state as old
    as a long capture's, where the sample alone would only give states as young as it is long."""
    if passes < 1:
        return None
    w, count, slide = model.config.w, batch.i_s.shape[1], model.config.edge_slide
    order = list(outputs)
    state: DecoderState | None = None
    with torch.no_grad():
        frames = _encode_all(model, batch, 0, count)
        for remaining in range(passes, 0, -1):
            for i in (order[:0:-1] if remaining % 2 else order[:-1]):
                window = [frames[j] for j in window_indices(i, w, count, slide)]
                aligned = None if batch.i_a is None else batch.i_a[:, i]
                if remaining % 2:
                    state = model.step_backward(window, state, window_valid(i, w, count, slide), batch.convention,
                                                aligned)
                else:
                    state = model.step(window, state, valid=window_valid(i, w, count, slide),
                                       convention=batch.convention, aligned=aligned)[1]
    return detach_state(state)


def primed_state(model: RmbNet, batch: Batch, prime: int, frames: list | None = None) -> DecoderState | None:
    """The state a sample's first frame starts from as a clip's first: the network run backwards over frames
    ``prime`` .. 1 without gradients, as the engine primes a clip (``priming_frames``; None when ``prime`` is 0).
    ``frames``: the sample's encodings from frame 0 when the caller has them (else encoded here)."""
    w, count, slide = model.config.w, batch.i_s.shape[1], model.config.edge_slide
    state: DecoderState | None = None
    with torch.no_grad():
        reach = max([prime + w + 1, *(window_reach(i, w, count, slide).stop for i in priming_frames(prime, count))])
        frames = _encode_all(model, batch, 0, min(reach, count)) if frames is None else frames
        for i in priming_frames(prime, count):
            state = model.step_backward([frames[j] for j in window_indices(i, w, count, slide)], state,
                                        window_valid(i, w, count, slide), batch.convention,
                                        None if batch.i_a is None else batch.i_a[:, i])
    return detach_state(state)


def start_state(model: RmbNet, batch: Batch, outputs: range, edges: bool, aged_passes: int,
                prime: int) -> DecoderState | None:
    """The state a sample's supervised run starts from: aged (``aged_passes``), primed as a clip's first frame's
    (its first frame supervised as a clip's, ``prime``), or fresh."""
    if aged_passes:
        return aged_state(model, batch, outputs, aged_passes)
    if edges and prime:
        return primed_state(model, batch, prime)
    return None


def held_targets(teacher: RmbNet, batch: Batch, edges: bool, prime: int) -> torch.Tensor:
    """The batch's ground truth with each supervised output whose window lies whole inside the sample replaced by
    ``teacher``'s linear output (started as the trained model's run is): trained on these, a run moves the edge
    frames towards the truth and holds the rest of a clip where the teacher had it."""
    w, count, slide = teacher.config.w, batch.i_s.shape[1], teacher.config.edge_slide
    outputs = output_range(count, w, edges)
    targets = batch.gt.clone()
    with torch.no_grad():
        frames = _encode_all(teacher, batch, 0, count)
        state = primed_state(teacher, batch, prime, frames) if edges and prime else None
        for i in outputs:
            t, state = teacher.step([frames[j] for j in window_indices(i, w, count, slide)], state,
                                    valid=window_valid(i, w, count, slide), convention=batch.convention,
                                    aligned=None if batch.i_a is None else batch.i_a[:, i])
            if all(window_valid(i, w, count)):
                targets[:, i] = teacher.to_linear(t[:, 0])
    return targets


def segment_losses(model: RmbNet, batch: Batch, tbptt: int, loss_config: LossConfig,
                   edges: bool = False, aged_passes: int = 0, prime: int = 0, bf16: bool = False,
                   edge_only: bool = False) -> Iterator[SegmentLoss]:
    """Yield the TBPTT segments of one batch in order; the caller back-propagates each before
    asking for the next, so only one segment's graph exists at a time. The sample's first frame
    starts the recurrent state (``start_state``): fresh, primed as the engine primes a clip's first frame, or aged.
    ``bf16``: the network runs under bf16 autocast, the losses in fp32; the backward pass (the caller's) outside it.
    ``edge_only``: only the outputs whose window the sample's ends cut are in the loss (``scored_outputs``)."""
    w, slide = model.config.w, model.config.edge_slide
    count = batch.i_s.shape[1]
    supervised = output_range(count, w, edges)
    scored = scored_outputs(count, w, edges, edge_only)
    outputs = len(scored)
    device = batch.i_s.device.type
    with torch.autocast(device, torch.bfloat16, enabled=bf16):
        state: DecoderState | None = start_state(model, batch, supervised, edges, aged_passes, prime)
    previous: torch.Tensor | None = None  # the last output, for the temporal term (detached across segments)
    for first in range(supervised.start, supervised.stop, tbptt):
        last = min(first + tbptt, supervised.stop) - 1
        reaches = [window_reach(i, w, count, slide) for i in range(first, last + 1)]
        lo, hi = min(r.start for r in reaches), max(r.stop for r in reaches)
        with torch.autocast(device, torch.bfloat16, enabled=bf16):
            frames = _encode_all(model, batch, lo, hi)
        cache: dict = {}
        state_in = state
        # a segment that scores nothing (``edge_only``, mid-sample) runs for the state alone, without a graph
        grad = torch.is_grad_enabled() and any(i in scored for i in range(first, last + 1))
        segment_loss = torch.zeros((), device=batch.i_s.device)
        parts = dict.fromkeys(LOSS_PARTS, 0.0)
        for i in range(first, last + 1):
            window = [frames[j - lo] for j in window_indices(i, w, count, slide)]
            with torch.autocast(device, torch.bfloat16, enabled=bf16), torch.set_grad_enabled(grad):
                t, state = model.step(window, state, cache, valid=window_valid(i, w, count, slide),
                                      convention=batch.convention,
                                      aligned=None if batch.i_a is None else batch.i_a[:, i])
            t = t.float()
            if i not in scored:
                previous = t[:, 0]
                continue
            loss, step_parts = reconstruction_loss(t[:, 0], batch.gt[:, i], loss_config, batch.convention)
            if loss_config.temporal > 0 and previous is not None:
                change = temporal_loss(t[:, 0], previous, batch.gt[:, i], batch.gt[:, i - 1], loss_config)
                loss = loss + loss_config.temporal * change
                step_parts["temporal"] = float(change.detach())
            previous = t[:, 0]
            segment_loss = segment_loss + loss
            parts["loss"] += float(loss.detach())
            for key, value in step_parts.items():
                parts[key] += value
        yield SegmentLoss(segment_loss / max(outputs, 1), parts, state_in)
        state = detach_state(state)
        previous = previous.detach()


def scored_outputs(count: int, w: int, edges: bool, edge_only: bool) -> set[int]:
    """The outputs of a sample of ``count`` frames that the loss scores: every supervised one (``output_range``), or
    with ``edge_only`` those whose window the sample's ends cut (none in a step without its edge frames)."""
    supervised = output_range(count, w, edges)
    if not edge_only:
        return set(supervised)
    return {i for i in supervised if not all(window_valid(i, w, count))} if edges else set()


def freeze_except(model: nn.Module, prefixes: tuple[str, ...]) -> list[nn.Parameter]:
    """Freeze every parameter whose name starts with none of ``prefixes`` (none frozen when empty);
    the trainable ones, in ``model.parameters()`` order. ``InputError`` if a prefix names nothing."""
    if not prefixes:
        return list(model.parameters())
    names = [name for name, _ in model.named_parameters()]
    unmatched = [p for p in prefixes if not any(name.startswith(p) for name in names)]
    if unmatched:
        raise InputError(f"trainable prefixes match no parameter: {', '.join(unmatched)}")
    for name, param in model.named_parameters():
        param.requires_grad_(any(name.startswith(p) for p in prefixes))
    return [p for p in model.parameters() if p.requires_grad]


def train_mode(model: nn.Module) -> None:
    """``model.train()``, except BatchNorm layers that are frozen: they keep normalising with their
    running statistics (as at inference) and do not update them."""
    model.train()
    for module in model.modules():
        if isinstance(module, nn.modules.batchnorm._BatchNorm) and not any(p.requires_grad for p in module.parameters()):
            module.eval()


def train_batch(model: RmbNet, batch: Batch, tbptt: int, loss_config: LossConfig,
                edges: bool = False, aged_passes: int = 0, prime: int = 0,
                teacher: RmbNet | None = None, bf16: bool = False, edge_only: bool = False) -> dict[str, float]:
    """Forward and backward one batch with TBPTT (gradients accumulate in ``.grad``; the caller
    steps the optimizer). Returns the mean loss and its parts over the supervised outputs. With a ``teacher``
    the outputs whose window is whole are trained against its outputs (``held_targets``). ``bf16``: the forward
    passes (the teacher's too) under bf16 autocast (``segment_losses``); ``edge_only``: only the edge outputs in the
    loss."""
    if teacher is not None:
        with torch.autocast(batch.i_s.device.type, torch.bfloat16, enabled=bf16):
            held = held_targets(teacher, batch, edges, prime)
        batch = replace(batch, gt=held.float())
    train_mode(model)
    outputs = len(scored_outputs(batch.i_s.shape[1], model.config.w, edges, edge_only))
    totals = dict.fromkeys(LOSS_PARTS, 0.0)
    for segment in segment_losses(model, batch, tbptt, loss_config, edges, aged_passes, prime, bf16, edge_only):
        if segment.loss.requires_grad:  # a segment scoring nothing (``edge_only``, mid-sample) has no graph
            segment.loss.backward()
        for key, value in segment.parts.items():
            totals[key] += value
    return {key: value / max(outputs, 1) for key, value in totals.items()}


def batch_seeds(seed: int, step: int, batch: int, count: int) -> list[int]:
    """Training seeds of ``step``: a fresh permutation of 0..count-1 per epoch, from ``seed``."""
    seeds = []
    for position in range(step * batch, (step + 1) * batch):
        epoch, offset = divmod(position, count)
        seeds.append(int(np.random.default_rng([seed, epoch]).permutation(count)[offset]))
    return seeds


def video_seeds(config: TrainConfig, step: int) -> list[int]:
    """Seeds of ``step`` for video scenes: ceil(batch / reuse) new scenes every step, each used by
    ``reuse`` consecutive steps (so simulation keeps up with training), never repeating within a
    run and never reaching the held-out range."""
    batch, reuse = config.optim.batch, config.data.reuse
    fresh = -(-batch // reuse)
    first = config.seed * 100_003
    return [(first + max(step - j // fresh, 0) * fresh + j % fresh) % EVAL_SEED_START for j in range(batch)]


def learning_rate(step: int, elapsed_s: float, config: TrainConfig) -> float:
    """Cosine decay from ``lr`` to ``lr_final`` over the run: progress is the larger of the step
    fraction and the wall-time fraction, so a run cut short by its budget still anneals."""
    o = config.optim
    progress = min(max(step / max(o.steps, 1), elapsed_s / (config.minutes * 60.0)), 1.0)
    return o.lr_final + 0.5 * (o.lr - o.lr_final) * (1 + math.cos(math.pi * progress))


def machine_description(device: torch.device) -> str:
    """Where a run trained: CPU count and torch threads, or the GPU name."""
    if device.type == "cuda":
        return f"{torch.cuda.get_device_name(device)} (CUDA), torch {torch.__version__}"
    return (f"{platform.machine()} CPU, {os.cpu_count()} cores visible, {torch.get_num_threads()} torch "
            f"threads, torch {torch.__version__}")


class Trainer:
    """Runs one recipe into ``out_dir``: ``loss.csv``, ``checkpoint.*`` and at the end
    ``<name>.safetensors`` + ``<name>.json``. Samples are cached under ``cache_dir``."""

    def __init__(self, config: TrainConfig, out_dir: str | Path, cache_dir: str | Path | None = None,
                 resume: bool = False, progress: bool = False, device: str = "cpu", overwrite: bool = False) -> None:
        self.config = config
        self.out_dir = Path(out_dir)
        if not resume and not overwrite:
            refuse_to_restart_over(self.out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.cache = SampleCache(Path(cache_dir) if cache_dir is not None else self.out_dir / "cache",
                                 config.sample_spec())
        self.resume = resume
        self.progress = progress
        self.device = torch.device(device)
        self.model = RmbNet(config.model).to(self.device)
        if config.init and not resume:
            self.warm_start(config.init)
        self.optimizer = torch.optim.Adam(freeze_except(self.model, config.optim.trainable), lr=config.optim.lr)
        self.teacher = self.held_teacher()
        self.bf16 = uses_bf16(config.optim.precision, self.device)
        self._prefetcher = (SamplePrefetcher(config.sample_spec(), self.step_seeds, depth=max(3, config.data.workers),
                                             workers=config.data.workers)
                            if config.data.scenes == "video" else None)

    def initial_model(self, source: str) -> RmbNet:
        """The weights of model ``source`` (a file or a shipped model's name) as this recipe's network, widened where
        it gained inputs or candidates (``widen_model``; new blend logits at the recipe's ``init_new_logit``), and
        without its window (``without_window``) for a recipe at w = 0."""
        path = bundled_path(Path(source))
        if not path.suffix:
            path = default_model_path(self.config.model.input_mode).with_name(f"{source}.safetensors")
        old, _card = load_model(path)
        if self.config.model.w == 0 < old.config.w:  # a recipe without the window, from a model with one
            old = without_window(old)
        try:
            widened = widen_model(old, self.config.model, self.config.init_new_logit)
        except ValueError as error:
            raise InputError(f"{self.config.source}: init {path}: {error}") from None
        model = RmbNet(self.config.model).to(self.device)
        model.load_state_dict(widened.state_dict())
        return model

    def warm_start(self, source: str) -> None:
        """Start from ``initial_model(source)``, so the run starts from (close to) the old model's function."""
        self.model.load_state_dict(self.initial_model(source).state_dict())
        log.info("warm start from %s (widened to this recipe's network where it gained inputs or candidates)", source)

    def held_teacher(self) -> RmbNet | None:
        """The model whole-window outputs are held to (``optim.hold_whole_windows``): the ``init`` weights, frozen,
        also on a resumed run."""
        if not self.config.optim.hold_whole_windows:
            return None
        teacher = self.initial_model(self.config.init).eval()
        teacher.requires_grad_(False)
        return teacher

    def step_seeds(self, step: int) -> list[int]:
        """The scene seeds of ``step``: video scenes (``video_seeds``) or cached panorama scenes."""
        if self.config.data.scenes == "video":
            return video_seeds(self.config, step)
        return batch_seeds(self.config.seed, step, self.config.optim.batch, self.config.data.count)

    def batch_samples(self, step: int) -> list[Sample]:
        """The training samples of ``step``: simulated ahead (video scenes) or from the cache."""
        if self._prefetcher is not None:
            return self._prefetcher.get(step)
        return [self.cache.get(s) for s in self.step_seeds(step)]

    def validation_samples(self) -> list[Sample]:
        """The held-out samples (seeds from ``EVAL_SEED_START``)."""
        return [self.cache.get(EVAL_SEED_START + k) for k in range(self.config.data.val_count)]

    def run(self) -> TrainResult:
        """Train until the step count or the time budget is reached, then save model and card."""
        cfg = self.config
        if self.device.type == "cpu":
            torch.set_num_threads(cfg.optim.threads or default_threads())
        torch.manual_seed(cfg.seed)
        state = CheckpointState(0, 0.0)
        if self.resume:
            state = load_checkpoint(self.out_dir, self.model, self.optimizer)
            log.info("resuming %s at step %d (%.1f min trained)", cfg.name, state.step, state.elapsed_s / 60)
        elif checkpoint_paths(self.out_dir)[1].exists():
            log.info("%s: starting afresh over an existing checkpoint (--overwrite)", self.out_dir)
        log_writer = _LossLog(self.out_dir / "loss.csv", keep_until=state.step if self.resume else None)
        budget_s = cfg.minutes * 60.0
        step, elapsed = state.step, state.elapsed_s
        started = time.monotonic() - elapsed
        stopped_by = "steps"
        val_samples: list[Sample] | None = None
        bar = tqdm(total=cfg.optim.steps, initial=step, disable=not self.progress, unit="step", desc=cfg.name)
        with checkpointed_on_stop(self.out_dir, self.model, self.optimizer,
                                  lambda: CheckpointState(step, time.monotonic() - started)):
            try:
                while step < cfg.optim.steps:
                    if time.monotonic() - started >= budget_s:
                        stopped_by = "time budget"
                        break
                    samples = self.batch_samples(step)
                    flips = [bool(np.random.default_rng([cfg.seed, step, j, 1]).integers(2))
                             for j in range(len(samples))]
                    batch = Batch.from_samples(samples, self.device, flips, cfg.model.centre_windows, cfg.model.n,
                                               cfg.model)
                    lr = learning_rate(step, time.monotonic() - started, cfg)
                    for group in self.optimizer.param_groups:
                        group["lr"] = lr
                    self.optimizer.zero_grad(set_to_none=True)
                    edges = bool(np.random.default_rng([cfg.seed, step, 2]).random() < cfg.optim.edges)
                    losses = train_batch(self.model, batch, cfg.optim.tbptt, cfg.loss, edges, cfg.optim.aged_passes,
                                         cfg.optim.prime, self.teacher, self.bf16, cfg.optim.edge_only)
                    if not all(math.isfinite(v) for v in losses.values()):
                        raise FloatingPointError(f"step {step}: non-finite loss {losses} "
                                                 f"(seeds {self.step_seeds(step)})")
                    with signals_deferred():  # a stop lands before or after a whole step, never inside one
                        torch.nn.utils.clip_grad_norm_(self.model.parameters(), cfg.optim.grad_clip)
                        self.optimizer.step()
                        step += 1
                    elapsed = time.monotonic() - started
                    row: dict[str, float] = {"step": step, "elapsed_s": elapsed, "lr": lr, **losses}
                    if step % cfg.optim.val_every == 0:
                        val_samples = val_samples or self.validation_samples()
                        row.update(validate(self.model, val_samples, self.cache.spec.quanta, cfg.loss.saturation,
                                            self.device, cfg.optim.edges > 0))
                        log.info("step %d (%.1f min): loss %.4f, val mu-PSNR %.2f dB (TFW %.2f dB)", step,
                                 elapsed / 60, losses["loss"], row["val_mu_psnr"], row["val_tfw_mu_psnr"])
                    log_writer.write(row)
                    if step % cfg.optim.checkpoint_every == 0:
                        save_checkpoint(self.out_dir, self.model, self.optimizer, CheckpointState(step, elapsed))
                    bar.update(1)
                    bar.set_postfix(loss=f"{losses['loss']:.4f}")
            finally:
                bar.close()
                log_writer.close()
                if self._prefetcher is not None:
                    self._prefetcher.close()
            elapsed = time.monotonic() - started
            save_checkpoint(self.out_dir, self.model, self.optimizer, CheckpointState(step, elapsed))
            metrics = validate(self.model, val_samples or self.validation_samples(), self.cache.spec.quanta,
                               cfg.loss.saturation, self.device, cfg.optim.edges > 0)
            metrics["val_samples"] = float(cfg.data.val_count)
            weights = save_model(self.out_dir / f"{cfg.name}.safetensors", self.model,
                                 self.card(step, elapsed, stopped_by, metrics))
            log.debug("%s: %d steps in %.1f min (stopped by %s); held-out mu-law PSNR %.2f dB (TFW %.2f dB)",
                     weights, step, elapsed / 60, stopped_by, metrics["val_mu_psnr"], metrics["val_tfw_mu_psnr"])
        return TrainResult(weights, step, elapsed, stopped_by, metrics)

    def card(self, steps: int, elapsed_s: float, stopped_by: str, metrics: dict[str, float]) -> ModelCard:
        """The model card: recipe, loss, data description, wall time, machine, held-out metrics."""
        cfg, spec = self.config, self.cache.spec
        w = cfg.model.w
        return ModelCard(
            name=cfg.name,
            description=cfg.description,
            training={
                "recipe_file": cfg.source,
                "recipe": cfg.recipe_text,
                "steps_done": steps,
                "steps_planned": cfg.optim.steps,
                "stopped_by": stopped_by,
                "wall_time_s": round(elapsed_s, 1),
                "machine": machine_description(self.device),
                "optimizer": f"Adam, lr {cfg.optim.lr} cosine to {cfg.optim.lr_final} over steps or wall time, batch {cfg.optim.batch}, "
                             f"grad-norm clip {cfg.optim.grad_clip}"
                             + (f"; trained only {', '.join(cfg.optim.trainable)} (the rest frozen)" if cfg.optim.trainable else "")
                             + ("; the network's forward passes under bf16 autocast, the losses in fp32" if self.bf16 else ""),
                "tbptt": f"{cfg.data.steps} consecutive outputs per sample, back-propagated in segments of "
                         f"{cfg.optim.tbptt}" + (f", from a state aged by {cfg.optim.aged_passes} passes over the "
                                                 "outputs without gradients" if cfg.optim.aged_passes else "")
                         + (f"; a sample supervised from its first frame primed backwards over {cfg.optim.prime} "
                            "frames, as the engine primes a clip" if cfg.optim.prime else "")
                         + ("; outputs whose window is whole trained against the init model's outputs (held), "
                            "the edge frames against the truth" if cfg.optim.hold_whole_windows else "")
                         + ("; only the edge outputs in the loss (a model for a clip's edge frames)"
                            if cfg.optim.edge_only else ""),
                "loss": (f"{cfg.loss.l2:g} x " if cfg.loss.l2 != 1 else "") + f"mu-law (mu={cfg.loss.mu:g}) L2 + {cfg.loss.ssim:g} x (1 - SSIM) + {cfg.loss.edge:g} x "
                        f"gradient L1" + (f" + {cfg.loss.linear:g} x linear L1 relative to the sample's mean"
                                          if cfg.loss.linear > 0 else "")
                        + (f" + {cfg.loss.regional:g} x linear L1 of 8x8 block means relative to their level"
                           if cfg.loss.regional > 0 else "")
                        + (f" + {cfg.loss.display_linear:g} x the linear L1 again on spikezoo-convention "
                           "(display-referred) samples" if cfg.loss.display_linear > 0 else "")
                        + (f" + {cfg.loss.temporal:g} x L1 of consecutive outputs' mu-law changes against the truth's"
                           if cfg.loss.temporal > 0 else "")
                        + f"; ground truth clipped at {cfg.loss.saturation:g} (sensor saturation)",
                "lpips": "not used (no downloadable weights); replaced by the gradient L1 term"
                         if cfg.loss.edge > 0 else "not used (no downloadable weights), no replacement",
            },
            data={
                "input_mode": spec.mode,
                "readout": f"{spec.readout}, band {spec.band}, shift {spec.shift}, level {spec.level}",
                "description": (
                    "dead-leaves video scenes (rmbvideo.scenes.video): texture at every scale, a camera "
                    "moving up to 1.2 raw px/plane with shake and zoom, 0-6 independent objects (own translation "
                    "up to 1.5 raw px/plane, rotation, scaling; occlusion; some lights 5-300x brighter), soft "
                    "shadows, median rate 2e-3..0.5 per raw plane; 1-bit simulation at 2x size and rate, binned "
                    f"2x2x2 as real captures; {1 - cfg.data.spikezoo_fraction:.0%} physical emission with effects "
                    f"{', '.join(REALISTIC_EFFECTS)}, {cfg.data.spikezoo_fraction:.0%} spikezoo's convention "
                    "(8-bit intensity, rate 0.6 x intensity, accumulate-and-subtract, no noise)"
                    + (f"; {cfg.data.flat_fraction:.0%} of the training scenes static, nearly flat fields "
                       "(level 1e-3..1, log-uniform; +-30 % gradient)" if cfg.data.flat_fraction else "")
                    + (f"; {cfg.data.low_contrast_fraction:.0%} of the training scenes with the background's "
                       "log-contrast scaled by 0.1-0.5" if cfg.data.low_contrast_fraction else "")
                    + (f"; {cfg.data.pan_fraction:.0%} of the training scenes rigid pans (constant 0.02-0.5 raw "
                       "px/plane, no movers, shake or zoom)" if cfg.data.pan_fraction else "")
                    + (f"; {cfg.data.subtract_fraction:.0%} of the physical scenes by a pixel reset by subtraction "
                       "(a real camera's such as car.dat's: noisy spikes in the rate convention, the network told so)"
                       if cfg.data.subtract_fraction else "")
                    + f"; new scenes every step, each used in {cfg.data.reuse} steps"
                    + (f"; initialised from {cfg.init}" if cfg.init else "")
                ) if cfg.data.scenes == "video" else (
                    "random HDR scenes: CC0 Poly Haven panoramas with random pan/zoom, 0-3 moving textured "
                    "objects (some light sources 10-1e4x brighter), random dark regions, exposure "
                    f"{cfg.data.exposure[0]:g}-{cfg.data.exposure[1]:g} e-/readout at median radiance; "
                    + ("1-bit simulation at 2x size and rate, binned 2x2x2 as real captures"
                       if spec.mode == "binned" else "native multi-bit RMB emission")
                    + f"; effects: {', '.join(REALISTIC_EFFECTS)}"),
                "sample": f"{spec.crop}x{spec.crop} px, {spec.frames} preliminary frames (2w+K, w={w}, "
                          f"K={cfg.data.steps}) of N={spec.n} readouts, {spec.warmup_frames} warm-up frames dropped",
                "train_seeds": (f"0..{cfg.data.count - 1}" if cfg.data.scenes == "panorama"
                                else "fresh every step (rmbvideo.train.loop.video_seeds)"),
                "train_panoramas": list(TRAIN_PANORAMAS),
                "eval_seeds": f"{EVAL_SEED_START}..{EVAL_SEED_START + cfg.data.val_count - 1}",
                "held_out_panorama": HELD_OUT_PANORAMA,
                "panorama_licence": "CC0 (Poly Haven)",
                "metrics_note": "validation mu-law PSNR/SSIM (rmbvideo.evaluate.metrics) over all K outputs of "
                                "the held-out samples, ground truth clipped at saturation; TFW from the same "
                                "preliminary frames over the same 2w+1 window: "
                                + ("pooled (I_s + I_m) / (N (2w+1) (1 + q))" if spec.quanta is not None else
                                   "I_s only (a weak baseline: native band reads reset pixels, so the 1-bit "
                                   "rate is biased low, and the band value is not a per-readout rate)"),
            },
            metrics={k: round(v, 4) for k, v in metrics.items()},
        )


class _LossLog:
    """Appends rows to ``loss.csv``; on resume, rows after the checkpoint's step are dropped (the kept rows are
    rewritten atomically, so a stop then leaves the log as it was)."""

    def __init__(self, path: Path, keep_until: int | None) -> None:
        rows: list[dict[str, str]] = []
        if keep_until is not None and path.exists():
            with path.open(newline="") as fh:
                rows = [r for r in csv.DictReader(fh) if r.get("step", "").isdigit() and int(r["step"]) <= keep_until]
        kept = io.StringIO(newline="")
        writer = csv.DictWriter(kept, fieldnames=LOG_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
        atomic_write_text(path, kept.getvalue())
        self.handle = path.open("a", newline="")
        self.writer = csv.DictWriter(self.handle, fieldnames=LOG_COLUMNS, extrasaction="ignore")

    def write(self, row: dict[str, float]) -> None:
        self.writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
        self.handle.flush()

    def close(self) -> None:
        self.handle.close()
