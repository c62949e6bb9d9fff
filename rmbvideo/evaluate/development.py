"""Candidate models scored on the development sets only: how a training stage is chosen without looking
at the evaluation's held-out tables.

Per model file: the mean mu-law PSNR of each development sequence's scored frames
(``heldout.load_development``: the held-out kinds drawn from other evaluation seeds) and their frame-to-frame score
(``metrics.temporal_mu_law_psnr``: flicker), the first and last
frames against their clip's median (dB), the development clips (texture pans in spikezoo's convention),
the real-video streams when given, the development sequences again as a real camera's pixel makes them (reset by
subtraction, like ``car.dat``'s: the rate convention with the camera's noise), the dark-end bias at 1e-3 on a flat field of seed 1 (the
evaluation's own dark check uses seed 0), and how a long still clip's quality changes as the recurrent
state ages (late minus early, in both conventions; other seeds than the evaluation's long captures). Beside the
table, ``development_figure`` shows the frames where the default's misses are (``PICTURED``) and the real-video
reference frames, every candidate beside the truth: a candidate is looked at before it ships.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence as Seq
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rmbvideo.evaluate.harness import MethodSpec, run_frames, score_frames, scored_truth, temporal_score
from rmbvideo.evaluate.heldout import Sequence
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.real_video import (CONVENTION, RealRow, RealScore, RealStream, binned_reference,
                                          comparison_image, score_stream)
from rmbvideo.evaluate.table import pick_moving_region, pick_regions, side_by_side
from rmbvideo.evaluate.video_checks import band_sequence, dark_bias, state_age_report
from rmbvideo.net.weights import load_model

#: flat-field seed of the dark-end bias used for choosing (seed 0 is the evaluation's check)
DARK_SEED = 1
DARK_LEVEL = 1e-3
#: the long still clips' seed (the evaluation's are ``band_sequence``'s default), size and length
LONG_SEED = 1_700_000
LONG_SIZE = (112, 64)
LONG_FRAMES = 60
#: marks a development sequence made by a pixel reset by subtraction in the per-set table
CAMERA_SUFFIX = "/subtract"
#: Frames pictured per development sequence kind (its name without the seed): where the default's misses are (the
#: dark clip's first frame, the fast-dark clip's last), a dark and a fast moving frame mid-clip, a textured first frame
PICTURED: dict[str, tuple[str, ...]] = {"dark": ("first", "middle"), "fast": ("middle",), "fast-dark": ("last",),
                                        "low-contrast": ("first",)}
#: (sequence name, frame index) -> the frame a model made there
Pictures = dict[tuple[str, int], np.ndarray]


@dataclass(frozen=True)
class DevelopmentScore:
    """One candidate on the development sets (mu-law PSNR in dB; linear PSNR on clips and real streams)."""

    name: str
    sequences: dict[str, float]
    first_frame_db: float  # mean over sequences of (first frame - median frame)
    last_frame_db: float
    clips: dict[str, float]
    real_frames: dict[str, RealScore]  # each real-video stream's scored frame (gain-scaled) and its PSNR
    dark_bias: float  # relative bias of the mean output at DARK_LEVEL
    state_age: dict[str, float]  # long still clip -> late minus early mean (dB)
    camera: dict[str, float] = field(default_factory=dict)  # the sequences from a pixel reset by subtraction
    pictures: Pictures = field(default_factory=dict)  # the frames ``PICTURED`` names
    temporal: dict[str, float] = field(default_factory=dict)  # each sequence's frame-to-frame (temporal) mu-PSNR

    @property
    def real(self) -> dict[str, float]:
        """Linear PSNR on each real-video stream."""
        return {name: score.psnr for name, score in self.real_frames.items()}

    @property
    def sequence_mean(self) -> float:
        return float(np.mean(list(self.sequences.values())))


def _options(model: Path, device: str) -> dict:
    return {"model": Path(model), "device": device, "input_mode": "binned", "threads": 1}


def _readout(model: Path) -> str:
    """The readout design the model was trained on (its input is made with it)."""
    return load_model(model)[0].config.readout


def pictured_frames(name: str, frames: Seq[int], pictured: dict[str, tuple[str, ...]]) -> list[int]:
    """The indices among ``frames`` (sorted) that ``pictured`` names for a sequence called ``name``."""
    positions = {"first": frames[0], "middle": frames[len(frames) // 2], "last": frames[-1]}
    return [positions[p] for p in pictured.get(name.rsplit("-", 1)[0], ())]


def score_sequences(model: Path, sequences: Seq[Sequence], device: str = "cpu",
                    pictured: dict[str, tuple[str, ...]] | None = None
                    ) -> tuple[dict[str, float], float, float, Pictures, dict[str, float]]:
    """Mean mu-law PSNR of each sequence's scored frames, the mean drop of its first and last frame
    below the median of all its frames, the frames ``pictured`` names (``PICTURED`` when None), and each sequence's
    frame-to-frame score (``temporal_score`` over its scored frames)."""
    spec = MethodSpec("candidate", "rmbnet", _options(model, device), _readout(model))
    scores, first, last, pictures, temporal = {}, [], [], {}, {}
    for seq in sequences:
        frames, _, _ = run_frames(spec, seq)
        images = {f.index: f.image for f in frames}
        scored = {i: images[i] for i in seq.scored_frames}
        scores[seq.name] = score_frames(scored, seq)[0]
        temporal[seq.name] = temporal_score(scored, scored_truth(seq, scored))
        per_frame = {i: mu_law_psnr(images[i], seq.gt[i]) for i in images}
        median = float(np.median(list(per_frame.values())))
        first.append(per_frame[min(per_frame)] - median)
        last.append(per_frame[max(per_frame)] - median)
        for i in pictured_frames(seq.name, sorted(images), PICTURED if pictured is None else pictured):
            pictures[seq.name, i] = images[i]
    return scores, float(np.mean(first)), float(np.mean(last)), pictures, temporal


def score_streams(model: Path, streams: Seq[RealStream], device: str = "cpu") -> dict[str, RealScore]:
    """The frame at each stream's reference moment, gain-scaled, and its linear PSNR (the real-video scorer,
    spikezoo's convention)."""
    row = RealRow("candidate", "rmbnet", {**_options(model, device), "convention": CONVENTION}, readout=_readout(model))
    return {s.name: score_stream(s, [row])["candidate"] for s in streams}


