"""The streaming reconstruction loop: reader chunks -> reconstructor -> frames -> sink.

Reconstructors are built by name from ``rmbvideo.recon.methods``. This module is the one place that
guards the sink against non-finite pixels.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Iterator, Protocol

import numpy as np
from tqdm import tqdm

from rmbvideo.chunks import Frame, RmbChunk, SpikeChunk, clean_image
from rmbvideo.io.dat import PackedChunk
from rmbvideo.recon.classical import Reconstructor
from rmbvideo.sensor.readout import RmbReadout

log = logging.getLogger(__name__)

class SpikeSource(Protocol):
    """What the loop reads from (``rmbvideo.io.dat.DatReader`` or anything shaped like it)."""

    @property
    def n_planes(self) -> int: ...

    def chunks(self, chunk_planes: int, start: int, stop: int | None) -> Iterator[SpikeChunk]: ...

    def binned_chunks(self, chunk_planes: int, start: int, stop: int | None) -> Iterator[RmbChunk]: ...


class FrameConsumer(Protocol):
    """What the loop writes to (a ``rmbvideo.io.sinks`` sink); committing it is the caller's job."""

    def write(self, frame: Frame) -> None: ...


@dataclass
class RunSummary:
    """What a run did: frames written, raw planes read, wall-clock seconds, pixels repaired, seconds per stage
    (``STAGES``, plus the method's own parts, e.g. RMB-Net's "network"), and the frames an interrupted run had written
    that a resumed one kept (``kept``: the output holds ``frames + kept``)."""

    frames: int
    planes: int
    seconds: float
    nonfinite_pixels: int = 0
    stages: dict[str, float] = field(default_factory=dict)
    kept: int = 0

    @property
    def frames_per_second(self) -> float:
        """Output frames per wall-clock second (0 for an instantaneous run)."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0


#: The stages every run is timed by: reading (decoding and binning included), the readout design,
#: the method (push/flush), and the sink (finite check, tone map, encoding, writing).
STAGES = ("read", "readout", "method", "sink")


def _pushes(chunk: SpikeChunk | PackedChunk, most: int) -> Iterator[SpikeChunk | PackedChunk]:
    """``chunk`` in consecutive pieces of at most ``most`` raw planes (views, no copies)."""
    if isinstance(chunk, PackedChunk):
        for a in range(0, len(chunk.data), most):
            yield PackedChunk(data=chunk.data[a:a + most], start=chunk.start + a, rate_hz=chunk.rate_hz,
                              geometry=chunk.geometry)
    else:
        for a in range(0, len(chunk.planes), most):
            yield SpikeChunk(planes=chunk.planes[a:a + most], start=chunk.start + a, rate_hz=chunk.rate_hz)


def finite_frame(frame: Frame) -> tuple[Frame, int]:
    """``frame`` with NaN/Inf replaced by 0 and negatives clipped to 0 (``clean_image``), and how
    many pixels were not finite."""
    image, count = clean_image(frame.image)
    if image is frame.image:
        return frame, 0
    return Frame(index=frame.index, time_s=frame.time_s, image=image), count


class FrameCollector:
    """A sink that keeps frames in memory by index (every frame, or only those in ``keep``), for
    evaluation and figures; a capture of any length with ``keep`` stays bounded."""

    def __init__(self, keep: Collection[int] | None = None) -> None:
        self.frames: dict[int, Frame] = {}
        self._keep = None if keep is None else set(keep)

    def write(self, frame: Frame) -> None:
        if self._keep is None or frame.index in self._keep:
            self.frames[frame.index] = frame

    @property
    def images(self) -> dict[int, np.ndarray]:
        """Index -> image of the kept frames."""
        return {index: frame.image for index, frame in self.frames.items()}


@dataclass
class StreamStats:
    """Counters an ``iter_frames`` run fills in as it goes: planes read, frames emitted, pixels
    repaired, seconds per stage (``STAGES`` except "sink", which the consumer adds)."""

    planes: int = 0
    frames: int = 0
    nonfinite_pixels: int = 0
    stages: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))


def iter_frames(
    reader: SpikeSource,
    method: Reconstructor,
    *,
    start: int = 0,
    stop: int | None = None,
    chunk_planes: int = 1024,
    progress: bool = False,
    readout: RmbReadout | None = None,
    stats: StreamStats | None = None,
    expected_frames: int | None = None,
) -> Iterator[Frame]:
    """The frames of ``method`` over raw planes ``start..stop`` of ``reader``, as they are made:
    finite, >= 0 (``finite_frame``), in bounded memory. The one streaming loop of the library.

    Methods on the RMB stream (``input_kind == "rmb"``) read 2x2x2-binned data, passed through
    ``readout`` when given (default: the binned pure-M stream as is); binning needs an even start and
    chunk size, so odd values are rounded up. ``readout`` is an error for methods on raw spikes.
    Methods on raw spikes that declare ``accepts_packed`` get the stored bits undecoded
    (``reader.packed_chunks``) when the reader offers them, and those that declare ``max_push_planes``
    get each chunk in pushes of at most that many planes. Memory is bounded by ``chunk_planes``
    and the method's own look-ahead. ``stats`` (optional) is filled in while the frames flow.
    ``progress``: a progress bar on stderr counting output frames (of ``expected_frames``, with
    frames/s and time left) or, without that number, raw planes read.
    """
    stats = stats if stats is not None else StreamStats()
    stages = stats.stages
    most = getattr(method, "max_push_planes", None)  # a method on raw planes may want them a few at a time
    stop = reader.n_planes if stop is None else stop
    if method.input_kind == "rmb":
        if start % 2 or chunk_planes % 2:
            log.info("binned input needs even planes: start %d -> %d, chunk %d -> %d",
                     start, start + start % 2, chunk_planes, chunk_planes + chunk_planes % 2)
        start += start % 2
        chunk_planes = max(2, chunk_planes + chunk_planes % 2)
        chunks: Iterator[SpikeChunk | RmbChunk | PackedChunk] = reader.binned_chunks(chunk_planes, start, max(start, stop))
    elif readout is not None:
        raise ValueError(f"a readout design applies only to methods on the RMB stream, not {type(method).__name__}")
    elif getattr(method, "accepts_packed", False) and hasattr(reader, "packed_chunks"):
        chunks = reader.packed_chunks(chunk_planes, start, stop)
    else:
        chunks = reader.chunks(chunk_planes, start, stop)

    def cleaned(batch: list[Frame]) -> Iterator[Frame]:
        for frame in batch:
            frame, bad = finite_frame(frame)
            if bad:
                log.warning("frame %d: replaced %d non-finite pixels with 0", frame.index, bad)
                stats.nonfinite_pixels += bad
            stats.frames += 1
            if by_frames:
                bar.update(1)
            yield frame

    by_frames = expected_frames is not None
    bar = tqdm(total=expected_frames if by_frames else max(stop - start, 0), unit="frame" if by_frames else "plane",
               disable=not progress, dynamic_ncols=True, mininterval=0.5)
    with bar:
        iterator = iter(chunks)
        while True:
            tick = time.perf_counter()
            chunk = next(iterator, None)
            tock = time.perf_counter()
            stages["read"] += tock - tick
            if chunk is None:
                break
            if isinstance(chunk, RmbChunk):
                advanced = len(chunk.single) * chunk.raw_per_readout
                if readout is not None:
                    chunk = readout.apply(chunk)
                pushes: Iterator[SpikeChunk | RmbChunk | PackedChunk] = iter((chunk,))
            else:
                advanced = chunk.stop - chunk.start
                pushes = _pushes(chunk, most) if most else iter((chunk,))
            stages["readout"] += time.perf_counter() - tock
            for piece in pushes:
                tick = time.perf_counter()
                out = method.push(piece)
                stages["method"] += time.perf_counter() - tick
                yield from cleaned(out)
                del out  # the frames go with their consumer: a method may reuse their memory (``ImagePool``)
            chunk = pushes = piece = None  # freed before the next read, which can then reuse its memory
            stats.planes += advanced
            if not by_frames:
                bar.update(advanced)
        tick = time.perf_counter()
        out = method.flush()
        stages["method"] += time.perf_counter() - tick
        yield from cleaned(out)
    stages.update(getattr(method, "stage_seconds", {}))


def reconstruct_stream(
    reader: SpikeSource,
    method: Reconstructor,
    sink: FrameConsumer,
    *,
    start: int = 0,
    stop: int | None = None,
    chunk_planes: int = 1024,
    progress: bool = False,
    readout: RmbReadout | None = None,
    expected_frames: int | None = None,
) -> RunSummary:
    """Run ``method`` over raw planes ``start..stop`` of ``reader`` (``iter_frames``) and write its
    frames to ``sink``. The sink is not closed here: the caller commits it (or aborts it on error),
    e.g. by using it as a context manager."""
    began = time.perf_counter()
    stats = StreamStats()
    for frame in iter_frames(reader, method, start=start, stop=stop, chunk_planes=chunk_planes, progress=progress,
                             readout=readout, stats=stats, expected_frames=expected_frames):
        tick = time.perf_counter()
        sink.write(frame)
        stats.stages["sink"] += time.perf_counter() - tick
    seconds = time.perf_counter() - began
    log.debug("%d frames from %d planes in %.2f s", stats.frames, stats.planes, seconds)
    return RunSummary(frames=stats.frames, planes=stats.planes, seconds=seconds,
                      nonfinite_pixels=stats.nonfinite_pixels, stages=stats.stages)
