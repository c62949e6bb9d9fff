"""``rmbvideo reconstruct``: one capture in, a video or an HDR frame sequence out."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from rmbvideo.cli import progress_enabled, quiet_option, verbose_option
from rmbvideo.cli.options import capture_options
from rmbvideo.io.sinks import PLAYBACK_FPS_RANGE, SINK_FORMATS
from rmbvideo.io.tonemap import TONE_METHODS
from rmbvideo.recon.full_resolution import DETAIL_KINDS, RAW_GATE_KINDS
from rmbvideo.recon.methods import DEFAULT_METHOD, METHODS
from rmbvideo.recon.run import CHUNK_BYTES, DEFAULT_RESOLUTION, RESOLUTIONS, run_reconstruction
from rmbvideo.sensor.conventions import CONVENTIONS, RESPONSES
from rmbvideo.sensor.readout import ReadoutMode
from rmbvideo.shipped import EDGE_MODEL_KINDS

log = logging.getLogger(__name__)



def _auto_choice(flag: str, choices: tuple[str, ...], help_text: str):
    """An option choosing among ``choices`` or "auto" (the default: decided per capture, ``recon.run.prepare_run``)."""
    return click.option(flag, type=click.Choice(["auto", *choices]), default="auto", show_default=True, help=help_text)


def rmbnet_options(func):
    """Options that only RMB-Net uses (ignored by the other methods)."""
    options = [
        click.option("--model", type=click.Path(path_type=Path), default=None,
                     help="RMB-Net weights (.safetensors with its .json card) [default: shipped binned model]."),
        click.option("--align", type=click.Choice(["none", "dis", "farneback", "tvl1"]), default="none",
                     show_default=True, help="Align the window's frames to the reference with optical flow."),
        click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto",
                     show_default=True, help="Where the network runs (auto: CUDA when available)."),
        click.option("--upsampling", type=click.Choice(["interp", "dis", "farneback", "tvl1"]),
                     default="interp", show_default=True,
                     help="Dense multi-bit planes from the rolling band: flow-free interpolation or optical flow."),
        click.option("--precision", type=click.Choice(["auto", "fp32", "bf16"]), default="auto",
                     show_default=True, help="Network precision (auto: bf16 on CPUs with AVX512-BF16 or AMX, where it is faster; fp32 elsewhere, CUDA included)."),
        click.option("--threads", type=click.IntRange(min=1), default=None,
                     help="CPU threads [default: the thread policy: for the network 1 on a busy or 2-core machine, "
                  "else the idle cores, at most 8; RMB-Net's aligned window means in a thread of their own "
                  "when a second core is idle, and, with the network on 1 or 2 threads, the full-resolution raw "
                  "rates, gate and detail stage in another, a chunk behind the network; with the network on a GPU, "
                  "every core but one for the aligned means]. With 2 or more, the aligned means take one of them "
                  "(with 2, the full-resolution stages run beside the network); on a GPU the aligned means take "
                  "them all."),
        _auto_choice("--convention", CONVENTIONS,
                     "What made the spikes (rmbnet, gc20 and mg20 read it): physical (pixels reset to zero at a spike: "
                     "rmbvideo's emission model) or "
                     "spikezoo (the charge past the threshold kept: spikezoo's REDS streams, and real cameras such as "
                     "car.dat's). auto: for a capture `rmbvideo simulate` made, the pixel its sidecar records; else "
                     "what its first 200 planes show (a pile-up of spike counts at half the planes means reset to "
                     "zero), physical when they cannot tell."),
        _auto_choice("--response", RESPONSES,
                     "How a camera's rates are read back as light where RMB-Net passes them through: closed-form (any "
                     "camera: smooth, reads above half a threshold per plane dark) or emission-model (the tabulated "
                     "response of rmbvideo's simulated camera: exact for streams `rmbvideo simulate` made with shot "
                     "noise and threshold mismatch, as every bundled scene has; contours on a camera whose response "
                     "differs). auto: emission-model where the capture's sidecar says `rmbvideo simulate` made it "
                     "with those effects, else closed-form."),
        click.option("--frame-batch", type=click.IntRange(min=1), default=None,
                     help="Output frames RMB-Net makes per batched pass (its ConvLSTM still steps through them in "
                          "order; the same frames) [default: up to 128 on a GPU, fewer for large frames; 1 on a CPU, "
                          "where batching loses]."),
        click.option("--prime", type=click.IntRange(min=0), default=None,
                     help="Frames after the first whose evidence RMB-Net's first frame reads through its recurrent "
                          "state, by running the network backwards over them once (0: the first frames start from "
                          "an empty state) [default: the model's w]."),
        click.option("--edges", type=click.Choice(EDGE_MODEL_KINDS), default="auto", show_default=True,
                     help="RMB-Net's first and last w frames of a clip, whose windows its edges cut: auto: mixed half "
                          "and half with those of the model's edge model where one is beside it "
                          "(NAME-edges.safetensors, trained on those frames alone: the default model has one); off: "
                          "the model's alone."),
        click.option("--cuda-graphs/--no-cuda-graphs", default=True, show_default=True,
                     help="On a GPU, replay RMB-Net's ConvLSTM steps through a batched pass as CUDA graphs (the same "
                          "frames, fewer kernel launches)."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("-o", "--output", "outdir", required=True, type=click.Path(path_type=Path),
              help="Output folder (created if missing).")
@click.option("--method", type=click.Choice(sorted(METHODS)), default=DEFAULT_METHOD, show_default=True,
              help="Reconstruction method: " + "; ".join(f"{m.name}: {m.help}" for m in METHODS.values()) + ".")
@click.option("--window", type=click.IntRange(min=0), default=None,
              help="Window: raw planes for tfp [41]; binned readouts for tfw [10 = TFW-S; 70 = TFW-L]; "
                   "for rmbnet the half-width w of the model (0..3; 2w+1 preliminary frames) [3].")
@click.option("--step", type=click.IntRange(min=1), default=None,
              help="Raw planes per output frame [default: 20 (1000 frames per second of a 20 kHz "
                   "capture); 10 for a native RMB capture, whose readouts are not binned]. RMB-Net makes a frame "
                   "every 20 (10): a multiple keeps every k-th of them, e.g. 660 for about 30 a second of capture "
                   "(a video that plays in real time at --fps 30).")
@click.option("--format", "fmt", type=click.Choice(SINK_FORMATS), default="mp4", show_default=True,
              help="mp4 (tone-mapped SDR H.264, BT.709), hdr10 (HEVC Main10, BT.2020, PQ), hlg (HEVC Main10, "
                   "BT.2020, HLG), exr (linear HDR frames), png (tone-mapped 8-bit), null (timing).")
@click.option("--fps", type=click.FloatRange(*PLAYBACK_FPS_RANGE), default=30.0, show_default=True,
              help="Video playback frame rate.")
@click.option("--nits-per-unit", type=click.FloatRange(min=0, min_open=True), default=None,
              help="HDR video (hdr10, hlg): display light (cd/m^2) of one linear unit [default: chosen from the "
                   "first frames, their median at 20 nits].")
@click.option("--pixel-format", type=click.Choice(["auto", "yuv420p", "yuv444p"]), default="auto",
              show_default=True,
              help="MP4 chroma: auto keeps the exact size (yuv444p for odd sizes, which QuickTime and some "
                   "hardware players cannot open); yuv420p plays everywhere but pads odd sizes by one row/column.")
@click.option("--tonemap", type=click.Choice(TONE_METHODS), default="exposure", show_default=True,
              help="Tone mapping for mp4/png.")
@click.option("--exr-dtype", type=click.Choice(["half", "float"]), default="half", show_default=True,
              help="EXR pixel type; half clips values above 65504.")
@click.option("--readout", type=click.Choice([m.value for m in ReadoutMode]), default=None,
              help="Readout design applied to the binned stream (rmbnet, tfw, gc20, mg20) [default: the one the "
                   "RMB-Net model was trained on; rmb for the other methods].")
@click.option("--resolution", type=click.Choice(RESOLUTIONS), default=DEFAULT_RESOLUTION, show_default=True,
              help="Output size of methods on the binned stream from a real 1-bit capture: full (the camera's: the "
                   "binned result's levels with the raw stream's detail inside each 2x2 block) or binned (half the "
                   "camera's: the binned result, with RMB-Net mixed with the raw intervals as at full size, which "
                   "the full frames average to; about 1.2x faster on 2 cores).")
@click.option("--detail", type=click.Choice(DETAIL_KINDS), default="auto", show_default=True,
              help="With --resolution full: how the detail inside each 2x2 block is found: learned (the shipped "
                   "detail stage), classical (noise-gated TFP ratio); auto: learned when installed.")
@click.option("--raw-gate", type=click.Choice(RAW_GATE_KINDS), default="auto", show_default=True,
              help="With RMB-Net on a 1-bit capture, at either --resolution: mix each binned frame per pixel with TFI "
                   "of the raw planes where the shipped raw-interval gate trusts it (dim fine texture of slow scenes); "
                   "off: RMB-Net's binned frame as it is.")
@capture_options
@click.option("--start", "start_s", type=click.FloatRange(min=0), default=0.0, show_default=True,
              help="Start time in seconds from the beginning of the capture.")
@click.option("--duration", "duration_s", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Seconds of capture to process [default: to the end].")
@click.option("--chunk-planes", type=click.IntRange(min=1), default=1024, show_default=True,
              help=f"Raw planes read per chunk (memory bound, cut to {CHUNK_BYTES // 2**20} MiB of decoded planes; the "
                   "output does not depend on it).")
@rmbnet_options
@click.option("--overwrite", is_flag=True,
              help="Replace the outputs of an earlier run in OUTDIR (kept intact until the new run is complete).")
@click.option("--resume", is_flag=True,
              help="For a long capture (--format exr or png): if this run is interrupted (Ctrl-C, a full disk, a "
                   "crash) its frames are kept, and the same command with --resume again continues it from the "
                   "first frame missing.")
@quiet_option
@verbose_option
def reconstruct(input_path: Path, outdir: Path, method: str, window, step, fmt: str, fps: float,
                pixel_format: str, tonemap: str, exr_dtype: str, readout: str, resolution: str, detail: str,
                raw_gate: str, width, height, flip,
                header_cols, rate_hz,
                start_s: float, duration_s, chunk_planes: int, model, align: str, device: str,
                upsampling: str, precision: str, threads, convention: str, response: str, frame_batch, prime,
                edges: str, cuda_graphs: bool, overwrite: bool, resume: bool,
                nits_per_unit,
                quiet: bool) -> None:
    """Reconstruct a .dat capture INPUT into frames in OUTDIR."""
    extra = dict(model=model, align=align, device=device, upsampling=upsampling, precision=precision,
                 threads=threads, convention=convention, response=response, frame_batch=frame_batch, prime=prime,
                 edges=edges, cuda_graphs=cuda_graphs)
    _warn_unread(click.get_current_context(), method, extra)
    summary = run_reconstruction(
        input_path, outdir, method=method, window=window, step=step, fmt=fmt, fps=fps,
        pixel_format=pixel_format, tonemap=tonemap, exr_dtype=exr_dtype, readout=readout, start_s=start_s,
        duration_s=duration_s, chunk_planes=chunk_planes, progress=progress_enabled(quiet),
        capture=dict(width=width, height=height, flip=flip, header_cols=header_cols, rate_hz=rate_hz),
        extra_options=extra, overwrite=overwrite, nits_per_unit=nits_per_unit, resolution=resolution,
        detail=detail, raw_gate=raw_gate, resume=resume,
    )
    if not quiet:
        kept = f" (and {summary.kept} kept from the interrupted run)" if summary.kept else ""
        frames = f"{summary.frames} frame{'' if summary.frames == 1 else 's'}"
        click.echo(f"{frames}{kept} from {summary.planes} planes in {summary.seconds:.2f} s "
                   f"({summary.frames_per_second:.1f} frames/s) -> {outdir}", err=True)


def _warn_unread(ctx: click.Context, method: str, extra: dict) -> None:
    """Log the method options typed on the command line that ``method`` does not read (``--threads`` is every
    method's), so a setting with no effect is not taken for one that had it."""
    spec = METHODS.get(method)
    if spec is None:  # an unknown method is refused with its own message
        return
    unread = [f"--{name.replace('_', '-')}" for name in extra
              if name != "threads" and name not in spec.extra_options
              and ctx.get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE]
    if unread:
        log.warning("%s: not read by --method %s, ignored", ", ".join(unread), method)
