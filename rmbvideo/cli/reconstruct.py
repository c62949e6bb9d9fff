"""``rmbvideo reconstruct``: one capture in, a video or an HDR frame sequence out."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import click

from rmbvideo.cli import progress_enabled
from rmbvideo.cli.options import capture_options, open_capture
from rmbvideo.errors import InputError
from rmbvideo.io.rmbfile import RmbFileReader
from rmbvideo.io.sinks import SINK_FORMATS, make_sink
from rmbvideo.recon.pipeline import RECONSTRUCTORS, RunSummary, make_reconstructor, reconstruct_stream
from rmbvideo.recon.tonemap import ToneMapConfig
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

log = logging.getLogger(__name__)

DEFAULT_METHOD = "rmbnet"
TONEMAPS = ("mulaw", "reinhard", "drago", "mantiuk")


def method_options(method: str, window: int | None, step: int, raw_per_readout: int = 2) -> dict:
    """Keyword options for ``method``. ``step`` is in raw planes; methods on the mixed-bit stream
    count readouts, each ``raw_per_readout`` raw planes (2 for binned data, 1 for a native sensor)."""
    if window == 0 and method != "rmbnet":
        raise click.BadParameter("a window of 0 is only meaningful for rmbnet (w = 0)", param_hint="--window")
    if method == "tfp":
        return {"step": step, **({"window": window} if window else {})}
    if method == "tfi":
        return {"step": step}
    if step % raw_per_readout:
        raise click.BadParameter(f"methods on the binned stream need an even step, got {step}",
                                 param_hint="--step")
    if method == "rmbnet":
        if step != 10 * raw_per_readout:
            raise click.BadParameter(
                f"RMB-Net's frame step is fixed by its model (N = 10 readouts = {10 * raw_per_readout} "
                "raw planes)", param_hint="--step")
        if window is not None and window > 3:
            raise click.BadParameter("RMB-Net's window half-width w is 0..3", param_hint="--window")
        return {} if window is None else {"w": window}
    options: dict = {"step": step // raw_per_readout}
    if window:
        options["window"] = window
    return options


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
                     show_default=True, help="Network precision (auto: bf16 autocast on CUDA, fp32 on CPU)."),
        click.option("--threads", type=click.IntRange(min=1), default=None,
                     help="CPU threads for the network [default: torch's choice; 1 is fastest on a busy machine]."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def rmbnet_extra_options(method: str, model, align: str, device: str, upsampling: str,
                         precision: str, threads: int | None = None) -> dict:
    """Keyword options for the RMB-Net factory; empty for the other methods."""
    if method != "rmbnet":
        return {}
    return {"model": model, "align": align, "device": device, "upsampling": upsampling,
            "precision": precision, "threads": threads}


def run_reconstruction(input_path: Path, outdir: Path, *, method: str = DEFAULT_METHOD,
                       window: int | None = None, step: int | None = None, fmt: str = "mp4",
                       fps: float = 30.0, tonemap: str = "mulaw", exr_dtype: str = "half",
                       pixel_format: str = "auto",
                       readout: str = "rmb", start_s: float = 0.0, duration_s: float | None = None,
                       chunk_planes: int = 1024, progress: bool = False,
                       capture: dict | None = None, extra_options: dict | None = None) -> RunSummary:
    """Reconstruct ``input_path`` into ``outdir``: the library form of the command (used by batch).

    The input is opened and checked before anything is created, and a failed run removes what it
    wrote (and ``outdir`` itself if this run created it), so bad input leaves no output behind.
    """
    reader = open_capture(input_path, **(capture or {}))
    start = reader.plane_index(start_s)
    stop = reader.n_planes if duration_s is None else min(reader.n_planes,
                                                           start + reader.plane_index(duration_s))
    if start >= reader.n_planes:
        raise InputError(f"{input_path}: --start {start_s} s is past the end of the capture "
                         f"({reader.duration_s:.6f} s)")
    native = isinstance(reader, RmbFileReader)
    step = step or (10 if native else 20)
    options = method_options(method, window, step, raw_per_readout=1 if native else 2)
    options.update(extra_options or {})
    if native and method == "rmbnet":
        options.setdefault("input_mode", "native")
    try:
        recon = make_reconstructor(method, **options)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    # A native capture was read out by its sensor already; binned data gets the chosen design.
    rmb_readout = RmbReadout(mode=ReadoutMode(readout)) if recon.input_kind == "rmb" and not native else None
    created = not outdir.exists()
    try:
        with make_sink(fmt, outdir, fps=fps, tonemap=ToneMapConfig(method=tonemap),
                       exr_dtype=exr_dtype, mp4_pixel_format=pixel_format, capture_rate_hz=reader.rate_hz,
                       frame_rate_hz=reader.rate_hz / step) as sink:
            summary = reconstruct_stream(reader, recon, sink, start=start, stop=stop,
                                         chunk_planes=chunk_planes, progress=progress,
                                         readout=rmb_readout)
    except BaseException:
        if created and outdir.is_dir() and not any(outdir.iterdir()):
            shutil.rmtree(outdir, ignore_errors=True)
        raise
    return summary


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("-o", "--output", "outdir", required=True, type=click.Path(path_type=Path),
              help="Output folder (created if missing).")
@click.option("--method", type=click.Choice(sorted(RECONSTRUCTORS)), default=DEFAULT_METHOD,
              show_default=True, help="Reconstruction method.")
@click.option("--window", type=click.IntRange(min=0), default=None,
              help="Window: raw planes for tfp [41]; binned readouts for tfw [10 = TFW-S; 70 = TFW-L]; "
                   "for rmbnet the half-width w of the model (0..3; 2w+1 preliminary frames) [3].")
@click.option("--step", type=click.IntRange(min=1), default=None,
              help="Raw planes per output frame [default: 20 (1000 frames per second of a 20 kHz "
                   "capture); 10 for a native RMB capture, whose readouts are not binned].")
@click.option("--format", "fmt", type=click.Choice(SINK_FORMATS), default="mp4", show_default=True,
              help="mp4 (tone-mapped H.264), exr (linear HDR), png (tone-mapped 8-bit), null (timing).")
@click.option("--fps", type=click.FloatRange(min=0, min_open=True), default=30.0, show_default=True,
              help="MP4 playback frame rate.")
@click.option("--pixel-format", type=click.Choice(["auto", "yuv420p", "yuv444p"]), default="auto",
              show_default=True,
              help="MP4 chroma: auto keeps the exact size (yuv444p for odd sizes, which QuickTime and some "
                   "hardware players cannot open); yuv420p plays everywhere but pads odd sizes by one row/column.")
@click.option("--tonemap", type=click.Choice(TONEMAPS), default="mulaw", show_default=True,
              help="Tone mapping for mp4/png.")
@click.option("--exr-dtype", type=click.Choice(["half", "float"]), default="half", show_default=True,
              help="EXR pixel type; half clips values above 65504.")
@click.option("--readout", type=click.Choice([m.value for m in ReadoutMode]), default="rmb",
              show_default=True, help="Readout design applied to the binned stream (rmbnet, tfw, gc20, mg20).")
@capture_options
@click.option("--start", "start_s", type=click.FloatRange(min=0), default=0.0, show_default=True,
              help="Start time in seconds from the beginning of the capture.")
@click.option("--duration", "duration_s", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Seconds of capture to process [default: to the end].")
@click.option("--chunk-planes", type=click.IntRange(min=1), default=1024, show_default=True,
              help="Raw planes read per chunk (memory bound; the output does not depend on it).")
@rmbnet_options
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def reconstruct(input_path: Path, outdir: Path, method: str, window, step, fmt: str, fps: float,
                pixel_format: str, tonemap: str, exr_dtype: str, readout: str, width, height, flip, header_cols, rate_hz,
                start_s: float, duration_s, chunk_planes: int, model, align: str, device: str,
                upsampling: str, precision: str, threads, quiet: bool) -> None:
    """Reconstruct a .dat capture INPUT into frames in OUTDIR."""
    extra = rmbnet_extra_options(method, model, align, device, upsampling, precision, threads)
    summary = run_reconstruction(
        input_path, outdir, method=method, window=window, step=step, fmt=fmt, fps=fps,
        pixel_format=pixel_format, tonemap=tonemap, exr_dtype=exr_dtype, readout=readout, start_s=start_s,
        duration_s=duration_s, chunk_planes=chunk_planes, progress=progress_enabled(quiet),
        capture=dict(width=width, height=height, flip=flip, header_cols=header_cols, rate_hz=rate_hz),
        extra_options=extra,
    )
    if not quiet:
        click.echo(f"{summary.frames} frames from {summary.planes} planes in {summary.seconds:.2f} s "
                   f"({summary.frames_per_second:.1f} frames/s) -> {outdir}", err=True)
