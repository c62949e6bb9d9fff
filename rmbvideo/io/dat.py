"""Reading and writing ``.dat`` spike streams: headerless 1-bit planes, concatenated.

A stored plane of W x H pixels is W*H/8 bytes; pixel ``i`` (row-major) is bit ``i & 7`` of byte
``i >> 3``, least significant bit first. Stored rows are upside down (image = ``stored[::-1]``)
unless ``flip=False``. Some cameras store 416-column rows whose last 16 columns are a header;
``header_cols`` drops them (and the writer fills them with zeros). The reader reads any range by
position (``rmbvideo.io.records``), so resident memory is one chunk however long the capture, and a
file truncated while it is read gives an error, not a crash.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np

from rmbvideo.chunks import RmbChunk, SpikeChunk
from rmbvideo.errors import InputError, OutputError
from rmbvideo.image_pool import ImagePool
from rmbvideo.io.records import RecordFile, regular_file_size
from rmbvideo.sensor.binning import bin_2x2x2, bin_packed, binned_rmb_chunk

logger = logging.getLogger(__name__)

MAX_SIDE = 16384  # larger than any spiking camera; rejects typos such as 4000x2500000
DEFAULT_RATE_HZ = 20000.0
#: Plane rates a capture may have: anything outside is a typo (and would make times absurd or infinite).
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 1e9
_WRITE_BLOCK_PLANES = 1024
_UNPACK_BLOCK_PLANES = 32  # planes numpy decodes at a time (3.2 MB of bits at 400x250)
#: decoded chunks kept for reuse: two 1,024-plane chunks at 400x250 (a consumer holds one while the next is read)
DECODED_POOL_BYTES = 256 << 20


@dataclass(frozen=True)
class DatGeometry:
    """How planes are laid out in a ``.dat`` file (the file itself does not say)."""

    width: int = 400
    height: int = 250
    header_cols: int = 0
    flip: bool = True

    def __post_init__(self) -> None:
        desc = f"{self.width}x{self.height} with {self.header_cols} header columns"
        for name in ("width", "height", "header_cols"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise InputError(f"invalid .dat geometry {desc}: {name} must be an integer")
        if not (0 < self.width <= MAX_SIDE and 0 < self.height <= MAX_SIDE):
            raise InputError(f"invalid .dat geometry {desc}: sides must be 1..{MAX_SIDE}")
        if (self.width * self.height) % 8:
            raise InputError(f"invalid .dat geometry {desc}: width*height must be a multiple of 8")
        if not 0 <= self.header_cols < self.width:
            raise InputError(f"invalid .dat geometry {desc}: header columns must be 0..width-1")

    @property
    def image_width(self) -> int:
        """Columns of image per row (``width`` minus the header columns)."""
        return self.width - self.header_cols

    @property
    def plane_bytes(self) -> int:
        """Bytes of one stored plane, header columns included."""
        return self.width * self.height // 8

    @property
    def byte_aligned(self) -> bool:
        """True when rows and the image/header split fall on byte boundaries (fused binning)."""
        return self.width % 8 == 0 and self.header_cols % 8 == 0


COMMON_GEOMETRIES: tuple[DatGeometry, ...] = (
    DatGeometry(400, 250),
    DatGeometry(416, 250, header_cols=16),
    DatGeometry(1000, 1000),
)


def unpack_planes(packed: np.ndarray, geometry: DatGeometry, out: np.ndarray | None = None) -> np.ndarray:
    """Stored plane bytes (T, plane_bytes) -> (T, H, image_width) uint8 0/1 planes in image orientation.

    ``out``, when given, is a contiguous array of that shape and type to fill (e.g. a reused one: a fresh
    100 MB chunk costs its page faults every time). Decoded ``_UNPACK_BLOCK_PLANES`` at a time, so the
    intermediate bits stay small and in cache.
    """
    g = geometry
    shape = (len(packed), g.height, g.image_width)
    if out is None:
        out = np.empty(shape, np.uint8)
    elif out.shape != shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a contiguous {shape} uint8 array, got {out.shape} {out.dtype}")
    for b in range(0, len(packed), _UNPACK_BLOCK_PLANES):
        block = packed[b : b + _UNPACK_BLOCK_PLANES]
        bits = np.unpackbits(block, axis=1, bitorder="little").reshape(len(block), g.height, g.width)
        out[b : b + len(block)] = bits[:, ::-1, : g.image_width] if g.flip else bits[:, :, : g.image_width]
    return out


@dataclass
class PackedChunk:
    """Consecutive planes exactly as stored: ``data`` is (T, plane_bytes) uint8, file orientation,
    header columns included, laid out by ``geometry``; for methods that work on the bits directly."""

    data: np.ndarray
    start: int
    rate_hz: float
    geometry: DatGeometry

    @property
    def stop(self) -> int:
        return self.start + len(self.data)

    def unpack(self, pool: ImagePool | None = None) -> SpikeChunk:
        """The same planes decoded into a ``SpikeChunk`` (image orientation, header dropped), into an array taken
        from ``pool`` when given (one its earlier chunks no longer use: no page faults per chunk)."""
        out = None if pool is None else pool.take((len(self.data), self.geometry.height, self.geometry.image_width),
                                                   np.uint8)
        return SpikeChunk(planes=unpack_planes(self.data, self.geometry, out), start=self.start, rate_hz=self.rate_hz)


def _geometry_hint(size: int) -> str:
    fits = [f"{g.width}x{g.height}" for g in COMMON_GEOMETRIES if size % g.plane_bytes == 0]
    return f" (the size fits {', '.join(fits)})" if fits else ""


#: (offset, bytes, what): the first bytes of files taken for a capture by mistake. A .dat has no header, so a capture
#: would have to spell one of these (at least 4 bytes) with its first pixels; a video or picture read as planes of
#: spikes gave frames of noise without a word.
FOREIGN_SIGNATURES: tuple[tuple[int, bytes, str], ...] = (
    (0, b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (4, b"ftyp", "an MP4/MOV video"),
    (0, b"\x1a\x45\xdf\xa3", "a Matroska/WebM video"),
    (0, b"RIFF", "a RIFF file (AVI video or WAV sound)"),
    (0, b"\x76\x2f\x31\x01", "an OpenEXR image"),
    (0, b"\xff\xd8\xff\xe0", "a JPEG image"),
    (0, b"\xff\xd8\xff\xe1", "a JPEG image"),
    (0, b"\xff\xd8\xff\xdb", "a JPEG image"),
    (0, b"GIF8", "a GIF image"),
    (0, b"II*\x00", "a TIFF image"),
    (0, b"MM\x00*", "a TIFF image"),
    (0, b"\x93NUMPY", "a NumPy array (.npy)"),
    (0, b"PK\x03\x04", "a ZIP archive (or .npz)"),
    (0, b"\x89HDF\r\n\x1a\n", "an HDF5 file"),
)


def foreign_format(path: Path) -> str | None:
    """What ``path`` is when its first bytes are another format's signature (``FOREIGN_SIGNATURES``), else None."""
    with open(path, "rb") as handle:
        head = handle.read(16)
    return next((what for offset, magic, what in FOREIGN_SIGNATURES if head[offset:offset + len(magic)] == magic),
                None)


