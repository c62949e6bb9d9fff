"""Per-frame checks of a video reconstruction that a table of mean scores hides.

- Clip edges: the first and last frames against the clip's median frame (mu-law PSNR), and the
  moment each edge frame shows: the time offset at which the scene's ground truth matches the
  frame best (a window that repeats or leans on one side shows the scene early or late). Since a
  clip's first frames may simply show harder content than its median (a darker moment), the edge's own
  cost is measured too: the middle frame made mid-clip against the same frame made as the first (the
  stream cut to start there) and as the last (cut to end there): same content, same spikes.
- Rolling-band oscillation: the RMB band returns to a row every H / shift readouts (6.25 frames
  for 125 binned rows); the amplitude (dB) of the per-frame PSNR at that period, against the floor
  the same fit reads at other periods, on a slow pan and a still scene, beside methods that read the
  band.
- Long captures: a still textured scene over 100 frames, in both conventions: the mean quality early (the
  state as young as in the held-out sequences and training clips) against the second half.
- Dark-end bias: a flat, static field at levels 1e-3..1 (charge per raw plane relative to the
  threshold) through the physical emission model: the mean output over the clip's second half
  relative to the level, and the output's spatial coefficient of variation (invented texture). Two levels lie
  in the plateau where a reset-to-zero pixel fires every second plane over a range of charges: there the rate
  moves little with the level, so reading it back (the network's box candidates invert the measured response,
  ``rmbvideo.net.blend``) multiplies the rate's noise, and the estimate is noisier than its neighbours.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from collections.abc import Sequence as Seq
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rmbvideo.chunks import RmbChunk
from rmbvideo.evaluate.harness import SIMULATED_RESPONSE, sequence_convention
from rmbvideo.evaluate.heldout import FRAME_STEP, RAW_RATE_HZ, VIDEO_KINDS, Sequence
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
from rmbvideo.recon.run import trained_readout
from rmbvideo.scenes.render import bin_image
from rmbvideo.scenes.video import VideoScene
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout
from rmbvideo.sensor.response import flat_field_chunks

DARK_LEVELS = (1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 0.6, 0.8, 0.9, 1.0)
#: levels inside the reset-to-zero pixel's plateau, where its mean rate hardly changes (``rmbvideo.sensor.response``)
PLATEAU_LEVELS = (0.6, 0.8)
TIME_OFFSETS_MS = tuple(np.round(np.arange(-1.0, 1.0001, 0.05), 3))


@dataclass(frozen=True)
class EdgeReport:
    """Per-frame mu-law PSNR of a clip and, for its first and last frame, the drop below the median
    frame (dB) and the time offset (ms) at which the ground truth matches the frame best; the edge's own
    cost (dB): the middle frame made mid-clip minus the same frame made as a clip's first or last."""

    psnr: list[float]
    first_drop_db: float
    last_drop_db: float
    first_offset_ms: float
    last_offset_ms: float
    middle_offset_ms: float
    first_edge_cost_db: float
    last_edge_cost_db: float


class BinnedChunks:
    """Binned chunks held in memory, as the source ``reconstruct_stream`` reads."""

    def __init__(self, chunks: Seq[RmbChunk]) -> None:
        self._chunks = list(chunks)
        self.n_planes = sum(len(c.single) * c.raw_per_readout for c in self._chunks)

    def binned_chunks(self, chunk_planes: int, start: int = 0, stop: int | None = None) -> Iterator[RmbChunk]:
        return iter(self._chunks)


def run_rmb(method: str, options: dict, source: Sequence | BinnedChunks) -> dict[int, np.ndarray]:
    """Frames (index -> image) of a method on the binned stream of ``source``, through the readout its
    model was trained on (RMB for methods without a model); a held-out sequence's own convention, and the emission
    model's response (it made both kinds of source)."""
    if method == "rmbnet":
        options = {"response": SIMULATED_RESPONSE, **options}
        if isinstance(source, Sequence):
            options["convention"] = sequence_convention(source)
    recon = make_reconstructor(method, **options)
    sink = FrameCollector()
    reconstruct_stream(source, recon, sink, readout=RmbReadout(mode=ReadoutMode(trained_readout(recon))))
    return sink.images


def video_scene_of(seq: Sequence) -> VideoScene:
    """The scene a held-out video sequence was simulated from (rebuilt from its seed and kind)."""
    info = json.loads(seq.description)
    kind = next(k for k in VIDEO_KINDS if k.name == info["kind"])
    height, width = seq.shape
    return VideoScene(seq.seed, 2 * width, 2 * height, 2 * seq.readouts, kind.ranges, kind.convention)


