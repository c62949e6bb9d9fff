"""Reconstruct one capture file into an output folder: the library form of ``rmbvideo reconstruct``
(used by the command and by ``batch``)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from rmbvideo.errors import InputError
from rmbvideo.io.capture import open_capture
from rmbvideo.io.rmbfile import RmbFileReader
from rmbvideo.io.sinks import make_sink
from rmbvideo.io.tonemap import ToneMapConfig
from rmbvideo.recon.methods import DEFAULT_METHOD, get_method
from rmbvideo.recon.pipeline import RunSummary, reconstruct_stream
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout


def run_reconstruction(input_path: Path, outdir: Path, *, method: str = DEFAULT_METHOD,
                       window: int | None = None, step: int | None = None, fmt: str = "mp4",
                       fps: float = 30.0, tonemap: str = "mulaw", exr_dtype: str = "half",
                       pixel_format: str = "auto",
                       readout: str = "rmb", start_s: float = 0.0, duration_s: float | None = None,
                       chunk_planes: int = 1024, progress: bool = False,
                       capture: dict | None = None, extra_options: dict[str, Any] | None = None) -> RunSummary:
    """Reconstruct ``input_path`` into ``outdir`` with ``method``; ``extra_options`` are further
    command-line values, of which the method takes those it declares (``Method.extra_options``).

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
    spec = get_method(method)
    options = spec.options(window, step, raw_per_readout=1 if native else 2)
    options.update(spec.select_extra(extra_options or {}))
    if native and "input_mode" in spec.extra_options:
        options.setdefault("input_mode", "native")
    recon = spec.build(**options)
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
