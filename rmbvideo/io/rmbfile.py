"""Multi-bit and rolling-mixed-bit captures: a ``.dat`` of 1-bit planes plus a ``.mbit`` sidecar.

``NAME.dat`` holds the single-bit plane of every readout in the ordinary ``.dat`` layout (LSB-first,
rows flipped by default), so every tool that reads 1-bit captures reads it. ``NAME.mbit`` beside it
holds the multi-bit values:

- 8 bytes magic ``b"RMBMBIT1"``, a little-endian uint32 ``n``, then ``n`` bytes of UTF-8 JSON:
  ``{"version": 1, "width", "height", "level", "bits", "rows": "all" | "band", "band",
  "shift", "rate_hz", "flip"}`` (``flip`` describes the ``.dat``; ``width``/``height`` are the image
  size; ``bits`` = log2(level + 1)).
- Then one fixed-size record per readout: the multi-bit values of the rows read multi-bit at that
  readout, in image orientation (never flipped), row after row, each value ``bits`` bits wide,
  LSB-first and packed across byte boundaries; the record is padded to a whole byte.
  ``rows = "all"``: every row, top to bottom (full L-bit planes). ``rows = "band"``: at readout
  ``t`` the rows ``(t * shift + j) mod height`` for ``j = 0 .. band-1`` in that order
  (``rmbvideo.sensor.readout.RmbReadout.band_rows``).

Both files are written atomically; the reader reads both by position, a chunk at a time, so memory
stays bounded (``rmbvideo.io.records``).
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType

import numpy as np

from rmbvideo.chunks import RmbChunk
from rmbvideo.errors import InputError
from rmbvideo.io.atomic import commit, output_error, remove_quietly, temp_path_for
from rmbvideo.io.dat import DatGeometry, DatReader, DatWriter
from rmbvideo.io.records import RecordFile, regular_file_size
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

MAGIC = b"RMBMBIT1"
_MAX_HEADER_BYTES = 1 << 16  # a header is ~200 bytes; a larger length field is corruption
VERSION = 1


def mbit_path(dat_path: Path) -> Path:
    """The ``.mbit`` sidecar of a ``.dat`` capture."""
    return Path(dat_path).with_suffix(".mbit")


def _pack(values: np.ndarray, bits: int) -> bytes:
    """Pack uint8 values (< 2**bits) into ``bits`` bits each, LSB-first."""
    unpacked = np.unpackbits(values.reshape(-1, 1), axis=1, bitorder="little")[:, :bits]
    return np.packbits(unpacked.reshape(-1), bitorder="little").tobytes()


def _unpack(record: np.ndarray, count: int, bits: int) -> np.ndarray:
    """Inverse of ``_pack`` for a (R, record_bytes) array: (R, count) uint8."""
    unpacked = np.unpackbits(record, axis=1, bitorder="little")[:, : count * bits]
    weights = (1 << np.arange(bits, dtype=np.uint8))
    return (unpacked.reshape(len(record), count, bits) * weights).sum(axis=2, dtype=np.uint8)


class RmbFileWriter:
    """Writes ``RmbChunk``s as ``path`` (.dat, single-bit planes) plus ``path.with_suffix('.mbit')``.

    ``band`` None stores full multi-bit planes (L-bit sensor); otherwise the RMB band geometry.
    """

    def __init__(self, path: Path, width: int, height: int, level: int, rate_hz: float,
                 band: int | None = None, shift: int = 2, flip: bool = True) -> None:
        self.path = Path(path)
        self.mbit = mbit_path(self.path)
        self.width, self.height, self.level = width, height, level
        self.bits = int(math.log2(level + 1))
        self.readout = RmbReadout(ReadoutMode.RMB, band, shift) if band is not None else None
        rows = height if band is None else min(band, height)
        self.record_bytes = (rows * width * self.bits + 7) // 8
        self.header = {"version": VERSION, "width": width, "height": height, "level": level,
                       "bits": self.bits, "rows": "all" if band is None else "band", "band": band or height,
                       "shift": shift, "rate_hz": rate_hz, "flip": flip}
        self.dat = DatWriter(self.path, DatGeometry(width=width, height=height, flip=flip))
        self._temp = temp_path_for(self.mbit)
        self._file = None
        self.n_written = 0

    def __enter__(self) -> RmbFileWriter:
        self.dat.__enter__()
        try:
            self._file = open(self._temp, "wb")
            header = json.dumps(self.header).encode("utf-8")
            self._file.write(MAGIC + struct.pack("<I", len(header)) + header)
        except OSError as exc:
            self.dat.__exit__(type(exc), exc, None)
            raise output_error(self.mbit, exc) from None
        return self

    def write(self, chunk: RmbChunk) -> None:
        """Append a chunk; it must continue the previous one and match the declared geometry."""
        if chunk.start != self.n_written:
            raise ValueError(f"chunk starts at readout {chunk.start}, expected {self.n_written}")
        if chunk.single.shape[1:] != (self.height, self.width) or chunk.level != self.level:
            raise ValueError("chunk geometry or level does not match the file")
        self.dat.write(chunk.single)
        records = []
        for t in range(len(chunk.single)):
            index = chunk.start + t
            rows = (np.arange(self.height) if self.readout is None
                    else self.readout.band_rows(index, self.height))
            records.append(_pack(np.ascontiguousarray(chunk.multi[t, rows]), self.bits))
        try:
            self._file.write(b"".join(records))
        except OSError as exc:
            raise output_error(self.mbit, exc) from None
        self.n_written += len(chunk.single)

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        file, self._file = self._file, None
        try:
            if file is not None:
                file.close()
        except OSError as err:
            remove_quietly(self._temp)
            self.dat.__exit__(type(err), err, None)
            raise output_error(self.mbit, err) from None
        if exc_type is not None:
            remove_quietly(self._temp)
            self.dat.__exit__(exc_type, exc, tb)
            return
        self.dat.__exit__(None, None, None)
        commit(self._temp, self.mbit)


class RmbFileReader:
    """Reads a ``.dat`` + ``.mbit`` capture as ``RmbChunk``s (native sensor: raw_per_readout = 1)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.mbit = mbit_path(self.path)
        if not self.mbit.exists():
            raise InputError(f"{self.mbit}: no such file (multi-bit sidecar of {self.path.name})")
        size = regular_file_size(self.mbit)
        try:
            with open(self.mbit, "rb") as file:
                start = file.read(12)
                if len(start) < 12 or start[:8] != MAGIC:
                    raise InputError(f"{self.mbit}: not an rmbvideo multi-bit file (bad magic)")
                (length,) = struct.unpack("<I", start[8:12])
                header_bytes = file.read(min(length, _MAX_HEADER_BYTES))
        except OSError as exc:
            raise InputError(f"{self.mbit}: cannot read ({exc.strerror or exc})") from None
        try:
            header = json.loads(header_bytes.decode("utf-8"))
            self.width, self.height = int(header["width"]), int(header["height"])
            self.level, self.bits = int(header["level"]), int(header["bits"])
            self.rate_hz, self.flip = float(header["rate_hz"]), bool(header["flip"])
            band, shift, rows = int(header["band"]), int(header["shift"]), header["rows"]
        except (ValueError, KeyError, TypeError, UnicodeDecodeError, RecursionError, OverflowError) as exc:
            raise InputError(f"{self.mbit}: bad header ({str(exc).splitlines()[0][:200]})") from None
        if header.get("version") != VERSION or rows not in ("all", "band"):
            raise InputError(f"{self.mbit}: unsupported version or rows ({header.get('version')}, {rows!r})")
        if not (1 <= self.level <= 255 and 1 <= self.bits <= 8 and self.level < 2 ** self.bits and band >= 1
                and shift >= 1 and self.width >= 1 and self.height >= 1):
            raise InputError(f"{self.mbit}: bad header (level {self.level}, bits {self.bits}, band {band}, "
                             f"shift {shift}, {self.width}x{self.height})")
        self.readout = RmbReadout(ReadoutMode.RMB, band, shift) if rows == "band" else None
        self.rows_per_readout = self.height if self.readout is None else min(band, self.height)
        self.record_bytes = (self.rows_per_readout * self.width * self.bits + 7) // 8
        self.dat = DatReader(self.path, DatGeometry(width=self.width, height=self.height, flip=self.flip),
                             rate_hz=self.rate_hz)
        records = max(size - 12 - length, 0) // self.record_bytes
        if records != self.dat.n_planes:
            raise InputError(f"{self.mbit}: {records} multi-bit readouts but {self.path.name} has "
                             f"{self.dat.n_planes} planes (truncated capture?)")
        self._records = RecordFile(self.mbit, self.record_bytes, records, offset=12 + length)

    @property
    def shape(self) -> tuple[int, int]:
        """Image (height, width) of the stream (native: no binning)."""
        return self.height, self.width

    @property
    def n_readouts(self) -> int:
        return self._records.count

    # The pipeline's source interface: raw 1-bit planes via the .dat, the RMB stream natively.
    @property
    def n_planes(self) -> int:
        """Readouts of the capture (a native sensor's raw planes)."""
        return self.n_readouts

    @property
    def geometry(self) -> DatGeometry:
        return self.dat.geometry

    @property
    def duration_s(self) -> float:
        return self.n_readouts / self.rate_hz

    @property
    def trailing_bytes(self) -> int:
        return self.dat.trailing_bytes

    def plane_index(self, time_s: float) -> int:
        return self.dat.plane_index(time_s)

    def mean_firing_rate(self, max_planes: int = 64) -> float:
        return self.dat.mean_firing_rate(max_planes)

    def saturated_fraction(self, max_planes: int = 64) -> float | None:
        return self.dat.saturated_fraction(max_planes)

    def read(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        return self.dat.read(start, stop)

    def chunks(self, chunk_planes: int = 1024, start: int = 0, stop: int | None = None):
        """The 1-bit planes of the capture (as a 1-bit camera would see them)."""
        return self.dat.chunks(chunk_planes, start, stop)

    def binned_chunks(self, chunk_planes: int = 1024, start: int = 0,
                      stop: int | None = None) -> Iterator[RmbChunk]:
        """The native mixed-bit stream (already in RMB or L-bit form; nothing to bin)."""
        return self.rmb_chunks(chunk_planes, start, stop)

    def rmb_chunks(self, chunk_readouts: int = 256, start: int = 0,
                   stop: int | None = None) -> Iterator[RmbChunk]:
        """Consecutive chunks of at most ``chunk_readouts`` readouts from ``start`` to ``stop``."""
        stop = self.n_readouts if stop is None else min(stop, self.n_readouts)
        for first in range(start, stop, chunk_readouts):
            last = min(first + chunk_readouts, stop)
            single = self.dat.read(first, last)
            count = last - first
            values = _unpack(self._records.read(first, last), self.rows_per_readout * self.width,
                             self.bits).reshape(count, self.rows_per_readout, self.width)
            multi = np.zeros((count, self.height, self.width), dtype=np.uint8)
            if self.readout is None:
                multi[:] = values
                multi_rows = np.ones((count, self.height), dtype=bool)
            else:
                multi_rows = self.readout.multi_rows(first, count, self.height)
                for t in range(count):
                    multi[t, self.readout.band_rows(first + t, self.height)] = values[t]
            yield RmbChunk(single=single, multi=multi, multi_rows=multi_rows, start=first,
                           rate_hz=self.rate_hz, level=self.level, raw_per_readout=1)
