"""``rmbvideo evaluate``: the paper's Table 2 on the held-out synthetic set, plus comparison figures.

Writes ``evaluation.md``, ``evaluation.csv`` and ``evaluation.png`` into ``--out``; with ``--real`` also
``real_comparison.png`` (RMB-Net vs TFP vs TFI on a real capture).
"""

from __future__ import annotations

import json
import logging
import math
import os
import platform
from pathlib import Path
from typing import TYPE_CHECKING

import click

from rmbvideo.cli import progress_enabled, quiet_option, verbose_option
from rmbvideo.cli.options import AliasOption

if TYPE_CHECKING:  # the evaluation modules load torch: imported where a command runs, not when the CLI starts
    from rmbvideo.evaluate.harness import RowResult
    from rmbvideo.evaluate.heldout import Sequence
    from rmbvideo.evaluate.real_video import RealStream

log = logging.getLogger(__name__)
#: The files ``evaluate`` can write into its folder: those a run did not write are an earlier run's.
REPORT_PATTERNS = ("evaluation.md", "evaluation.csv", "evaluation*.png", "checks.md", "checks.png", "real_video.*",
                   "texture_pans.*", "full_resolution.*", "development.*", "real_comparison.png")


def warn_of_earlier_reports(out_dir: Path, written: list[Path]) -> list[str]:
    """Name (in a warning, and return) the reports in ``out_dir`` that this run did not write: an earlier run's, with
    other options, which a reader would otherwise take for this run's."""
    mine = {Path(path).name for path in written}
    earlier = sorted({path.name for pattern in REPORT_PATTERNS for path in out_dir.glob(pattern)
                      if path.suffix in (".md", ".csv", ".png") and path.name not in mine})
    if earlier:
        log.warning("%s: %s %s from an earlier run, not this one (other options); move or delete %s to avoid "
                    "confusion", out_dir, ", ".join(earlier), "is" if len(earlier) == 1 else "are",
                    "it" if len(earlier) == 1 else "them")
    return earlier


def _real_video(streams: list[RealStream], model: Path, device: str, out_dir: Path, stem: str = "real_video",
                title: str = "Real-video streams", pictured: tuple[str, ...] = ("",),
                precision: str = "auto") -> list[Path]:
    """Score the real-video ``streams`` (``find_streams``); write ``STEM.md`` and ``STEM.png`` (of the streams whose
    name contains one of ``pictured``)."""
    from rmbvideo.evaluate.real_video import (
        BEST_RAW,
        GATED_ROW,
        binned_reference,
        comparison_image,
        evaluate_streams,
        markdown_table,
        real_video_rows,
    )
    from rmbvideo.io.png import write_png
    from rmbvideo.io.atomic import atomic_write_text

    results = evaluate_streams(streams, real_video_rows(model, device, precision=precision))
    md = out_dir / f"{stem}.md"
    atomic_write_text(md, f"# {title} (reference frame, least-squares gain, binned resolution)\n\n"
                      + markdown_table(results) + "\nCells: linear PSNR (dB) / SSIM of the frame made at the "
                      "reference's moment; raw rows are 2x2 area-averaged; the best raw row is chosen per stream.\n")
    references = {s.name: binned_reference(s) for s in streams if any(p in s.name for p in pictured)}
    gated = [GATED_ROW] if GATED_ROW in next(iter(results.values())) else []
    png = write_png(out_dir / f"{stem}.png",
                    comparison_image({name: results[name] for name in references}, references,
                                     ["TFW-L", "GC20", "MG20", "RMB-Net", *gated, BEST_RAW]))
    return [md, png]


def _development(out_dir: Path, models: list[Path], cache_dir: Path | None, real_video: Path | None, device: str,
                 progress: bool) -> list[Path]:
    """Score ``models`` on the development sets; write ``development.md`` and the pictured frames,
    ``development.png``."""
    from tqdm import tqdm

    from rmbvideo.evaluate.development import development_figure, long_clips, markdown, score_candidates
    from rmbvideo.evaluate.heldout import default_cache_dir, load_development
    from rmbvideo.evaluate.real_video import find_streams
    from rmbvideo.evaluate.texture_pans import texture_pan_folder
    from rmbvideo.io.atomic import atomic_write_text
    from rmbvideo.io.png import write_png
    from rmbvideo.net.weights import load_model

    for model in models:  # a bad file fails here, in one line, before any simulation
        load_model(model)
    sequences, camera = load_development(cache_dir), load_development(cache_dir, reset="subtract")
    clips = find_streams(texture_pan_folder(cache_dir if cache_dir is not None else default_cache_dir()))
    real = find_streams(real_video) if real_video is not None else []
    with tqdm(total=len(models), disable=not progress, unit="model", desc="development") as bar:
        scores = score_candidates(models, sequences, clips, real, device, done=lambda: bar.update(1), long=long_clips(),
                                  camera=camera)
    path = out_dir / "development.md"
    atomic_write_text(path, markdown(scores, models))
    figure = development_figure(scores, sequences, real)
    return [path] + ([] if figure is None else [write_png(out_dir / "development.png", figure)])