#: Sampled planes below which ``saturated_fraction`` does not say: a pixel at 0.95 spikes per plane fires in all 32
#: with probability 0.19, in all 64 with 0.04.
MIN_SATURATION_PLANES = 32


class DatReader:
    """Random access and chunked iteration over the whole planes of a ``.dat`` file.

    Raises ``InputError`` for a missing, unreadable or empty file or one smaller than a plane;
    a trailing partial plane is logged as a warning and ignored.
    """

    def __init__(
        self, path: str | os.PathLike, geometry: DatGeometry = DatGeometry(), rate_hz: float = DEFAULT_RATE_HZ
    ) -> None:
        self.path = Path(path)
        self.geometry = geometry
        if not (math.isfinite(rate_hz) and MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ):
            raise InputError(f"{self.path}: plane rate must be between {MIN_RATE_HZ:g} and {MAX_RATE_HZ:g} Hz, "
                             f"got {rate_hz}")
        self.rate_hz = float(rate_hz)
        size = regular_file_size(self.path)
        if size == 0:
            raise InputError(f"{self.path}: empty file")
        try:
            foreign = foreign_format(self.path)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read: {exc.strerror or exc}") from None
        if foreign is not None:
            raise InputError(f"{self.path}: is {foreign}, not a spike capture (a .dat holds raw planes of spikes)")
        plane_bytes = geometry.plane_bytes
        if size < plane_bytes:
            raise InputError(
                f"{self.path}: {size} bytes is less than one {geometry.width}x{geometry.height} plane "
                f"({plane_bytes} bytes); wrong geometry?{_geometry_hint(size)}"
            )
        self._n_planes = size // plane_bytes
        self._trailing_bytes = size % plane_bytes
        if self._trailing_bytes:
            logger.warning(
                "%s: %d trailing bytes after %d whole %dx%d planes (truncated capture or wrong "
                "geometry%s); they are ignored",
                self.path, self._trailing_bytes, self._n_planes, geometry.width, geometry.height,
                _geometry_hint(size),
            )
        self._file = RecordFile(self.path, plane_bytes, self._n_planes)
        self._binned = ImagePool()  # binned chunks' arrays, reused once released (no page faults per chunk)
        self._decoded = ImagePool(DECODED_POOL_BYTES)  # decoded planes likewise

    def close(self) -> None:
        """Close the file (reading after this is an error)."""
        self._file.close()

    @property
    def n_planes(self) -> int:
        """Whole planes in the file."""
        return self._n_planes

    @property
    def trailing_bytes(self) -> int:
        """Bytes after the last whole plane (0 for an intact file)."""
        return self._trailing_bytes

    @property
    def duration_s(self) -> float:
        """Capture length in seconds at ``rate_hz``."""
        return self._n_planes / self.rate_hz

    @property
    def shape(self) -> tuple[int, int]:
        """Image (height, width) of decoded planes."""
        return self.geometry.height, self.geometry.image_width

    def plane_index(self, time_s: float) -> int:
        """Index of the plane whose interval ``[k, k+1) / rate_hz`` contains ``time_s``.

        Times within 1e-6 of a plane boundary snap to it, so ``k / rate_hz`` maps back to ``k``.
        The result may exceed ``n_planes``; range checks are the caller's.
        """
        if not (math.isfinite(time_s) and time_s >= 0):
            raise InputError(f"{self.path}: time must be a non-negative number of seconds, got {time_s}")
        position = time_s * self.rate_hz
        nearest = round(position)
        return int(nearest) if abs(position - nearest) < 1e-6 else int(math.floor(position))

    def _range(self, start: int, stop: int | None) -> tuple[int, int]:
        stop = self._n_planes if stop is None else stop
        if not 0 <= start <= stop <= self._n_planes:
            raise InputError(f"{self.path}: planes {start}..{stop} are outside the capture's 0..{self._n_planes}")
        return start, stop

    def read(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Planes ``start..stop-1`` as (T, H, image_width) uint8 0/1 in image orientation."""
        start, stop = self._range(start, stop)
        out = self._decoded.take((stop - start, self.geometry.height, self.geometry.image_width), np.uint8)
        return unpack_planes(self._file.read(start, stop, scratch=True), self.geometry, out)

    def chunks(self, chunk_planes: int = 1024, start: int = 0, stop: int | None = None) -> Iterator[SpikeChunk]:
        """Consecutive ``SpikeChunk``s of at most ``chunk_planes`` planes covering ``start..stop``."""
        if chunk_planes < 1:
            raise ValueError(f"chunk_planes must be >= 1, got {chunk_planes}")
        start, stop = self._range(start, stop)
        for s in range(start, stop, chunk_planes):
            e = min(s + chunk_planes, stop)
            yield SpikeChunk(planes=self.read(s, e), start=s, rate_hz=self.rate_hz)

    def packed_chunks(self, chunk_planes: int = 1024, start: int = 0, stop: int | None = None) -> Iterator[PackedChunk]:
        """Consecutive ``PackedChunk``s of at most ``chunk_planes`` planes covering ``start..stop``.

        ``data`` is the stored bytes, read-only and not decoded.
        """
        if chunk_planes < 1:
            raise ValueError(f"chunk_planes must be >= 1, got {chunk_planes}")
        start, stop = self._range(start, stop)
        for s in range(start, stop, chunk_planes):
            e = min(s + chunk_planes, stop)
            yield PackedChunk(data=self._file.read(s, e), start=s, rate_hz=self.rate_hz, geometry=self.geometry)

    def read_binned(self, start: int = 0, stop: int | None = None) -> RmbChunk:
        """2x2x2-binned readouts of raw planes ``start..stop`` as a pure-M ``RmbChunk``.

        ``start`` must be even (readout ``k`` is raw planes ``2k, 2k+1``); an odd trailing plane
        is dropped. Uses the fused decode+bin path when rows are byte aligned, else unpacks.
        """
        start, stop = self._range(start, stop)
        if start % 2:
            raise ValueError(f"binned reading must start at an even raw plane, got {start}")
        stop -= (stop - start) % 2
        g = self.geometry
        if g.byte_aligned:
            packed = self._file.read(start, stop, scratch=True).reshape(stop - start, g.height, g.width // 8)
            out = self._binned.take((2, (stop - start) // 2, g.height // 2, g.image_width // 2), np.uint8)
            single, multi = bin_packed(packed, g.image_width, g.flip, out=out)
        else:
            single, multi = bin_2x2x2(self.read(start, stop))
        return binned_rmb_chunk(single, multi, start, self.rate_hz)

    def binned_chunks(self, chunk_planes: int = 1024, start: int = 0, stop: int | None = None) -> Iterator[RmbChunk]:
        """Consecutive binned chunks of ``chunk_planes`` raw planes (even) covering ``start..stop``."""
        if chunk_planes < 2 or chunk_planes % 2:
            raise ValueError(f"chunk_planes must be even and >= 2, got {chunk_planes}")
        start, stop = self._range(start, stop)
        if start % 2:
            raise ValueError(f"binned reading must start at an even raw plane, got {start}")
        stop -= (stop - start) % 2
        for s in range(start, stop, chunk_planes):
            e = min(s + chunk_planes, stop)
            yield self.read_binned(s, e)

    def mean_firing_rate(self, max_planes: int = 64) -> float:
        """Spikes per pixel per plane, estimated from up to ``max_planes`` evenly spaced planes."""
        return float(self._sampled_planes(max_planes).mean())

    def saturated_fraction(self, max_planes: int = 64) -> float | None:
        """The fraction of pixels that fired in every one of up to ``max_planes`` evenly spaced planes: lit at or above
        a spike per plane, where the sensor says nothing about how much brighter (None with fewer than
        ``MIN_SATURATION_PLANES`` planes, too few to tell a bright pixel from a saturated one)."""
        planes = self._sampled_planes(max_planes)
        if len(planes) < MIN_SATURATION_PLANES:
            return None
        return float(planes.all(axis=0).mean())

    def _sampled_planes(self, max_planes: int) -> np.ndarray:
        """Up to ``max_planes`` evenly spaced planes, decoded."""
        if max_planes < 1:
            raise ValueError(f"max_planes must be >= 1, got {max_planes}")
        picks = np.unique(np.linspace(0, self._n_planes - 1, min(max_planes, self._n_planes)).round().astype(np.int64))
        return unpack_planes(self._file.take(picks), self.geometry)


class DatWriter:
    """Context manager writing planes to a ``.dat`` file atomically.

    Planes go to a temporary file in the same folder, renamed over ``path`` only on a clean exit
    (removed on an exception), so a reader never sees a half-written capture.
    """

    def __init__(self, path: str | os.PathLike, geometry: DatGeometry = DatGeometry()) -> None:
        self.path = Path(path)
        self.geometry = geometry
        self._tmp_path = self.path.with_name(f".{self.path.name}.{os.getpid()}.part")
        self._file = None
        self._n_written = 0

    @property
    def n_written(self) -> int:
        """Planes written so far."""
        return self._n_written

    def __enter__(self) -> DatWriter:
        try:
            self._file = open(self._tmp_path, "wb")
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot write: {exc.strerror or exc}") from None
        return self

    def write(self, planes: np.ndarray) -> None:
        """Append planes (T, H, image_width) of 0/1 (uint8 or bool) in image orientation."""
        if self._file is None:
            raise RuntimeError("DatWriter.write called outside its 'with' block")
        g = self.geometry
        if planes.ndim != 3 or planes.shape[1:] != (g.height, g.image_width):
            raise ValueError(f"planes must be (T, {g.height}, {g.image_width}), got {planes.shape}")
        for s in range(0, len(planes), _WRITE_BLOCK_PLANES):
            block = planes[s : s + _WRITE_BLOCK_PLANES]
            if block.dtype != np.bool_ and np.any(block > 1):
                raise ValueError("planes must hold only 0 and 1")
            stored = np.zeros((len(block), g.height, g.width), dtype=np.uint8)
            stored[:, :, : g.image_width] = block[:, ::-1] if g.flip else block
            packed = np.packbits(stored.reshape(len(block), -1), axis=1, bitorder="little")
            try:
                self._file.write(packed.tobytes())
            except OSError as exc:
                raise OutputError(f"{self.path}: cannot write: {exc.strerror or exc}") from None
            self._n_written += len(block)

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        file, self._file = self._file, None
        if file is None:
            return
        try:
            file.close()
            if exc_type is None:
                os.replace(self._tmp_path, self.path)
        except OSError as err:
            self._tmp_path.unlink(missing_ok=True)
            raise OutputError(f"{self.path}: cannot write: {err.strerror or err}") from None
        if exc_type is not None:
            self._tmp_path.unlink(missing_ok=True)


def write_dat(path: str | os.PathLike, planes: np.ndarray, geometry: DatGeometry = DatGeometry()) -> None:
    """Write planes (T, H, image_width) of 0/1 in image orientation to ``path`` atomically."""
    with DatWriter(path, geometry) as writer:
        writer.write(planes)