def best_time_offset_ms(image: np.ndarray, scene: VideoScene, raw_plane: float) -> float:
    """The offset (ms) from ``raw_plane`` at which the scene's ground truth best matches ``image``."""
    scores = [mu_law_psnr(image, np.minimum(bin_image(scene.render(raw_plane + ms * RAW_RATE_HZ / 1000)), 1.0))
              for ms in TIME_OFFSETS_MS]
    return float(TIME_OFFSETS_MS[int(np.argmax(scores))])


def clip_frames(seq: Sequence, first: int, stop: int) -> Sequence:
    """Frames ``first .. stop - 1`` of ``seq`` as a clip of their own: its binned and raw streams cut there
    (a capture that starts or ends at that moment), its ground truth with them."""
    a, b = first * FRAME_STEP, stop * FRAME_STEP
    return replace(seq, single=seq.single[a:b], multi=seq.multi[a:b], raw_packed=seq.raw_packed[2 * a:2 * b],
                   gt=seq.gt[first:stop])


def edge_report(seq: Sequence, method: str = "rmbnet", options: dict | None = None) -> EdgeReport:
    """Clip-edge check of ``method`` on held-out video sequence ``seq`` (every frame scored)."""
    options = options or {}
    frames = run_rmb(method, options, seq)
    count = len(seq.gt)
    psnr = [mu_law_psnr(frames[i], np.minimum(seq.gt[i], 1.0)) for i in range(count)]
    median = float(np.median(psnr))
    scene = video_scene_of(seq)
    centre = lambda i: 2 * FRAME_STEP * i + FRAME_STEP  # noqa: E731  raw plane at frame i's centre
    first = best_time_offset_ms(frames[0], scene, centre(0))
    last = best_time_offset_ms(frames[count - 1], scene, centre(count - 1))
    mid = count // 2
    middle = best_time_offset_ms(frames[mid], scene, centre(mid))
    truth = np.minimum(seq.gt[mid], 1.0)
    as_first = run_rmb(method, options, clip_frames(seq, mid, count))[0]
    as_last = run_rmb(method, options, clip_frames(seq, 0, mid + 1))[mid]
    return EdgeReport(psnr, median - psnr[0], median - psnr[-1], first, last, middle,
                      psnr[mid] - mu_law_psnr(as_first, truth), psnr[mid] - mu_law_psnr(as_last, truth))


def band_sequence(width: int, height: int, frames: int, static: bool = False, seed: int = 1_600_000,
                  convention: str = "physical") -> Sequence:
    """A long held-out video sequence for the rolling-band check: slow motion, or (``static``) a still
    textured scene, where the per-frame PSNR varies with nothing but noise and the band's phase; in the
    physical convention or spikezoo's (a still scene there: the spikes are periodic, with no noise)."""
    from rmbvideo.evaluate.heldout import (
        HeldoutConfig,
        VideoHeldout,
        simulate_video_sequence,
    )
    from rmbvideo.scenes.video import VideoSceneRanges

    if static:
        kind = VideoHeldout("static" if convention == "physical" else f"static-{convention}",
                            VideoSceneRanges(static_probability=1.0, shake_px=0.0, zoom_rate=0.0,
                                             max_objects=0, median_rate=(0.02, 0.2)), convention)
        seed += 1 if convention == "physical" else 2
    else:
        kind = VideoHeldout("slow", VideoSceneRanges(camera_speed=(0.02, 0.05), static_probability=0.0,
                                                     object_speed=(0.01, 0.05), median_rate=(0.02, 0.2)))
    return simulate_video_sequence(seed, kind, HeldoutConfig(count=1, width=width, height=height,
                                                              readouts=frames * FRAME_STEP))


def band_period_frames(height: int, shift: int = 2) -> float:
    """Frames per cycle of the rolling band over ``height`` binned rows."""
    return height / shift / FRAME_STEP


def band_oscillation_db(psnr: Seq[float], period_frames: float) -> float:
    """Amplitude (dB) of the sinusoid of period ``period_frames`` fitted to a per-frame PSNR series
    (least squares, with its mean and a linear trend)."""
    t = np.arange(len(psnr), dtype=np.float64)
    omega = 2 * math.pi / period_frames
    design = np.stack([np.ones_like(t), t, np.cos(omega * t), np.sin(omega * t)], axis=1)
    coef, *_ = np.linalg.lstsq(design, np.asarray(psnr, np.float64), rcond=None)
    return float(math.hypot(coef[2], coef[3]))


def oscillation_floor_db(psnr: Seq[float], period_frames: float) -> float:
    """The same amplitude at periods away from the band's (3..16 frames, outside +-20 % of it),
    median over them: what the measure reads on this series when nothing oscillates at a period."""
    periods = [p for p in np.linspace(3.0, 16.0, 53) if abs(p / period_frames - 1.0) > 0.2]
    return float(np.median([band_oscillation_db(psnr, p) for p in periods]))