def _precision_used(precision: str, device: str) -> str:
    """What ``precision`` runs the network in on ``device``: "fp32" or "bf16" (and "auto" named as such)."""
    import torch

    from rmbvideo.recon.precision import uses_bf16

    used = "bf16" if uses_bf16(precision, torch.device(device)) else "fp32"
    return f"auto: {used}" if precision == "auto" else used


def _notes(sequences: list, quick: bool, device: str, figure: tuple[str, int], reset: str = "zero",
           precision: str = "auto") -> str:
    """The Markdown notes under the table: what was measured, on what, how."""
    import torch

    from rmbvideo.evaluate.heldout import FRAME_STEP

    seq = sequences[0]
    height, width = seq.shape
    scored = sum(len(s.scored_frames) for s in sequences)
    names = ", ".join(f"{s.name} ({json.loads(s.description).get('panorama') or json.loads(s.description)['convention']})"
                      for s in sequences)
    return "\n".join([
        "## Notes",
        "",
        f"- Set: {'quick' if quick else 'full'}, {len(sequences)} held-out sequences ({names}); evaluation seeds "
        "of `rmbvideo.scenes.random_scenes` (panorama pans) and of `rmbvideo.scenes.video` (fast, dark, "
        "fast-dark and spikezoo-convention video scenes), never used in training. Each: "
        f"{seq.readouts} binned readouts at "
        f"{width}x{height}, {seq.rate_hz:g} Hz, simulated as 1-bit at {2 * width}x{2 * height} and "
        f"{2 * seq.rate_hz:g} Hz with realistic noise, then 2x2x2-binned."
        + (" The cameras' pixels reset by subtraction (`--reset subtract`: the charge past the threshold kept, like "
           "car.dat's camera), so their streams are in the rate convention, with the camera's noise." if reset ==
           "subtract" else ""),
        f"- Frames: one per {FRAME_STEP} binned readouts; ground truth = linear radiance at the frame's centre. "
        f"Scored: the {scored} frames whose +-{seq.edge_readouts}-readout neighbourhood lies inside their sequence "
        "(same frames for every method).",
        "- Input: the binned stream through the default model's readout design (the one it was trained on: "
        "every bin count for the shipped model) for the baselines and RMB-Net; 'RMB-Net, RMB readout' and the "
        "ablations through their own design (RMB band 4 / shift 2, Pure-S, Pure-M, Full-M); TFI gets the 1-bit "
        "plane of that stream; the '(raw)' rows are TFP and TFI on the raw full-resolution capture, 2x2 "
        "area-averaged to the ground-truth size. 'best classical on the raw capture' takes, per sequence, the "
        "best of those raw rows. 'RMB-Net + raw gate (1-bit capture)' is what the default job makes of the raw "
        "capture at this size (`reconstruct --resolution binned`, the default full frames' 2x2 average): RMB-Net's "
        "frames mixed with the raw intervals by the shipped gate; set it against the raw rows, and RMB-Net against "
        "the methods on its own input. RMB-Net is told each sequence's sensor convention (spikezoo-fast: "
        "spikezoo's) and, rmbvideo's emission model having made them all, that camera's response (`reconstruct "
        "--response emission-model`; a real capture is read by the closed form). TFP, TFI and TFW give spike rates, "
        "not light: on those camera streams their frames are read through the same response, per pixel before any 2x2 "
        "average (`harness.rate_as_light`; a reset-to-zero pixel's rate is below its light, 20 % at half a "
        "threshold per plane); GC20 and MG20 estimate light by their own likelihoods, told the convention too: the "
        "thresholded-Poisson jot model on a reset-to-zero camera's streams, the firing rate itself in the rate "
        "convention (`reconstruct --convention`; until 2026-11-28 always Poisson, 39 % bright at half a spike per "
        "plane there).",
        "- Metrics: PSNR and SSIM of mu-law tone-mapped frames (mu = 5000) after dividing by the ground truth's "
        "99.9th percentile; PU21 PSNR replaces HDR-VDP-3/HDR-VQM (MATLAB only); temporal mu-PSNR: the PSNR of the "
        "mu-law frame-to-frame differences against the ground truth's over consecutive scored frames (flicker and "
        "shimmer; an error held still costs nothing there). Per-sequence means, then the mean over sequences.",
        f"- frames/s: output frames per wall-clock second, end to end from the input stream, measured in this run "
        f"({platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__} with "
        f"{torch.get_num_threads()} threads, device {device}, precision {_precision_used(precision, device)}). "
        "Network frames/s: RMB-Net's network alone.",
        "- 'not trained': no weight file in the models folder (ablations: `[ablations/]rmbnet-binned-<w0|pure-s|"
        "pure-m|full-m|no-xba|no-xta>.safetensors`, from the short recipes `ablation-*.toml`).",
        f"- Figure: {figure[0]}, frame {figure[1]}; zooms of the darkest and brightest textured ground-truth "
        "patches, each re-exposed to its own ground-truth patch.",
        "",
    ])


