"""Frame sinks: where reconstructed frames go (MP4 video, EXR or PNG sequence, or nowhere).

Every sink is a context manager: ``write(frame)`` per frame, ``close()`` commits, ``abort()``
removes this run's partial outputs (leaving other files in the folder alone); leaving the
``with`` block normally closes, leaving it by an exception aborts. Memory is bounded however many
frames arrive: video frames are streamed to ffmpeg and the frame index is streamed to a
temporary file.

Next to its frames each sink (except ``null``) writes ``<stem>.csv`` (``frames.csv`` by default)
with columns ``index,time_s,file``, ``file`` relative to the output folder. Per-frame files are
named ``frame_<index:06d>.exr|png``; the video is ``<stem>.mp4``.

MP4 frame size is always exact (no silent resize). The default pixel format ``auto`` uses yuv420p,
which every player handles, when width and height are even, and yuv444p (exact size, supported by
ffmpeg, VLC and browsers' software decoders, not by some hardware players) when either is odd, as for
binned 400x250 captures (200x125); the choice is logged. ``yuv420p`` forces the common format and pads
an odd size by one edge-replicated row/column (logged).
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import struct
import zlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np

from rmbvideo.chunks import Frame, clean_image
from rmbvideo.errors import OutputError
from rmbvideo.io.atomic import (
    atomic_write_bytes,
    commit,
    is_environment_error,
    output_error,
    remove_quietly,
    staged_folder,
    temp_path_for,
)
from rmbvideo.io.exr import ExrDtype, write_exr
from rmbvideo.io.ffmpeg import FfmpegEncoder
from rmbvideo.io.tonemap import ToneMapConfig, ToneMapper

log = logging.getLogger(__name__)

SinkFormat = Literal["mp4", "hdr10", "hlg", "exr", "png", "null"]
Mp4PixelFormat = Literal["auto", "yuv420p", "yuv444p"]
INDEX_HEADER = "index,time_s,file"
#: BT.709 primaries, transfer and matrix, limited ("tv") range: how the SDR MP4's values are meant.
#: (in the container and in the H.264 stream's VUI, where players look for them).
BT709_TAGS = ("-colorspace", "bt709", "-color_primaries", "bt709", "-color_trc", "bt709", "-color_range", "tv",
              "-x264-params", "colorprim=bt709:transfer=bt709:colormatrix=bt709")
# x264 constant-rate factor: 18 is visually lossless for 8-bit tone-mapped video.
_X264_CRF = 18
#: Playback rates the MP4 muxer and both encoders write correctly (models/experiments/ffmpeg-limits/scan.py:
#: 1e-5 fps is refused at the muxer, 1e6 by x265, and durations past 1e4 fps round to nothing).
PLAYBACK_FPS_RANGE = (0.01, 10000.0)


def frame_file_name(index: int, ext: str) -> str:
    """The file name of frame ``index`` in a per-frame sequence (``frame_000042.exr``)."""
    return f"frame_{index:06d}.{ext}"


DEFAULT_STEM = "frames"


def is_sink_output(name: str, stem: str = DEFAULT_STEM) -> bool:
    """Whether a file of this name is one a sink writes (``<stem>.mp4``, ``<stem>.csv``, ``frame_NNNNNN.exr``
    or ``.png``, as ``frame_file_name`` names them): what an earlier run's folder may hold and ``--overwrite``
    may replace."""
    return re.fullmatch(rf"{re.escape(stem)}\.(mp4|csv)|frame_\d{{6,}}\.(exr|png)", name) is not None


class FrameIndex:
    """The ``index,time_s,file`` table of a run, streamed to a temporary file, renamed at commit."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._temp = temp_path_for(self.path)
        try:
            self._handle = open(self._temp, "w", encoding="utf-8", newline="\n")
            self._handle.write(INDEX_HEADER + "\n")
        except OSError as exc:
            raise output_error(self.path, exc) from exc

    def add(self, index: int, time_s: float, file: str) -> None:
        """Record one written frame (times are written exactly, as Python's shortest repr)."""
        try:
            self._handle.write(f"{index},{float(time_s)!r},{file}\n")
        except OSError as exc:
            raise output_error(self.path, exc) from exc

    def recorded_files(self) -> list[str]:
        """Distinct files recorded so far (read back from disk, so memory stays bounded while writing)."""
        self._handle.flush()
        with open(self._temp, encoding="utf-8") as handle:
            next(handle)
            return sorted({line.rstrip("\n").split(",", 2)[2] for line in handle if line.strip()})

    def commit(self) -> None:
        """Close and rename the table onto its final name."""
        try:
            self._handle.close()
        except OSError as exc:
            remove_quietly(self._temp)
            raise output_error(self.path, exc) from exc
        commit(self._temp, self.path)

    def discard(self) -> None:
        """Close and delete the temporary table."""
        try:
            self._handle.close()
        except OSError:
            pass
        remove_quietly(self._temp)


