"""Reconstruct one capture file: into an output folder (``run_reconstruction``, the library form of
``rmbvideo reconstruct``, also used by ``batch``) or as a stream of frames (``reconstruct_frames``,
``rmbvideo.reconstruct`` for notebooks)."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from rmbvideo.chunks import Frame
from rmbvideo.errors import InputError, OptionError, OutputError
from rmbvideo.io.atomic import staged_folder
from rmbvideo.io.capture import capture_convention, open_capture
from rmbvideo.io.dat import DatReader
from rmbvideo.io.rmbfile import RmbFileReader
from rmbvideo.io.sidecar import simulated_camera
from rmbvideo.io.sinks import is_sink_output, make_sink
from rmbvideo.io.tonemap import ToneMapConfig
from rmbvideo.recon.decimate import EveryKthFrame
from rmbvideo.recon.fingerprint import fingerprint_digest, run_fingerprint
from rmbvideo.recon.full_resolution import FullResolution, detail_stage, raw_gate_stage
from rmbvideo.recon.methods import DEFAULT_METHOD, get_method
from rmbvideo.recon.pipeline import RunSummary, iter_frames, reconstruct_stream
from rmbvideo.recon.resume import (
    ResumedSink,
    check_resumable_format,
    check_resumable_step,
    finish_record,
    holds_frames,
    is_resumable,
    logged_rows,
    restart_plane,
    saved_state,
    scan_log,
    start_record,
    state_carrier,
    window_reach,
)
from rmbvideo.sensor.conventions import response_for
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

log = logging.getLogger(__name__)
#: Method options whose "auto" is decided per capture, from its sidecar and its first spikes (``prepare_run``).
PER_CAPTURE_OPTIONS = ("convention", "response")


RESOLUTIONS = ("binned", "full")
#: Full resolution is the default for real 1-bit captures: measured above TFP/TFI at full resolution and equal to
#: the binned output after 2x2 averaging (README "Full resolution"); "binned" (RMB-Net's frames mixed with the raw
#: intervals as at full size, without the detail stage) is about 1.2x faster on 2 cores.
DEFAULT_RESOLUTION = "full"
#: Most bytes a chunk's decoded planes may take, whatever --chunk-planes asks (one byte per pixel and plane):
#: memory stays bounded on any camera, and the frames do not depend on the chunk size. The default chunk of a 400x250
#: camera (1,024 planes, 100 MB) fits; on a 1000x1000 one the default job peaked at 2.70-2.71 GB in 28.8-30.6 s with
#: 256 MiB and 2.34-2.41 GB in 27.2-28.1 s with 128 (two runs each, 2026-12-04): a decoded chunk lives in two threads
CHUNK_BYTES = 128 * 2**20


@dataclass
class PreparedRun:
    """A capture opened and a method built, with the raw-plane range and readout to run them on."""

    reader: DatReader | RmbFileReader
    method: Any
    start: int
    stop: int
    step: int
    readout: RmbReadout | None


def prepare_run(input_path: Path, *, method: str = DEFAULT_METHOD, window: int | None = None,
                step: int | None = None, readout: str | None = None, start_s: float = 0.0,
                duration_s: float | None = None, capture: dict | None = None,
                extra_options: dict[str, Any] | None = None, resolution: str = DEFAULT_RESOLUTION,
                detail: str = "auto", raw_gate: str = "auto") -> PreparedRun:
    """Open ``input_path`` (options over sidecar over defaults) and build ``method`` for it, as
    ``rmbvideo reconstruct`` does; ``extra_options`` are further method options, of which the method
    takes those it declares (``Method.extra_options``). ``readout``: the design applied to the binned
    stream (default: the one RMB-Net's model was trained on, else "rmb"). ``resolution="full"`` gives a method on the
    binned stream the camera's full resolution with the raw stream's detail
    (``rmbvideo.recon.full_resolution``; ``detail``: how, see ``DETAIL_KINDS``); methods on raw spikes
    and native captures have it already. ``raw_gate``: whether RMB-Net's frames of a 1-bit capture are mixed with raw
    TFI, at either resolution (see ``RAW_GATE_KINDS``). Bad input raises before anything runs."""
    if resolution not in RESOLUTIONS:
        raise OptionError(f"--resolution: must be one of {', '.join(RESOLUTIONS)}, not {resolution!r}")
    reader = open_capture(Path(input_path), **(capture or {}))
    start = reader.plane_index(start_s)
    stop = reader.n_planes if duration_s is None else min(reader.n_planes, start + reader.plane_index(duration_s))
    if start >= reader.n_planes:
        raise InputError(f"{input_path}: --start {start_s} s is past the end of the capture "
                         f"({reader.duration_s:.6f} s)")
    native = isinstance(reader, RmbFileReader)
    step = step or (10 if native else 20)
    spec = get_method(method)
    options = spec.options(window, step, raw_per_readout=1 if native else 2)
    options.update(spec.select_extra(extra_options or {}))
    if "convention" in spec.extra_options and options.get("convention", "auto") == "auto":
        options["convention"] = auto_convention(reader, Path(input_path), start, stop)
    if "response" in spec.extra_options and options.get("response", "auto") == "auto":
        # a capture rmbvideo simulated is read by its camera's response; any other by the closed form
        camera = simulated_camera(Path(input_path))
        options["response"] = response_for(None if camera is None else camera.effects)
    if "input_mode" in spec.extra_options:  # a model trained for the other kind of stream is refused
        options.setdefault("input_mode", "native" if native else "binned")
    if "readout" in spec.extra_options and readout is not None and not native:
        options.setdefault("readout", readout)  # the shipped model for that readout design
    height, width = reader.shape
    if not native and spec.input_kind == "rmb":
        height, width = height // 2, width // 2  # the binned stream
    if min(height, width) < 1:
        raise InputError(f"{input_path}: {method} needs at least 1x1 pixels at its input; this capture "
                         f"gives {width}x{height} (check --width/--height/--header-cols)")
    recon = spec.build(**options)
    every = spec.frame_every(step, raw_per_readout=1 if native else 2)  # RMB-Net at a multiple of its step
    if every > 1:  # the frames no one sees are made for the recurrent state alone
        recon.emit_every = every
    # A native capture was read out by its sensor already; binned data gets the chosen design.
    readout = readout or trained_readout(recon)
    rmb_readout = RmbReadout(mode=ReadoutMode(readout)) if recon.input_kind == "rmb" and not native else None
    if rmb_readout is not None:
        # RMB-Net's frames of a 1-bit capture are mixed with the raw stream's intervals at either size (the raw gate)
        reads_light = getattr(recon, "light_reading", None) is not None
        gate = raw_gate_stage(raw_gate, options.get("model")) if reads_light else None
        wrap = dict(step=step // every, raw_gate=gate, threads=options.get("threads"),
                    precision=options.get("precision", "auto"), keep_every=every)
        if resolution == "full":
            recon, rmb_readout = FullResolution(recon, rmb_readout, detail=detail_stage(detail), **wrap), None
        elif gate is not None:
            recon, rmb_readout = FullResolution(recon, rmb_readout, output="binned", **wrap), None
    if every > 1:
        recon = EveryKthFrame(recon, every)
    return PreparedRun(reader, recon, start, stop, step, rmb_readout)


def bounded_chunk_planes(chunk_planes: int, reader: DatReader | RmbFileReader) -> int:
    """``chunk_planes``, cut to the planes of ``reader`` that fit in ``CHUNK_BYTES`` once decoded."""
    height, width = reader.shape
    most = max(2, CHUNK_BYTES // max(1, height * width))
    if chunk_planes > most:
        log.debug("--chunk-planes %d: %d planes of %dx%d fit in %d MiB; reading %d at a time", chunk_planes, most,
                 width, height, CHUNK_BYTES // 2**20, most)
    return min(chunk_planes, most)


def auto_convention(reader: DatReader | RmbFileReader, path: Path, start: int = 0, stop: int | None = None) -> str:
    """``capture_convention``, physical when it cannot tell; a real capture read in the rate convention is logged."""
    found = capture_convention(reader, path, start, stop)
    if found == "spikezoo" and simulated_camera(path) is None:
        log.info("%s: its spike counts do not pile up at half the planes, as a pixel reset to zero makes them: read "
                 "in the rate convention (--convention physical to override)", path)
    return found or "physical"


def trained_readout(recon: Any) -> str:
    """The readout design a reconstructor's model was trained on ("rmb" for methods without a model)."""
    network = getattr(recon, "network", None)
    return str(getattr(getattr(network, "config", None), "readout", "rmb"))


def reconstruct_frames(path: str | Path, method: str = DEFAULT_METHOD, *, window: int | None = None,
                       step: int | None = None, readout: str | None = None, start_s: float = 0.0,
                       duration_s: float | None = None, chunk_planes: int = 1024, progress: bool = False,
                       width: int | None = None, height: int | None = None, flip: bool | None = None,
                       header_cols: int | None = None, rate_hz: float | None = None,
                       resolution: str = DEFAULT_RESOLUTION, detail: str = "auto", raw_gate: str = "auto",
                       **options: Any) -> Iterator[Frame]:
    """The frames of capture ``path`` (``.index``, ``.time_s``, ``.image``: linear float32, finite,
    >= 0) reconstructed with ``method``, with the defaults and sidecar handling of ``rmbvideo
    reconstruct``, streaming in bounded memory. ``options`` go to the method (e.g. RMB-Net's ``model``,
    ``device``; ``threads`` is every method's, as on the command line: the classical ones run on one). Available as
    ``rmbvideo.reconstruct``."""
    unknown = sorted(set(options) - set(get_method(method).extra_options) - {"threads"})
    if unknown:
        raise OptionError(f"method {method} takes no option {', '.join(unknown)}")
    run = prepare_run(Path(path), method=method, window=window, step=step, readout=readout, start_s=start_s,
                      duration_s=duration_s, extra_options=options, resolution=resolution, detail=detail,
                      raw_gate=raw_gate, capture=dict(width=width, height=height, flip=flip, header_cols=header_cols, rate_hz=rate_hz))
    return iter_frames(run.reader, run.method, start=run.start, stop=run.stop,
                       chunk_planes=bounded_chunk_planes(chunk_planes, run.reader),
                       progress=progress, readout=run.readout, expected_frames=(run.stop - run.start) // run.step)


def run_reconstruction(input_path: Path, outdir: Path, *, method: str = DEFAULT_METHOD,
                       window: int | None = None, step: int | None = None, fmt: str = "mp4",
                       fps: float = 30.0, tonemap: str = "exposure", exr_dtype: str = "half",
                       pixel_format: str = "auto",
                       readout: str | None = None, start_s: float = 0.0, duration_s: float | None = None,
                       chunk_planes: int = 1024, progress: bool = False,
                       capture: dict | None = None, extra_options: dict[str, Any] | None = None,
                       overwrite: bool = False, nits_per_unit: float | None = None,
                       resolution: str = DEFAULT_RESOLUTION, detail: str = "auto",
                       raw_gate: str = "auto", resume: bool = False) -> RunSummary:
    """Reconstruct ``input_path`` into ``outdir`` with ``method`` (see ``prepare_run``).

    The input is opened and checked before anything is created. The outputs are written into a
    staging folder that replaces ``outdir`` as a whole when the run is complete (``staged_folder``):
    a failed or interrupted run leaves ``outdir`` as it was, an existing non-empty ``outdir`` is
    refused unless ``overwrite``, and a run that produces no frame is an ``InputError``. With ``resume``
    (frame files only, ``RESUMABLE_FORMATS``) an interrupted run's frames are kept for a later run with the same
    input and options, which continues it (``rmbvideo.recon.resume``).
    """
    if resume:
        check_resumable_format(fmt)
        spec = get_method(method)
        if step is not None and spec.fixed_readouts is not None:  # refused before the capture is probed
            native = isinstance(open_capture(Path(input_path), **(capture or {})), RmbFileReader)
            check_resumable_step(method, step, spec.frame_every(step, raw_per_readout=1 if native else 2))
    if resume and not overwrite and (Path(outdir) / "frames.csv").is_file():
        raise OutputError(f"{outdir}: holds a complete run already, nothing to resume (--overwrite makes it again)")
    run = prepare_run(input_path, method=method, window=window, step=step, readout=readout, start_s=start_s,
                      duration_s=duration_s, capture=capture, extra_options=extra_options, resolution=resolution,
                      detail=detail, raw_gate=raw_gate)
    reader = run.reader
    chunk_planes = bounded_chunk_planes(chunk_planes, reader)
    sink_options = dict(fps=fps, tonemap=ToneMapConfig(method=tonemap), exr_dtype=exr_dtype,
                        mp4_pixel_format=pixel_format, capture_rate_hz=reader.rate_hz,
                        frame_rate_hz=reader.rate_hz / run.step, nits_per_unit=nits_per_unit)

    def no_frame() -> InputError:
        return InputError(f"{input_path}: no frame to reconstruct: planes {run.start}..{run.stop} hold no whole frame "
                          f"of {run.step} planes (check --start/--duration)")

    def run_into(folder: Path) -> RunSummary:
        with make_sink(fmt, folder, **sink_options) as sink:
            summary = reconstruct_stream(reader, run.method, sink, start=run.start, stop=run.stop,
                                         chunk_planes=chunk_planes, progress=progress, readout=run.readout,
                                         expected_frames=(run.stop - run.start) // run.step)
            if summary.frames == 0:
                raise no_frame()
        return summary

    if fmt == "null":
        return run_into(Path(outdir))
    if not resume:
        with staged_folder(Path(outdir), is_sink_output, overwrite=overwrite) as staging:
            return run_into(staging)
    options = dict(method=method, window=window, step=run.step, fmt=fmt, exr_dtype=exr_dtype, tonemap=tonemap,
                   readout=readout, start_s=start_s, duration_s=duration_s,
                   extra_options=_output_options(extra_options), resolution=resolution, detail=detail,
                   raw_gate=raw_gate)
    fingerprint = run_fingerprint(Path(input_path), options, reader)
    digest = fingerprint_digest(fingerprint)
    with staged_folder(Path(outdir), is_sink_output, overwrite=overwrite, adopt=lambda f: is_resumable(f, digest),
                       keep=holds_frames) as staging:
        logged = scan_log(staging)
        start_record(staging, fingerprint, logged)
        next_index = logged.next_index
        if logged.frames:
            log.info("%s: resuming an interrupted run: %d frames kept, continuing at frame %d", input_path, logged.frames,
                     next_index)
        reach = window_reach(window, get_method(method).window, 1 if isinstance(reader, RmbFileReader) else 2)
        carrier = state_carrier(run.method)
        saved = saved_state(staging, next_index) if carrier is not None else None
        first = restart_plane(run.start, next_index if saved is None else saved[0] + 1, run.step, reach)
        if carrier is not None:
            carrier.keep_state_snapshots()
            if saved is not None:
                log.info("%s: the recurrent state after frame %d is set back", input_path, saved[0])
                carrier.resume_from(*saved)
        sink = make_sink(fmt, staging, prior_rows=logged_rows(staging, logged), **sink_options)
        if logged.frames:
            sink.restore_state(logged.state)
        frames = ResumedSink(sink, staging, next_index, fmt, carrier)
        try:
            summary = reconstruct_stream(reader, run.method, frames, start=first, stop=run.stop,
                                         chunk_planes=chunk_planes, progress=progress, readout=run.readout,
                                         expected_frames=(run.stop - first) // run.step)
            frames.close()
            if frames.written + logged.frames == 0:
                raise no_frame()
            sink.close()
        except BaseException as exc:
            sink.leave()
            with contextlib.suppress(OutputError):  # the log's own error is the one being raised
                frames.close()
            kept = scan_log(staging).frames
            said = f"its {kept} frames are kept for the same command with --resume, which continues it"
            if isinstance(exc, KeyboardInterrupt) and kept:  # said in place of "partial output removed"
                exc.left_behind = said  # type: ignore[attr-defined]
            if isinstance(exc, (OutputError, InputError)) and kept:  # a full disk: free space, then resume
                raise type(exc)(f"{str(exc).rstrip('.')}; {said}") from exc
            raise
        finish_record(staging)
        return replace(summary, frames=frames.written, kept=logged.frames)


def _output_options(extra_options: dict[str, Any] | None) -> dict[str, Any]:
    """The method options that decide the frames (the thread count does not)."""
    return {k: v for k, v in (extra_options or {}).items() if k != "threads"}