#: the rows the fast/dark figures show: the RMB-input baselines, RMB-Net (alone, and with the raw gate as the default
#: job runs it on a 1-bit capture) and the raw-capture methods
FIGURE_COLUMNS = ("TFW-L", "GC20", "MG20", "RMB-Net", "RMB-Net + raw gate (1-bit capture)", "TFP-41 (raw)", "TFI (raw)")


def _heldout_outputs(rows: list[RowResult], sequences: list[Sequence], out_dir: Path, quick: bool, device: str,
                     reset: str, precision: str = "auto") -> list[Path]:
    """The held-out tables (evaluation.md/.csv), the comparison figure and the fast/dark sequences' figures."""
    import numpy as np

    from rmbvideo.evaluate.harness import SATURATION, middle_frame
    from rmbvideo.evaluate.table import write_comparison_png, write_sequence_png, write_tables

    figure_seq = sequences[0]
    figure_frame = figure_seq.scored_frames[len(figure_seq.scored_frames) // 2]
    md, table = write_tables(rows, out_dir, _notes(sequences, quick, device, (figure_seq.name, figure_frame), reset,
                                                   precision))
    # figures show the ground truth as it is scored: clipped at the sensor's saturation
    png = write_comparison_png(rows, np.minimum(figure_seq.gt[figure_frame], SATURATION), figure_frame,
                               out_dir / "evaluation.png")
    written = [md, table, png]
    for seq in sequences:
        kind = json.loads(seq.description).get("kind")
        if kind in ("fast", "dark"):
            written.append(write_sequence_png(rows, seq.name, np.minimum(seq.gt[middle_frame(seq)], SATURATION),
                                              out_dir / f"evaluation-{kind}.png", FIGURE_COLUMNS))
    return written


@click.command()
@click.option("--models", "models_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder with rmbnet-binned.safetensors and ablations/*.safetensors [shipped models].")
@click.option("--quick", is_flag=True, help="2 small, short sequences (a few minutes on 2 CPU cores).")
@click.option("-o", "--output", "--out", "out_dir", cls=AliasOption, aliases=("--out",),
              type=click.Path(file_okay=False, path_type=Path),
              default=Path("evaluation"), show_default=True, help="Folder for evaluation.md/.csv/.png.")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Cache of simulated held-out sequences [~/.cache/rmbvideo/heldout].")
@click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True,
              help="Device for RMB-Net rows.")
@click.option("--precision", type=click.Choice(["auto", "fp32", "bf16"]), default="auto", show_default=True,
              help="RMB-Net's precision, as `reconstruct --precision` (auto: bf16 on CPUs with AVX512-BF16 or AMX). "
                   "bf16 moves the binned scores by up to 0.02 dB; fp32 gave the same figures, to 0.01 dB, on every CPU "
                   "measured. Not with --development, whose candidates run as the engine runs them.")
@click.option("--json", "as_json", is_flag=True, help="Also print the rows as JSON on stdout.")
@click.option("--real", "real_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write real_comparison.png for this real capture (RMB-Net vs TFP vs TFI).")
@click.option("--real-video", "real_video", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Also score every method on a folder of real-video spike streams with reference frames "
                   "(NAME.dat + NAME.png, spikezoo's format; each capture as large as its PNG): real_video.md and "
                   "real_video.png.")
@click.option("--heldout/--no-heldout", default=True, show_default=True,
              help="Score the held-out synthetic set (evaluation.md/.csv/.png, the per-frame checks); --no-heldout "
                   "scores only what --real-video, --texture-pans or --real name, e.g. a folder of your own streams.")
@click.option("--texture-pans", is_flag=True,
              help="Also score the development clips: textures panned at known speeds in spikezoo's convention, "
                   "written once into the cache (texture_pans.md/.png).")
@click.option("--full-resolution", is_flag=True,
              help="Also score --resolution full against TFP and TFI at the camera's full resolution "
                   "(full_resolution.md/png; the real-video streams too when given).")
@click.option("--development", is_flag=True,
              help="Instead of the held-out tables, score the default model and each --candidate on the development "
                   "sets (development sequences and clips, --real-video streams, the development sequences from a real "
                   "camera's pixel, the dark end): development.md.")