@dataclass(frozen=True)
class BandReport:
    """Per-frame mu-law PSNR of one method on one band-check sequence, its amplitude at the band's
    period and the measure's floor there (``oscillation_floor_db``)."""

    method: str
    sequence: str
    psnr: list[float]
    amplitude_db: float
    floor_db: float


def band_report(label: str, method: str, options: dict, seq: Sequence, period: float) -> BandReport:
    """Band check of ``method`` on ``seq`` (edge frames, whose windows are one-sided, left out)."""
    images = run_rmb(method, options, seq)
    psnr = [mu_law_psnr(images[i], np.minimum(seq.gt[i], 1.0)) for i in range(3, len(seq.gt) - 3)]
    return BandReport(label, seq.name, psnr, band_oscillation_db(psnr, period), oscillation_floor_db(psnr, period))


@dataclass(frozen=True)
class StateAgeReport:
    """Per-frame mu-law PSNR of a long still clip, and its means early (frames 3-8: the state is as young as in
    the held-out sequences, which is as old as training clips make it) and late (the second half: what a long
    capture gets once the state has settled)."""

    sequence: str
    psnr: list[float]
    early_db: float
    late_db: float


def state_age_report(method: str, options: dict, seq: Sequence) -> StateAgeReport:
    """How a still scene's quality changes as the recurrent state ages over a long clip (the content does not)."""
    images = run_rmb(method, options, seq)
    psnr = [mu_law_psnr(images[i], np.minimum(seq.gt[i], 1.0)) for i in range(len(seq.gt))]
    return StateAgeReport(seq.name, psnr, float(np.mean(psnr[3:9])), float(np.mean(psnr[len(psnr) // 2:])))


def dark_bias(method: str = "rmbnet", options: dict | None = None, levels: Seq[float] = DARK_LEVELS,
              size: tuple[int, int] = (48, 40), frames: int = 40, seed: int = 0) -> dict[float, tuple[float, float]]:
    """Per level: (relative bias of the mean output over the second half of the clip, spatial
    coefficient of variation of the last frame) of ``method`` on a flat static field. ``seed`` 0 is the
    evaluation's check; weight averages of the shipped model were chosen on seed 1."""
    width, height = size
    out = {}
    for level in levels:
        images = run_rmb(method, options or {}, BinnedChunks(flat_field_chunks(level, width, height, frames * FRAME_STEP, seed)))
        late = np.stack([images[i] for i in sorted(images)[len(images) // 2:]])
        last = images[max(images)]
        out[level] = (float(late.mean() / level - 1.0), float(last.std() / max(last.mean(), 1e-12)))
    return out


def write_checks(out_dir, method: str, options: dict, sequences: Seq[Sequence], quick: bool) -> list:
    """Run the three checks for ``method`` and write ``checks.md`` (and ``checks.png`` when
    matplotlib is installed) into ``out_dir``; returns the paths written."""
    from rmbvideo.io.atomic import atomic_write_text
    from rmbvideo.io.png import write_figure

    out_dir = Path(out_dir)
    lines = ["# Video checks: clip edges, rolling-band oscillation, dark end", "",
             f"Method: {method}. Targets (issue: real motion and texture): edge frames within 1.5 dB of the "
             "clip's median frame and within 0.2 ms of their timestamp; band-cycle oscillation < 0.1 dB; "
             "dark-end bias < 5 % from 1e-3 to 1.", "",
             "## Clip edges (held-out video sequences, every frame scored)", "",
             "Offset: the shift of the scene's time (ms, 0.05 ms steps, searched over +-1 ms) at which the ground "
             "truth matches the frame best; the middle frame's is the reference (a value at +-1.00 means no clear "
             "match within the range). Edge cost: the middle frame made mid-clip minus the same frame made as a "
             "clip's first frame (the stream cut to start there) or last (cut to end there): what the edge itself "
             "costs, with the content and the spikes unchanged.", "",
             "| sequence | first frame: dB below median | last frame: dB below median | first: offset ms | "
             "last: offset ms | middle: offset ms | edge cost as first frame (dB) | edge cost as last frame (dB) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    edges = {}
    for seq in sequences:
        report = edge_report(seq, method, options)
        edges[seq.name] = report
        lines.append(f"| {seq.name} | {report.first_drop_db:.2f} | {report.last_drop_db:.2f} | "
                     f"{report.first_offset_ms:+.2f} | {report.last_offset_ms:+.2f} | {report.middle_offset_ms:+.2f} | "
                     f"{report.first_edge_cost_db:.2f} | {report.last_edge_cost_db:.2f} |")
    width, height, frames = (112, 64, 40) if quick else (200, 125, 64)
    period = band_period_frames(height)
    sequences_band = [band_sequence(width, height, frames), band_sequence(width, height, frames, static=True)]
    controls = [("TFW-S (reads the band)", "tfw", {"window": FRAME_STEP, "step": FRAME_STEP})]
    rmb_model = Path(options["model"]).with_name("rmbnet-binned-rmb.safetensors") if "model" in options else None
    if rmb_model is not None and rmb_model.exists():
        controls.append(("RMB-Net, RMB readout", "rmbnet", {**options, "model": rmb_model}))
    bands = [band_report(label, m, o, seq, period) for seq in sequences_band
             for label, m, o in [(method, method, options), *controls]]
    lines += ["", "## Rolling-band oscillation", "",
              f"Held-out sequences of {frames} frames at {width}x{height} (a slow pan and a still textured scene); "
              f"band cycle {period:.2f} frames. Amplitude: the per-frame mu-law PSNR's sinusoid at that period "
              "(edge frames left out); floor: the median amplitude the same fit reads at periods of 3-16 frames "
              "away from the band's, i.e. what content and noise alone give. The TFW-S and RMB-readout rows read "
              "the RMB band itself (the default reads every bin count): what reading a band does to per-frame "
              "quality.", "",
              "| method | sequence | amplitude at the band period (dB) | floor (dB) |", "|---|---|---:|---:|"]
    lines += [f"| {b.method} | {b.sequence} | {b.amplitude_db:.3f} | {b.floor_db:.3f} |" for b in bands]
    long_frames = 40 if quick else 100
    ages = [state_age_report(method, options, band_sequence(width, height, long_frames, static=True,
                                                             convention=convention))
            for convention in ("physical", "spikezoo")]
    lines += ["", "## Long captures: a still scene as the recurrent state ages", "",
              f"Still textured scenes of {long_frames} frames at {width}x{height}, in the physical convention "
              "(noise) and spikezoo's (periodic spikes, no noise); the content never changes, so any trend is the "
              "state's age. Early: frames 3-8 (as old as the state gets in the held-out sequences); late: the "
              "second half (what a long capture gets).", "",
              "| sequence | early (dB) | late (dB) | late - early (dB) |", "|---|---:|---:|---:|"]
    lines += [f"| {a.sequence} | {a.early_db:.2f} | {a.late_db:.2f} | {a.late_db - a.early_db:+.2f} |" for a in ages]
    lines += [
              "", "## Dark end (flat static field, physical noise)", "",
              "Levels marked * lie in the plateau of a reset-to-zero pixel: from about 0.6 to 0.8 it fires every "
              "second plane over a range of charges (its mean binned rate goes only from 0.491 to 0.508 there, "
              "`rmbvideo.sensor.response`), so an estimate read back from rates is noisier there.", "",
              "| level (charge/plane/threshold) | relative bias | spatial CV of a frame |", "|---:|---:|---:|"]
    bias = dark_bias(method, options)
    for level, (rel, cv) in bias.items():
        mark = " *" if level in PLATEAU_LEVELS else ""
        lines.append(f"| {level:g}{mark} | {100 * rel:+.1f} % | {cv:.3f} |")
    md = out_dir / "checks.md"
    atomic_write_text(md, "\n".join(lines) + "\n")
    written = [md]
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return written
    fig, axes = plt.subplots(1, 4, figsize=(20, 4))
    for name, report in edges.items():
        axes[0].plot(report.psnr, marker=".", label=name)
    axes[0].set(xlabel="frame", ylabel="mu-law PSNR (dB)", title="per-frame quality: clip edges")
    axes[0].legend(fontsize=7)
    for band in bands:
        if band.sequence == sequences_band[-1].name:
            centred = np.asarray(band.psnr) - np.mean(band.psnr)
            axes[1].plot(range(3, 3 + len(centred)), centred, marker=".",
                         label=f"{band.method}: {band.amplitude_db:.3f} dB (floor {band.floor_db:.3f})")
    axes[1].set(xlabel="frame", ylabel="mu-law PSNR - mean (dB)",
                title=f"still scene, band cycle {period:.2f} frames")
    axes[1].legend(fontsize=7)
    for age in ages:
        axes[3].plot(age.psnr, marker=".", label=f"{age.sequence}: late - early {age.late_db - age.early_db:+.2f} dB")
    axes[3].set(xlabel="frame", ylabel="mu-law PSNR (dB)", title="long still clips: the state's age")
    axes[3].legend(fontsize=7)
    levels = list(bias)
    axes[2].semilogx(levels, [100 * bias[v][0] for v in levels], marker="o")
    axes[2].axhspan(-5, 5, color="green", alpha=0.15)
    axes[2].set(xlabel="level", ylabel="relative bias (%)", title="dark end: bias on a flat field")
    fig.tight_layout()
    return written + [write_figure(fig, out_dir / "checks.png", dpi=110)]
