"""Is ``reconstruct --method tfp --format null`` real time? A generated capture is streamed by reading
alone (every stored byte brought in, as tfp reads it: packed), by reading and unpacking every plane
(what a method on unpacked planes pays first), and through the whole tfp run; all exclude start-up."""

from __future__ import annotations

import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.io.dat import DatGeometry, DatReader

RAW_RATE_HZ = 20000.0
CHUNK_PLANES = 1024  # the pipeline's default chunk


@dataclass
class RealtimeResult:
    """Seconds of capture; wall seconds of reading alone, of reading and unpacking, and of the full
    tfp run; frames produced; and the derived ratios."""

    planes: int
    capture_s: float
    read_s: float
    unpack_s: float
    reconstruct_s: float
    frames: int

    @property
    def realtime_factor(self) -> float:
        """Capture seconds per wall second of the full run (>= 1: real time)."""
        return self.capture_s / self.reconstruct_s if self.reconstruct_s > 0 else 0.0

    @property
    def planes_per_s(self) -> float:
        """Raw planes per wall second of the full run."""
        return self.planes / self.reconstruct_s if self.reconstruct_s > 0 else 0.0

    @property
    def vs_reading(self) -> float:
        """How many times longer the full run takes than reading alone."""
        return self.reconstruct_s / self.read_s if self.read_s > 0 else 0.0

    def to_dict(self) -> dict:
        """JSON-ready dictionary with the derived ratios."""
        return {**asdict(self), "realtime_factor": self.realtime_factor, "planes_per_s": self.planes_per_s,
                "vs_reading": self.vs_reading, "meets_target": self.realtime_factor >= 1.0}


def bench_realtime(seconds: float = 5.0, width: int = 400, height: int = 250,
                   folder: Path | None = None) -> RealtimeResult:
    """Generate ``seconds`` of capture at 20 kHz (5 s of 400x250 is 100,000 planes, 1.25 GB) in
    ``folder`` (default: a temporary one, removed afterwards) and time reading, unpacking and tfp."""
    from rmbvideo.io.sinks import make_sink
    from rmbvideo.recon.classical import Tfp
    from rmbvideo.recon.pipeline import reconstruct_stream

    planes = int(round(seconds * RAW_RATE_HZ))
    with tempfile.TemporaryDirectory(prefix="rmbvideo-realtime-", dir=folder) as tmp:
        path = write_random_capture(Path(tmp) / "capture.dat", planes, width, height)
        reader = DatReader(path, DatGeometry(width=width, height=height), rate_hz=RAW_RATE_HZ)
        began = time.perf_counter()
        for packed in reader.packed_chunks(CHUNK_PLANES):
            np.bitwise_or.reduce(packed.data, axis=0)
        read_s = time.perf_counter() - began
        began = time.perf_counter()
        for _chunk in reader.chunks(CHUNK_PLANES):
            pass
        unpack_s = time.perf_counter() - began
        with make_sink("null", Path(tmp)) as sink:
            summary = reconstruct_stream(reader, Tfp(), sink, chunk_planes=CHUNK_PLANES)
        del reader
    return RealtimeResult(planes=planes, capture_s=planes / RAW_RATE_HZ, read_s=read_s, unpack_s=unpack_s,
                          reconstruct_s=summary.seconds, frames=summary.frames)