@click.option("--reset", type=click.Choice(["zero", "subtract"]), default="zero", show_default=True,
              help="What a spike does to the simulated held-out cameras' pixels: zero (the paper's: the charge "
                   "discarded) or subtract (the charge past the threshold kept, like car.dat's real camera: "
                   "streams in the rate convention with the camera's noise; cached apart).")
@click.option("--candidate", "candidates", multiple=True, type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="A model file to score beside the default with --development (repeatable).")
@quiet_option
@verbose_option
def evaluate(models_dir: Path | None, quick: bool, out_dir: Path, cache_dir: Path | None, device: str,
             precision: str, as_json: bool, real_path: Path | None, real_video: Path | None, heldout: bool,
             texture_pans: bool, full_resolution: bool, development: bool, reset: str, candidates: tuple[Path, ...], quiet: bool) -> None:
    """Score TFW-S/L, TFI, GC20, MG20, RMB-Net, its ablations and the classical methods on the raw
    capture (2x2-averaged) on the held-out synthetic set, and optionally on real-video streams (with
    --no-heldout, those alone); with --development, candidate models on the development sets instead."""
    from rmbvideo.io.atomic import output_folder, outputs_together
    from rmbvideo.evaluate.harness import evaluate_rows, table2_specs, with_best_raw
    from rmbvideo.evaluate.heldout import load_heldout, load_video_heldout
    from rmbvideo.evaluate.table import real_capture_comparison
    from rmbvideo.net.weights import MODELS_DIR
    from rmbvideo.recon.rmbnet import resolve_device

    models_dir = models_dir if models_dir is not None else MODELS_DIR
    if candidates and not development:
        raise click.UsageError("--candidate needs --development")
    if development and precision != "auto":
        raise click.UsageError("--precision is not used by --development (its candidates run as the engine runs them)")
    if not heldout and (development or as_json or not (real_video or texture_pans or real_path)):
        raise click.UsageError("--no-heldout scores only --real-video, --texture-pans or --real (not --development "
                               "or --json, which are the held-out set's)")
    from rmbvideo.evaluate.real_video import find_streams

    streams = find_streams(real_video) if real_video is not None else []  # a wrong folder fails before the long run
    resolved = str(resolve_device(device))
    with output_folder(out_dir), outputs_together(out_dir, REPORT_PATTERNS):  # all of this run's reports, or none
        if development:
            paths = _development(out_dir, [models_dir / "rmbnet-binned.safetensors", *candidates], cache_dir,
                                 real_video, resolved, progress_enabled(quiet))
            log.info("wrote %s", ", ".join(map(str, paths)))
            warn_of_earlier_reports(out_dir, paths)
            return
        sequences, rows, written = [], [], []
        if heldout:
            sequences = load_heldout(quick, cache_dir, reset) + load_video_heldout(quick, cache_dir, reset=reset)
            rows = with_best_raw(evaluate_rows(table2_specs(models_dir, resolved, precision), sequences,
                                               progress=progress_enabled(quiet)))
            written = _heldout_outputs(rows, sequences, out_dir, quick, resolved, reset, precision)
            from rmbvideo.evaluate.video_checks import write_checks

            video = [seq for seq in sequences if json.loads(seq.description).get("kind")]
            written += write_checks(out_dir, "rmbnet", {"model": models_dir / "rmbnet-binned.safetensors",
                                                        "device": resolved, "precision": precision, "threads": 1},
                                       video, quick)
        if streams:
            written += _real_video(streams, models_dir / "rmbnet-binned.safetensors", resolved, out_dir,
                                   precision=precision)
        if texture_pans:
            from rmbvideo.evaluate.heldout import default_cache_dir
            from rmbvideo.evaluate.texture_pans import texture_pan_folder

            folder = texture_pan_folder(cache_dir if cache_dir is not None else default_cache_dir())
            written += _real_video(find_streams(folder), models_dir / "rmbnet-binned.safetensors", resolved, out_dir,
                                   "texture_pans", "Development clips: textures panned in spikezoo's convention",
                                   pictured=("c16-v14", "c16-v28"), precision=precision)
        if full_resolution and (sequences or streams):
            from rmbvideo.evaluate.full_resolution import write_full_resolution

            written += write_full_resolution(out_dir, sequences, streams, models_dir / "rmbnet-binned.safetensors",
                                             precision=precision)
        if real_path is not None:
            model = models_dir / "rmbnet-binned.safetensors"
            written.append(real_capture_comparison(real_path, out_dir / "real_comparison.png", model, resolved,
                                                   precision=precision))
        if as_json:
            click.echo(json.dumps([{"method": r.name, "status": r.status,
                                    **{k: (getattr(r, k) if math.isfinite(getattr(r, k)) else None)
                                       for k in ("psnr", "ssim", "pu21", "temporal", "fps", "network_fps")}}
                                   for r in rows],
                                  indent=2))
        for path in written:
            log.info("wrote %s", path)
        warn_of_earlier_reports(out_dir, written)