class FrameSink(ABC):
    """Base sink: validates and counts frames; subclasses implement ``_write``/``_commit``/``_discard``.

    ``nonfinite_pixels`` counts NaN/Inf pixels received (they are written as 0).
    """

    def __init__(self, outdir: Path | None) -> None:
        self.outdir = Path(outdir) if outdir is not None else None
        self.frames_written = 0
        self.nonfinite_pixels = 0
        self._shape: tuple[int, int] | None = None
        self._open = True

    def __enter__(self) -> FrameSink:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def write(self, frame: Frame) -> None:
        """Accept one frame; all frames of a run must have the same (H, W) shape."""
        if not self._open:
            raise RuntimeError("write() on a sink that is already closed or aborted")
        image = np.asarray(frame.image, dtype=np.float32)
        if image.ndim != 2 or min(image.shape) < 1:
            raise ValueError(f"frame {frame.index}: expected a (H, W) image, got shape {image.shape}")
        if self._shape is None:
            self._shape = (int(image.shape[0]), int(image.shape[1]))
        elif image.shape != self._shape:
            raise ValueError(f"frame {frame.index}: shape {image.shape} differs from earlier {self._shape}")
        image, bad = clean_image(image)
        if bad:
            if self.nonfinite_pixels == 0:
                log.warning("frame %d: %d NaN/Inf pixels written as 0", frame.index, bad)
            self.nonfinite_pixels += bad
        self._write(frame, image)
        self.frames_written += 1

    def close(self) -> None:
        """Finish and commit the outputs under their final names (idempotent)."""
        if not self._open:
            return
        self._open = False
        try:
            self._commit()
        except BaseException:
            self._discard()
            raise
        if self.nonfinite_pixels:
            log.warning("%d NaN/Inf pixels in total were written as 0", self.nonfinite_pixels)

    def abort(self) -> None:
        """Remove this run's partial outputs (idempotent; does nothing after a successful close)."""
        if not self._open:
            return
        self._open = False
        self._discard()

    def carried_state(self) -> Any:
        """What this sink's next frame depends on of the frames before (a tone mapper's smoothed exposure), as JSON
        data, or None: a resumed run sets it back with ``restore_state``."""
        return None

    def restore_state(self, state: Any) -> None:
        """Continue from ``state`` (``carried_state`` of the run this one continues)."""

    def leave(self) -> None:
        """Stop without committing: the frames written so far stay where a resumed run finds them, where a sink
        can leave them (one file a frame); any other sink removes its partial output, as ``abort``."""
        if not self._open:
            return
        self._open = False
        self._leave()

    def _leave(self) -> None:
        self._discard()

    @abstractmethod
    def _write(self, frame: Frame, image: np.ndarray) -> None:
        """Output one validated, finite frame."""

    @abstractmethod
    def _commit(self) -> None:
        """Make this run's outputs final."""

    @abstractmethod
    def _discard(self) -> None:
        """Remove this run's partial outputs."""


class NullSink(FrameSink):
    """Counts frames and writes nothing (for timing the pipeline without output cost)."""

    def __init__(self) -> None:
        super().__init__(None)

    def _write(self, frame: Frame, image: np.ndarray) -> None:
        return None

    def _commit(self) -> None:
        return None

    def _discard(self) -> None:
        return None


class _SequenceSink(FrameSink):
    """One file per frame, each written atomically, plus the frame index."""

    ext = ""

    def __init__(self, outdir: Path, stem: str, prior_rows: Iterable[tuple[int, float, str]] = ()) -> None:
        super().__init__(outdir)
        self._index = FrameIndex(self.outdir / f"{stem}.csv")
        for index, time_s, name in prior_rows:  # the frames of an interrupted run this one continues
            self._index.add(index, time_s, name)

    def _write(self, frame: Frame, image: np.ndarray) -> None:
        name = frame_file_name(frame.index, self.ext)
        self._write_file(self.outdir / name, frame, image)
        self._index.add(frame.index, frame.time_s, name)

    @abstractmethod
    def _write_file(self, path: Path, frame: Frame, image: np.ndarray) -> None:
        """Write one frame's file atomically at ``path``."""

    def _commit(self) -> None:
        self._index.commit()

    def _discard(self) -> None:
        for name in self._index.recorded_files():
            remove_quietly(self.outdir / name)
        self._index.discard()

    def _leave(self) -> None:
        self._index.discard()  # the frame files stay; a resumed run lists them again