def long_clips() -> list[Sequence]:
    """The development's long still clips, in the physical convention and spikezoo's."""
    return [band_sequence(*LONG_SIZE, LONG_FRAMES, static=True, seed=LONG_SEED, convention=convention)
            for convention in ("physical", "spikezoo")]


def score_candidate(model: Path, sequences: Seq[Sequence], clips: Seq[RealStream], real: Seq[RealStream],
                    device: str = "cpu", name: str | None = None, long: Seq[Sequence] = (),
                    camera: Seq[Sequence] = (), pictured: dict[str, tuple[str, ...]] | None = None) -> DevelopmentScore:
    """Every development figure of one model file (``long``: still clips for the state's age; ``camera``: sequences
    a pixel reset by subtraction made, scored apart; ``pictured``: the frames kept for the figure)."""
    seq_scores, first, last, pictures, temporal = score_sequences(model, sequences, device, pictured)
    camera_scores = {f"{seq}{CAMERA_SUFFIX}": value for seq, value in score_sequences(model, camera, device, {})[0].items()}
    options = {"model": Path(model), "device": device, "threads": 1}
    bias = dark_bias("rmbnet", options, levels=(DARK_LEVEL,), seed=DARK_SEED)[DARK_LEVEL][0]
    ages = {a.sequence: a.late_db - a.early_db for a in (state_age_report("rmbnet", options, seq) for seq in long)}
    return DevelopmentScore(name or f"{Path(model).parent.name}/{Path(model).stem}", seq_scores, first, last,
                            {k: v.psnr for k, v in score_streams(model, clips, device).items()},
                            score_streams(model, real, device), bias, ages, camera_scores, pictures, temporal)


