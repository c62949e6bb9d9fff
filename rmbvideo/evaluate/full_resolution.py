"""Evaluation at the camera's full resolution: ``--resolution full`` against TFP and TFI on the raw capture.

Synthetic sequences: the held-out set, with full-resolution ground truth rendered again from each
sequence's seed (scenes are pure functions of their seed); scored like the binned table (mu-law PSNR
and SSIM on the scored frames, ground truth clipped at saturation). Real-video streams: the reference
PNG at full resolution, least-squares gain. Every row's frames/s is measured in the same run.

Also scored: the full-resolution output 2x2-averaged against the binned ground truth, next to the
binned output itself, so that adding detail is seen not to cost the binned quality.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Sequence as Seq
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from rmbvideo.evaluate.harness import (SATURATION, SIMULATED_RESPONSE, TFI_WINDOWS, downsample_2x, rate_as_light,
                                       scored_truth, sequence_convention, temporal_score)
from rmbvideo.evaluate.heldout import RAW_RATE_HZ, VIDEO_KINDS, Sequence
from rmbvideo.evaluate.metrics import mu_law_psnr, mu_law_ssim, ssim
from rmbvideo.evaluate.real_video import (
    CONVENTION,
    RAW_STEP,
    TFP_WINDOWS,
    RealStream,
    least_squares_gain,
    open_stream,
    scaled_psnr,
)
from rmbvideo.io.png import write_png
from rmbvideo.recon.full_resolution import FullResolution, detail_stage, raw_gate_stage, upsample
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
from rmbvideo.recon.run import trained_readout
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

log = logging.getLogger(__name__)

FULL = "RMB-Net, full resolution"
FULL_LEARNED = "RMB-Net, full resolution (learned detail)"
NO_RAW_GATE = "RMB-Net, full resolution (learned detail, no raw gate)"
BINNED_UP = "RMB-Net, binned (bilinear 2x)"
BEST_RAW_FULL = "best classical on the raw capture"


@dataclass(frozen=True)
class FullRow:
    """A row: ``method`` with ``options``; ``kind`` is "full" (binned method + classical raw detail),
    "full-learned" (+ the learned detail stage), "binned-up" (the binned output upsampled bilinearly) or
    "raw" (a method on the raw capture); ``raw_gate``: a full row's binned frames mixed with raw TFI by the shipped
    raw-interval gate (``rmbvideo.net.raw_gate``), as ``reconstruct`` does by default."""

    name: str
    method: str
    options: dict[str, Any] = field(default_factory=dict)
    kind: str = "raw"
    raw_gate: bool = False


def full_rows(model: Path | None = None, threads: int | None = 1, precision: str = "auto") -> list[FullRow]:
    """RMB-Net at full and at binned resolution (its network and detail stage in ``precision``), TFP at every window
    and TFI on the raw capture."""
    from rmbvideo.net.weights import default_detail_path, default_raw_gate_path

    rmbnet = {"model": model, "input_mode": "binned", "threads": threads, "precision": precision}
    gate = default_raw_gate_path().is_file()
    learned = ([FullRow(FULL_LEARNED, "rmbnet", rmbnet, "full-learned", raw_gate=gate)]
               + ([FullRow(NO_RAW_GATE, "rmbnet", rmbnet, "full-learned")] if gate else [])
               if default_detail_path().is_file() else [])
    return [*learned, FullRow(FULL, "rmbnet", rmbnet, "full"), FullRow(BINNED_UP, "rmbnet", rmbnet, "binned-up"),
            *(FullRow(f"TFP-{w}", "tfp", {"window": w, "step": RAW_STEP}) for w in TFP_WINDOWS),
            FullRow("TFI", "tfi", {"step": RAW_STEP}),
            *(FullRow(f"TFI-{w}", "tfi", {"step": RAW_STEP, "window": w}) for w in TFI_WINDOWS)]


def run_row(row: FullRow, source: Any, keep: list[int] | None = None,
            convention: str = "physical") -> tuple[dict[int, np.ndarray], float, int]:
    """Frames (index -> image) of ``row`` on ``source`` (a stream made in ``convention``), seconds, frames
    emitted: full resolution, except a "binned-up" row's binned frames (``at_full_resolution`` upsamples
    them). RMB-Net reads the binned stream through the readout its model was trained on."""
    options = ({**row.options, "convention": convention, "response": SIMULATED_RESPONSE} if row.method == "rmbnet"
               else row.options)
    recon = make_reconstructor(row.method, **options)
    readout = RmbReadout(mode=ReadoutMode(trained_readout(recon)))
    if row.kind in ("full", "full-learned"):
        stage = detail_stage("learned" if row.kind == "full-learned" else "classical")
        recon = FullResolution(recon, readout, step=RAW_STEP, detail=stage, threads=options.get("threads"),
                               raw_gate=raw_gate_stage("auto" if row.raw_gate else "off", options.get("model")),
                               precision=options.get("precision", "auto"))
        readout = None
    elif row.kind == "raw":
        readout = None
    sink = FrameCollector(keep=keep)
    began = time.perf_counter()
    summary = reconstruct_stream(source, recon, sink, chunk_planes=128, readout=readout)
    seconds = time.perf_counter() - began
    return {i: rate_as_light(row.method, f.image, convention) for i, f in sink.frames.items()}, seconds, summary.frames


def at_full_resolution(row: FullRow, image: np.ndarray) -> np.ndarray:
    """A frame of ``row`` from ``run_row`` at full resolution (a "binned-up" row's upsampled bilinearly)."""
    return upsample(image) if row.kind == "binned-up" else image


def full_ground_truth(seq: Sequence) -> dict[int, np.ndarray]:
    """Full-resolution ground truth of the scored frames of a held-out sequence, rendered from its seed."""
    description = json.loads(seq.description or "{}")
    raw_h, raw_w = seq.raw_shape
    kinds = {k.name: k for k in VIDEO_KINDS}
    if description.get("kind") in kinds:
        from rmbvideo.scenes.video import VideoScene

        kind = kinds[description["kind"]]
        scene = VideoScene(seq.seed, raw_w, raw_h, seq.n_planes, kind.ranges, kind.convention)
        return {i: scene.render(20 * i + 10).astype(np.float32) for i in seq.scored_frames}
    from rmbvideo.scenes.random_scenes import random_scene
    from rmbvideo.scenes.render import SceneRenderer

    scene = random_scene(seq.seed, raw_w, raw_h, duration_s=seq.n_planes / RAW_RATE_HZ, rate_hz=RAW_RATE_HZ)
    renderer = SceneRenderer(scene)
    scale = np.float32(scene.exposure / scene.sensor.q_r)
    return {i: renderer.render((20 * i + 10) / RAW_RATE_HZ) * scale for i in seq.scored_frames}


@dataclass
class FullScores:
    """Per sequence (or stream) name: row -> (PSNR, SSIM); per synthetic sequence: row -> temporal PSNR; frames/s per
    row; binned-resolution checks."""

    psnr: dict[str, dict[str, float]] = field(default_factory=dict)
    ssim: dict[str, dict[str, float]] = field(default_factory=dict)
    temporal: dict[str, dict[str, float]] = field(default_factory=dict)
    fps: dict[str, list[float]] = field(default_factory=dict)
    binned_check: dict[str, dict[str, float]] = field(default_factory=dict)  # seq -> row -> binned-res PSNR
    pictures: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


def _add_best_raw(psnr: dict[str, float], ssim_: dict[str, float]) -> None:
    raw = [k for k in psnr if k.startswith(("TFP", "TFI"))]
    best = max(raw, key=psnr.__getitem__)
    psnr[BEST_RAW_FULL], ssim_[BEST_RAW_FULL] = psnr[best], ssim_[best]


def score_sequences(sequences: Seq[Sequence], rows: Seq[FullRow], scores: FullScores) -> None:
    """Score every row on every held-out sequence at full resolution."""
    for seq in sequences:
        truth = {i: np.minimum(gt, SATURATION) for i, gt in full_ground_truth(seq).items()}
        binned_truth = scored_truth(seq, truth)
        psnr, ssim_ = {}, {}
        for row in rows:
            produced, seconds, emitted = run_row(row, seq, convention=sequence_convention(seq))
            missing = sorted(set(truth) - set(produced))
            if missing:
                raise ValueError(f"{row.name} on {seq.name}: no frame {missing[0]}")
            frames = {i: at_full_resolution(row, produced[i]) for i in truth}
            psnr[row.name] = float(np.mean([mu_law_psnr(frames[i], truth[i]) for i in truth]))
            ssim_[row.name] = float(np.mean([mu_law_ssim(frames[i], truth[i]) for i in truth]))
            scores.temporal.setdefault(seq.name, {})[row.name] = temporal_score(frames, truth)
            scores.fps.setdefault(row.name, []).append(emitted / seconds if seconds > 0 else math.inf)
            if row.kind != "raw":  # full outputs 2x2-averaged, and the binned output itself as it was made
                binned = {i: produced[i][: seq.shape[0], : seq.shape[1]] if row.kind == "binned-up"
                          else downsample_2x(frames[i], seq.shape)
                          for i in truth}
                scores.binned_check.setdefault(seq.name, {})[row.name] = float(np.mean(
                    [mu_law_psnr(binned[i], binned_truth[i]) for i in truth]))
            log.info("%s: %s %.2f dB", seq.name, row.name, psnr[row.name])
        _add_best_raw(psnr, ssim_)
        scores.psnr[seq.name], scores.ssim[seq.name] = psnr, ssim_


def score_streams(streams: Seq[RealStream], rows: Seq[FullRow], scores: FullScores) -> None:
    """Score every row on every real-video stream at full resolution (least-squares gain)."""
    for stream in streams:
        reference = cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
        psnr, ssim_, pictures = {}, {}, {"reference": reference}
        for row in rows:
            frames, _, _ = run_row(row, open_stream(stream), keep=[stream.frame],
                                   convention=CONVENTION)
            image = at_full_resolution(row, frames[stream.frame])[: reference.shape[0], : reference.shape[1]]
            scaled = (least_squares_gain(image, reference) * image).astype(np.float32)
            psnr[row.name] = scaled_psnr(image, reference)
            ssim_[row.name] = ssim(np.clip(scaled, 0, 1), reference)
            pictures[row.name] = scaled
            log.info("%s: %s %.2f dB", stream.name, row.name, psnr[row.name])
        _add_best_raw(psnr, ssim_)
        scores.psnr[stream.name], scores.ssim[stream.name] = psnr, ssim_
        scores.pictures[stream.name] = pictures


def markdown(scores: FullScores, synthetic: Seq[str], real: Seq[str]) -> str:
    """The full-resolution table (per sequence and means) and the binned-resolution check."""
    rows = list(next(iter(scores.psnr.values())))
    names = [*synthetic, *real]
    lines = ["# Full-resolution evaluation", "",
             "| method | " + " | ".join(names) + " | synthetic mean | real mean | synthetic temporal | frames/s |",
             "|---|" + "---:|" * (len(names) + 4)]
    for row in rows:
        cells = [f"{scores.psnr[n][row]:.2f}" for n in names]
        syn = f"{np.mean([scores.psnr[n][row] for n in synthetic]):.2f}" if synthetic else "—"
        rea = f"{np.mean([scores.psnr[n][row] for n in real]):.2f}" if real else "—"
        temporal = [scores.temporal[n][row] for n in synthetic if row in scores.temporal.get(n, {})]
        tem = f"{np.mean(temporal):.2f}" if temporal else "—"
        fps = f"{np.mean(scores.fps[row]):.1f}" if row in scores.fps else "—"
        lines.append(f"| {row} | " + " | ".join(cells) + f" | {syn} | {rea} | {tem} | {fps} |")
    lines += ["", "Synthetic: mu-law PSNR (dB) against the full-resolution ground truth; real video: linear PSNR "
              "with a least-squares gain against the full-resolution reference. 'best classical' picks the best "
              "raw row per sequence (an oracle window choice). Synthetic temporal: the PSNR of the mu-law "
              "frame-to-frame differences against the truth's (``temporal_mu_law_psnr``), what shows as flicker.", "",
              "## Binned-resolution check (synthetic, mu-law PSNR against the binned ground truth)", "",
              "Each full-resolution output 2x2-averaged, against the binned output (difference in brackets).", ""]
    if scores.binned_check:
        full = [r for r in next(iter(scores.binned_check.values())) if r != BINNED_UP]
        lines += ["| sequence | " + " | ".join(full) + " | binned output |", "|---|" + "---:|" * (len(full) + 1)]
        for name, checks in scores.binned_check.items():
            binned = checks.get(BINNED_UP, math.nan)
            cells = [f"{checks[r]:.2f} ({checks[r] - binned:+.2f})" for r in full]
            lines.append(f"| {name} | " + " | ".join(cells) + f" | {binned:.2f} |")
    return "\n".join(lines) + "\n"


def write_full_resolution(out_dir: Path, sequences: Seq[Sequence], streams: Seq[RealStream], model: Path,
                          threads: int | None = 1, precision: str = "auto") -> list[Path]:
    """Score everything, write ``full_resolution.md`` and ``full_resolution.png``; returns the paths."""
    from rmbvideo.io.atomic import atomic_write_text

    scores = FullScores()
    rows = full_rows(model, threads, precision)
    score_sequences(sequences, rows, scores)
    score_streams(streams, rows, scores)
    md = out_dir / "full_resolution.md"
    atomic_write_text(md, markdown(scores, [s.name for s in sequences], [s.name for s in streams]))
    written = [md]
    if streams:
        png = out_dir / "full_resolution.png"
        learned = [FULL_LEARNED] if any(r.name == FULL_LEARNED for r in rows) else []
        # TFI-8: the single classical row most accurate on the real streams (README "Evaluation", docs/evaluation.md)
        comparison_picture(scores, png, [*learned, FULL, BINNED_UP, "TFP-20", "TFI", "TFI-8"])
        written.append(png)
    return written


def comparison_picture(scores: FullScores, path: Path, rows: Seq[str]) -> None:
    """Side by side per real stream: reference, then ``rows`` (a crop of 160x120 at the centre, 2x)."""
    strips = []
    for pictures in scores.pictures.values():
        tiles = []
        for name in ["reference", *rows]:
            image = np.clip(pictures[name], 0, 1)
            h, w = image.shape
            crop = image[h // 2 - 60: h // 2 + 60, w // 2 - 80: w // 2 + 80]
            tile = cv2.resize((crop * 255).astype(np.uint8), (320, 240), interpolation=cv2.INTER_NEAREST)
            cv2.putText(tile, name[:44], (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 255, 1, cv2.LINE_AA)
            tiles.append(tile)
        strips.append(np.hstack(tiles))
    write_png(path, np.vstack(strips))
