"""Where RMB-Net's end-to-end time goes, per stage and output frame: decode + binning, preliminary
frames (band upsampling), encoders, attention (XBA + XTA), decoder with ConvLSTMs, the rest of the
network step, the aligned window mean (models that read it), tone mapping and the sinks. Each stage is timed on its own, in order, on one capture."""

from __future__ import annotations

import functools
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.io.dat import DatGeometry, DatReader

CHUNK_PLANES = 1024
#: the aligned means' stage when they ran in a thread of their own (overlapping the rest: not in the total)
ALIGNED_BESIDE = "aligned window mean (in a thread beside the network; not in the total)"


class _StageClock:
    """Accumulates wall seconds per stage name around wrapped callables."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def wrap(self, stage: str, func: Callable) -> Callable:
        @functools.wraps(func)
        def timed(*args, **kwargs):
            began = time.perf_counter()
            try:
                return func(*args, **kwargs)
            finally:
                self.seconds[stage] += time.perf_counter() - began
        return timed


def _instrument(network, clock: _StageClock) -> None:
    """Time the network's parts by wrapping their entry points on this instance only."""
    for encoder in (network.encoder_s, network.encoder_m):
        encoder.forward = clock.wrap("encoders", encoder.forward)
    for xba in getattr(network, "xba", []):
        for name in ("query_part", "key_part", "pair_logits", "fuse"):
            setattr(xba, name, clock.wrap("attention", getattr(xba, name)))
    network.time_fusion.forward = clock.wrap("attention", network.time_fusion.forward)
    network.decoder.forward = clock.wrap("decoder/ConvLSTM", network.decoder.forward)


def stage_breakdown(network, planes: int = 2000, width: int = 400, height: int = 250,
                    threads: int = 1, precision: str = "auto", device: str = "cpu") -> dict[str, float]:
    """Milliseconds per output frame of each stage for ``network`` on a random ``width`` x ``height``
    capture of ``planes`` raw planes (output at half the size): the stages of one streaming run
    (``RunSummary.stages``, the network split by instrumenting its parts), then tone mapping and the
    MP4 sink timed on its frames. Keys in pipeline order, plus "total" and "frames"."""
    from rmbvideo.io.sinks import make_sink
    from rmbvideo.io.tonemap import ToneMapper
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.recon.rmbnet import RmbNetReconstructor
    from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

    result: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="rmbvideo-stages-") as folder:
        path = write_random_capture(Path(folder) / "capture.dat", planes, width, height)
        reader = DatReader(path, DatGeometry(width=width, height=height))
        warm = RmbNetReconstructor(network, device=device, precision=precision, threads=threads)
        readout = RmbReadout(mode=ReadoutMode(network.config.readout))
        reconstruct_stream(reader, warm, FrameCollector(), stop=40 * network.config.window, readout=readout)
        engine = RmbNetReconstructor(network, device=device, precision=precision, threads=threads)
        clock = _StageClock()
        _instrument(engine.network, clock)
        keep = FrameCollector()
        summary = reconstruct_stream(reader, engine, keep, chunk_planes=CHUNK_PLANES, readout=readout)
        del reader
        stages = summary.stages
        result["decode + binning"] = stages["read"]
        result["RMB readout"] = stages["readout"]
        result["preliminary frames (upsampling)"] = stages["preliminary frames"]
        parts = ("encoders", "attention", "decoder/ConvLSTM")
        for part in parts:
            result[part] = clock.seconds[part]
        result["network other (stacking, caches, output)"] = max(
            0.0, stages["network"] - sum(clock.seconds[p] for p in parts))
        if "aligned mean" in stages:
            result[ALIGNED_BESIDE if engine.aligned_beside else "aligned window mean (DIS flow, warps)"] = stages["aligned mean"]
        result["sink null (finite check)"] = stages["sink"]
        out = list(keep.frames.values())
        tone = ToneMapper()
        began = time.perf_counter()
        for frame in out:
            tone(frame.image)
        result["tone map"] = time.perf_counter() - began
        began = time.perf_counter()
        with make_sink("mp4", Path(folder) / "mp4", frame_rate_hz=1000.0) as sink:
            for frame in out:
                sink.write(frame)
        result["sink mp4 (tone map + H.264)"] = time.perf_counter() - began
    count = max(len(out), 1)
    breakdown = {stage: 1e3 * seconds / count for stage, seconds in result.items()}
    breakdown["total (null sink)"] = sum(v for k, v in breakdown.items()
                                         if k not in ("tone map", "sink mp4 (tone map + H.264)", ALIGNED_BESIDE))
    breakdown["frames"] = float(len(out))
    return breakdown