def score_candidates(models: Seq[Path], sequences: Seq[Sequence], clips: Seq[RealStream], real: Seq[RealStream],
                     device: str = "cpu", done: Callable[[], None] | None = None,
                     long: Seq[Sequence] = (), camera: Seq[Sequence] = (),
                     pictured: dict[str, tuple[str, ...]] | None = None) -> list[DevelopmentScore]:
    """``score_candidate`` for each model; ``done`` is called after each (a progress bar)."""
    scores = []
    for model in models:
        scores.append(score_candidate(model, sequences, clips, real, device, long=long, camera=camera,
                                      pictured=pictured))
        if done is not None:
            done()
    return scores


def _mean(values: dict[str, float]) -> str:
    return f"{np.mean(list(values.values())):.2f}" if values else "—"


def markdown(scores: Seq[DevelopmentScore], models: Seq[Path]) -> str:
    """The candidates' table, then the per-sequence and per-stream figures."""
    lines = ["# Development sets: candidate models", "",
             "Never the evaluation's held-out tables: choose a training stage here, then run the full evaluation once.", "",
             "| model | development sequences (mu-PSNR) | frame to frame (temporal mu-PSNR) "
             "| first / last frame vs median (dB) | development clips (PSNR) "
             "| real-video streams (PSNR) | a real camera's pixel (mu-PSNR) | dark end at 1e-3 (seed 1) "
             "| long still clips: late - early (dB) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for s in scores:
        ages = " / ".join(f"{value:+.2f}" for value in s.state_age.values()) or "—"
        lines.append(f"| {s.name} | {s.sequence_mean:.2f} | {_mean(s.temporal)} "
                     f"| {s.first_frame_db:+.2f} / {s.last_frame_db:+.2f} | "
                     f"{_mean(s.clips)} | {_mean(s.real)} | {_mean(s.camera)} | {100 * s.dark_bias:+.1f} % | {ages} |")
    lines += ["", "Per set (dB):", ""]
    columns = [name for s in scores[:1] for name in [*s.sequences, *s.clips, *s.real, *s.camera, *s.state_age]]
    lines += ["| model | " + " | ".join(columns) + " |", "|---|" + "---:|" * len(columns)]
    for s in scores:
        values = {**s.sequences, **s.clips, **s.real, **s.camera, **s.state_age}
        lines.append(f"| {s.name} | " + " | ".join(f"{values[c]:.2f}" for c in columns) + " |")
    lines += ["", f"A real camera's pixel (columns `{CAMERA_SUFFIX}`): the development sequences simulated with a pixel reset "
              "by subtraction, like car.dat's camera (`rmbvideo evaluate --reset subtract`), read in the rate convention.",
              "", "Long still clips (the last columns): late (second half) minus early (frames 3-8) mean mu-law PSNR "
              "of a still scene, what the recurrent state's age alone does.",
              "", "Models: " + ", ".join(f"`{m}`" for m in models), ""]
    return "\n".join(lines)


def development_figure(scores: Seq[DevelopmentScore], sequences: Seq[Sequence],
                       streams: Seq[RealStream] = ()) -> np.ndarray | None:
    """One row per pictured frame: the truth and every model's frame beside it (mu-law PSNR of the frame in the
    label), the dark, bright and moving regions zoomed below, all tone-mapped against the truth; then each real
    stream's reference frame and every model's gain-scaled frame. None when nothing was pictured."""
    by_name = {seq.name: seq for seq in sequences}
    rows = []
    for name, i in scores[0].pictures if scores else ():
        gt = by_name[name].gt
        neighbour = gt[i + 1] if i + 1 < len(gt) else gt[i - 1]
        regions = (*pick_regions(gt[i]), pick_moving_region(neighbour, gt[i]))
        images = {f"truth: {name}, frame {i}": gt[i]}
        images.update({f"{s.name} {mu_law_psnr(s.pictures[name, i], gt[i]):.2f} dB": s.pictures[name, i]
                       for s in scores})
        rows.append(side_by_side(images, gt[i], regions))
    real = {stream.name: {s.name: s.real_frames[stream.name] for s in scores} for stream in streams}
    if real:
        rows.append(comparison_image(real, {stream.name: binned_reference(stream) for stream in streams},
                                     [s.name for s in scores]))
    if not rows:
        return None
    width = max(row.shape[1] for row in rows)
    gap = np.full((8, width, 3), 255, np.uint8)
    padded = [np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0)), constant_values=255) for row in rows]
    return np.vstack([part for row in padded for part in (row, gap)][:-1])
