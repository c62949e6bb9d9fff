"""Where RMB-Net's end-to-end time goes, per stage and output frame: decode + binning, preliminary
frames (band upsampling), encoders, attention (XBA + XTA), decoder with ConvLSTMs, the rest of the
network step, tone mapping and the sinks. Each stage is timed on its own, in order, on one capture."""

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
                    threads: int = 1, precision: str = "fp32", device: str = "cpu") -> dict[str, float]:
    """Milliseconds per output frame of each stage for ``network`` on a random ``width`` x ``height``
    capture of ``planes`` raw planes (output at half the size). Keys in pipeline order, plus "total"
    and "frames"."""
    from rmbvideo.io.sinks import make_sink
    from rmbvideo.recon.prelim import PreliminaryFrames
    from rmbvideo.recon.rmbnet import RmbNetReconstructor
    from rmbvideo.io.tonemap import ToneMapper

    result: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="rmbvideo-stages-") as folder:
        geometry = DatGeometry(width=width, height=height)
        path = write_random_capture(Path(folder) / "capture.dat", planes, width, height)
        reader = DatReader(path, geometry)
        began = time.perf_counter()
        chunks = list(reader.binned_chunks(CHUNK_PLANES, 0, planes))
        result["decode + binning"] = time.perf_counter() - began
        del reader
        prelim = PreliminaryFrames(n=network.config.n)
        began = time.perf_counter()
        frames = [f for c in chunks for f in prelim.push(c)] + prelim.flush()
        result["preliminary frames (upsampling)"] = time.perf_counter() - began
        engine = RmbNetReconstructor(network, device=device, precision=precision, threads=threads)
        clock = _StageClock()
        _instrument(engine.network, clock)
        engine.push(frames[: network.config.window])  # warm-up: one-off kernel selection
        engine = RmbNetReconstructor(network, device=device, precision=precision, threads=threads)
        _instrument(engine.network, clock)
        clock.seconds.clear()
        began = time.perf_counter()
        out = engine.push(frames) + engine.flush()
        network_s = time.perf_counter() - began
        parts = ("encoders", "attention", "decoder/ConvLSTM")
        for part in parts:
            result[part] = clock.seconds[part]
        result["network other (stacking, caches, output)"] = max(0.0, network_s - sum(clock.seconds[p] for p in parts))
        tone = ToneMapper()
        began = time.perf_counter()
        for frame in out:
            tone(frame.image)
        result["tone map"] = time.perf_counter() - began
        for fmt in ("null", "mp4"):
            began = time.perf_counter()
            with make_sink(fmt, Path(folder) / fmt, frame_rate_hz=1000.0) as sink:
                for frame in out:
                    sink.write(frame)
            result[f"sink {fmt}" + (" (tone map + H.264)" if fmt == "mp4" else "")] = time.perf_counter() - began
    count = max(len(out), 1)
    breakdown = {stage: 1e3 * seconds / count for stage, seconds in result.items()}
    breakdown["total (null sink)"] = sum(v for k, v in breakdown.items() if k not in ("tone map", "sink mp4 (tone map + H.264)"))
    breakdown["frames"] = float(len(out))
    return breakdown