class ExrSink(_SequenceSink):
    """Linear HDR frames as ``frame_NNNNNN.exr`` (one ``Y`` channel, capture time in the header)."""

    ext = "exr"

    def __init__(self, outdir: Path, stem: str, dtype: ExrDtype, attrs: dict[str, float | int | str],
                 prior_rows: Iterable[tuple[int, float, str]] = ()) -> None:
        super().__init__(outdir, stem, prior_rows)
        self.dtype = dtype
        self.attrs = attrs

    def _write_file(self, path: Path, frame: Frame, image: np.ndarray) -> None:
        write_exr(path, image, time_s=frame.time_s, dtype=self.dtype,
                  attrs={**self.attrs, "rmbvideo:frame_index": int(frame.index)})


class PngSink(_SequenceSink):
    """Tone-mapped 8-bit grayscale frames as ``frame_NNNNNN.png``."""

    ext = "png"

    def __init__(self, outdir: Path, stem: str, tonemap: ToneMapConfig,
                 prior_rows: Iterable[tuple[int, float, str]] = ()) -> None:
        super().__init__(outdir, stem, prior_rows)
        self._tonemapper = ToneMapper(tonemap)

    def carried_state(self) -> Any:
        return self._tonemapper.state

    def restore_state(self, state: Any) -> None:
        self._tonemapper.restore(state)

    def _write_file(self, path: Path, frame: Frame, image: np.ndarray) -> None:
        import cv2

        ok, encoded = cv2.imencode(".png", self._tonemapper(image))
        if not ok:
            raise OutputError(f"{path}: PNG encoding failed")
        atomic_write_bytes(path, with_bt709_tag(encoded.tobytes()))


def with_bt709_tag(png: bytes) -> bytes:
    """``png`` with a cICP chunk after its header: BT.709 primaries and transfer, RGB (identity)
    matrix, full range, so viewers know how the 8-bit values were meant (PNG 3rd edition)."""
    ihdr_end = 8 + 4 + 4 + 13 + 4  # signature, then the IHDR chunk (length, type, 13 bytes, CRC)
    body = b"cICP" + bytes([1, 1, 0, 1])
    chunk = struct.pack(">I", 4) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    return png[:ihdr_end] + chunk + png[ihdr_end:]


class Mp4Sink(FrameSink):
    """Tone-mapped H.264 video streamed through ffmpeg into a temporary file, renamed at close."""

    def __init__(
        self,
        outdir: Path,
        stem: str,
        *,
        fps: float,
        tonemap: ToneMapConfig,
        pixel_format: Mp4PixelFormat,
        capture_rate_hz: float | None,
        frame_rate_hz: float | None,
    ) -> None:
        super().__init__(outdir)
        self.path = self.outdir / f"{stem}.mp4"
        self.fps = fps
        self.pixel_format = pixel_format
        self.capture_rate_hz = capture_rate_hz
        self.frame_rate_hz = frame_rate_hz
        self._tonemapper = ToneMapper(tonemap)
        self._temp = temp_path_for(self.path)
        self._encoder = None
        self._padding = (0, 0)
        self._first_time: float | None = None
        self._last_time: float | None = None
        self._index = FrameIndex(self.outdir / f"{stem}.csv")

    def _encode(self, image: np.ndarray) -> np.ndarray:
        """Linear frame -> the pixels sent to ffmpeg (here 8-bit tone-mapped grey)."""
        return self._tonemapper(image)

    def _frame_bytes(self, pixels: np.ndarray) -> bytes:
        """The raw frame ffmpeg reads, from the (padded) pixels of ``_encode``."""
        return np.ascontiguousarray(pixels).tobytes()

    def _codec_args(self, shape: tuple[int, int]) -> tuple[str, str, str, list[str]]:
        """(pixel format in, pixel format out, codec, output parameters) for frames of ``shape``."""
        return "gray", self.pixel_format, "libx264", ["-crf", str(_X264_CRF), *BT709_TAGS]

    def _write(self, frame: Frame, image: np.ndarray) -> None:
        pixels = self._encode(image)
        if self._encoder is None:
            self._start_encoder(pixels.shape)
        if any(self._padding):
            pixels = np.pad(pixels, ((0, self._padding[0]), (0, self._padding[1])), mode="edge")
        self._encoder.send(self._frame_bytes(pixels))
        self._index.add(frame.index, frame.time_s, self.path.name)
        if self._first_time is None:
            self._first_time = frame.time_s
        self._last_time = frame.time_s

    def _start_encoder(self, shape: tuple[int, int]) -> None:
        """Launch ffmpeg for frames of ``shape`` and log size and playback-speed facts."""
        height, width = shape
        if self.pixel_format == "auto":
            self.pixel_format = "yuv420p" if height % 2 == 0 and width % 2 == 0 else "yuv444p"
            log.info("%s: %dx%d frames encoded as H.264 %s at their exact size",
                     self.path.name, width, height, self.pixel_format)
        if self.pixel_format.startswith("yuv420p"):
            self._padding = (height % 2, width % 2)
            if any(self._padding):
                log.info(
                    "%s: yuv420p needs even sizes; padding %dx%d frames to %dx%d by repeating edge "
                    "pixels (choose pixel format yuv444p for the exact size)",
                    self.path.name, width, height, width + self._padding[1], height + self._padding[0],
                )
        if self.capture_rate_hz:
            log.info("%s: capture read out at %.6g Hz", self.path.name, self.capture_rate_hz)
        if self.frame_rate_hz:
            log.info(
                "%s: %.6g output frames per second of capture played at %.6g fps: %.3gx slower "
                "than real time", self.path.name, self.frame_rate_hz, self.fps, self.frame_rate_hz / self.fps,
            )
        pix_fmt_in, pix_fmt_out, codec, params = self._codec_args(shape)
        self._encoder = FfmpegEncoder(self._temp, (width + self._padding[1], height + self._padding[0]),
                                      pix_fmt_in=pix_fmt_in, pix_fmt_out=pix_fmt_out, fps=float(self.fps),
                                      codec=codec, output_params=[*params, "-movflags", "+faststart", "-f", "mp4"],
                                      display_path=self.path)

    def _commit(self) -> None:
        import imageio_ffmpeg

        if self._encoder is None:
            log.warning("%s: no frames arrived; no video written", self.path)
            self._index.commit()
            return
        encoder, self._encoder = self._encoder, None
        encoder.close()
        try:
            encoded, _ = imageio_ffmpeg.count_frames_and_secs(str(self._temp))
        except (RuntimeError, OSError) as exc:
            raise OutputError(f"{self.path}: ffmpeg did not produce a readable video ({ffmpeg_reason(exc)}; "
                              "disk full or a write error?)") from exc
        if encoded != self.frames_written:
            raise OutputError(f"{self.path}: ffmpeg wrote {encoded} of {self.frames_written} frames")
        commit(self._temp, self.path)
        self._index.commit()
        if self.frame_rate_hz is None and self.frames_written > 1:
            span = (self._last_time - self._first_time) / (self.frames_written - 1)
            if span > 0:
                log.info(
                    "%s: each frame spans %.4g ms of capture; playback at %.6g fps is %.3gx slower "
                    "than real time", self.path.name, span * 1e3, self.fps, 1.0 / (span * self.fps),
                )

    def _discard(self) -> None:
        if self._encoder is not None:
            self._encoder.kill()
            self._encoder = None
        remove_quietly(self._temp)
        self._index.discard()


@dataclass(frozen=True)
class SinkOptions:
    """Everything a sink may be configured with; each format takes what applies to it.

    ``capture_rate_hz`` (raw readout rate) and ``frame_rate_hz`` (output frames per second of
    capture) are recorded in EXR headers and used to report slow-motion playback for MP4."""

    fps: float = 30.0
    tonemap: ToneMapConfig = field(default_factory=ToneMapConfig)
    exr_dtype: ExrDtype = "half"
    stem: str = DEFAULT_STEM
    capture_rate_hz: float | None = None
    frame_rate_hz: float | None = None
    mp4_pixel_format: Mp4PixelFormat = "auto"
    nits_per_unit: float | None = None
    #: (index, time_s, file) of the frames an interrupted run left, which a frame-file sink continues (read once)
    prior_rows: Iterable[tuple[int, float, str]] = ()

    def exr_attributes(self) -> dict[str, float | int | str]:
        """The rates as EXR header attributes."""
        attrs: dict[str, float | int | str] = {}
        if self.capture_rate_hz is not None:
            attrs["rmbvideo:capture_rate_hz"] = float(self.capture_rate_hz)
        if self.frame_rate_hz is not None:
            attrs["rmbvideo:frame_rate_hz"] = float(self.frame_rate_hz)
        return attrs


#: Output format -> how to build its sink in a folder. A new format is one ``FrameSink`` subclass
#: plus one line here; ``reconstruct --format`` and ``batch`` offer every key.
SINKS: dict[str, Callable[[Path, SinkOptions], FrameSink]] = {
    "mp4": lambda outdir, o: Mp4Sink(outdir, o.stem, fps=o.fps, tonemap=o.tonemap, pixel_format=o.mp4_pixel_format,
                                     capture_rate_hz=o.capture_rate_hz, frame_rate_hz=o.frame_rate_hz),
    "exr": lambda outdir, o: ExrSink(outdir, o.stem, o.exr_dtype, o.exr_attributes(), o.prior_rows),
    "png": lambda outdir, o: PngSink(outdir, o.stem, o.tonemap, o.prior_rows),
    "hdr10": lambda outdir, o: _hdr_sink("pq", outdir, o),
    "hlg": lambda outdir, o: _hdr_sink("hlg", outdir, o),
    "null": lambda outdir, o: NullSink(),
}
SINK_FORMATS: tuple[str, ...] = tuple(SINKS)


def _hdr_sink(transfer: str, outdir: Path, o: SinkOptions) -> FrameSink:
    from rmbvideo.io.hdr_video import HdrVideoSink

    return HdrVideoSink(outdir, o.stem, transfer=transfer, fps=o.fps, nits_per_unit=o.nits_per_unit,
                        capture_rate_hz=o.capture_rate_hz, frame_rate_hz=o.frame_rate_hz)


def make_sink(fmt: SinkFormat, outdir: Path, *, tonemap: ToneMapConfig | None = None, **options: Any) -> FrameSink:
    """Create the sink for output format ``fmt`` in ``outdir`` (created if missing; unused for null);
    keyword ``options`` are ``SinkOptions`` fields."""
    if fmt not in SINKS:
        raise ValueError(f"unknown output format {fmt!r}; use one of {SINK_FORMATS}")
    settings = SinkOptions(tonemap=tonemap or ToneMapConfig(), **options)
    if fmt == "null":
        return SINKS[fmt](Path(outdir), settings)
    low, high = PLAYBACK_FPS_RANGE
    if not low <= settings.fps <= high:
        raise ValueError(f"fps must be between {low:g} and {high:g}, got {settings.fps}")
    if settings.mp4_pixel_format not in ("auto", "yuv420p", "yuv444p"):
        raise ValueError(f"MP4 pixel format must be auto, yuv420p or yuv444p, got {settings.mp4_pixel_format!r}")
    outdir = Path(outdir)
    try:
        os.makedirs(outdir, exist_ok=True)
    except OSError as exc:
        if is_environment_error(exc) or isinstance(exc, FileExistsError):
            raise output_error(outdir, exc) from exc
        raise
    return SINKS[fmt](outdir, settings)


def ffmpeg_reason(exc: BaseException) -> str:
    """The last line of an ffmpeg failure: its reason without the version banner."""
    lines = [line.strip(" )") for line in str(exc).splitlines() if line.strip(" )")]
    return lines[-1] if lines else type(exc).__name__


def write_frames(frames: Iterable[Frame], outdir: Path, fmt: SinkFormat = "mp4", overwrite: bool = False,
                 **options: Any) -> int:
    """Write ``frames`` to ``outdir`` as ``fmt`` (``make_sink`` options) and return how many were written. Like
    ``rmbvideo reconstruct``, the folder is made whole in a staging folder and replaces ``outdir`` when all are
    written: an error leaves ``outdir`` as it was, and earlier outputs there are replaced only with ``overwrite``
    (frames written into them one by one left the earlier run's extra frames beside the new ones)."""
    with contextlib.ExitStack() as stack:
        folder = Path(outdir) if fmt == "null" else stack.enter_context(
            staged_folder(Path(outdir), is_sink_output, overwrite=overwrite))
        with make_sink(fmt, folder, **options) as sink:
            for frame in frames:
                sink.write(frame)
            return sink.frames_written
