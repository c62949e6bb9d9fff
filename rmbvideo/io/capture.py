"""Open a capture file with the geometry its options, its sidecar or the defaults give it."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from rmbvideo.errors import InputError
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.io.rmbfile import RmbFileReader, mbit_path
from rmbvideo.io.sidecar import read_sidecar, simulated_camera
from rmbvideo.sensor.conventions import PILE_UP_WINDOW, PILE_UP_WINDOWS, convention_from_spikes

log = logging.getLogger(__name__)

DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_RATE_HZ = 400, 250, 20000.0


def open_capture(path: Path, width: int | None = None, height: int | None = None, flip: bool | None = None,
                 header_cols: int | None = None, rate_hz: float | None = None) -> DatReader | RmbFileReader:
    """Open ``path`` as a ``DatReader``: options override the sidecar, which overrides defaults.

    A capture with a ``.mbit`` multi-bit sidecar (a native multi-bit/RMB sensor, see
    ``rmbvideo.io.rmbfile``) opens as an ``RmbFileReader``, whose header fixes its geometry.
    """
    _refuse_a_companion(Path(path))
    if Path(path).is_file() and mbit_path(Path(path)).is_file():
        reader = RmbFileReader(Path(path))
        given = {"--width": (width, reader.width), "--height": (height, reader.height), "--flip": (flip, reader.flip),
                 "--header-cols": (header_cols, 0), "--rate": (rate_hz, reader.rate_hz)}
        ignored = [name for name, (option, fixed) in given.items() if option is not None and option != fixed]
        if ignored:
            log.warning("%s: %s ignored: the header of %s fixes the capture's geometry and rate (%dx%d at %g Hz)",
                        path, ", ".join(ignored), reader.mbit.name, reader.width, reader.height, reader.rate_hz)
        return reader

    info = read_sidecar(Path(path)).override(width=width, height=height, flip=flip,
                                             header_cols=header_cols, rate_hz=rate_hz)
    try:
        geometry = DatGeometry(
            width=info.width if info.width is not None else DEFAULT_WIDTH,
            height=info.height if info.height is not None else DEFAULT_HEIGHT,
            header_cols=info.header_cols if info.header_cols is not None else 0,
            flip=info.flip if info.flip is not None else True,
        )
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    reader = DatReader(Path(path), geometry, rate_hz=info.rate_hz or DEFAULT_RATE_HZ)
    if info.width is None and info.height is None and info.header_cols is None:
        _warn_of_a_better_geometry(Path(path), geometry)
    return reader


def _refuse_a_companion(path: Path) -> None:
    """``InputError`` naming the capture when ``path`` is one of its companion files, the multi-bit readouts
    (``.mbit``) or the sidecar (``.capture.json``): read as spikes, they gave a misleading error or noise."""
    name = path.name.lower()
    if name.endswith(".capture.json"):
        what, dat = "the sidecar", path.with_name(path.name[: -len(".capture.json")] + ".dat")
    elif name.endswith(".mbit"):
        what, dat = "the multi-bit readouts", path.with_suffix(".dat")
    else:
        return
    if dat.is_file():
        raise InputError(f"{path}: is {what} of the capture {dat}; give {dat}, which is read with it")
    raise InputError(f"{path}: is {what} of a capture, read with its {dat.name}, which is not there")


#: The captures (path, size, modification time) already checked in this process: a warning once per capture
_checked: set[tuple[str, int, int]] = set()


def _warn_of_a_better_geometry(path: Path, assumed: DatGeometry) -> None:
    """Warn, once per capture, when the default size read for a capture that says nothing of its own looks wrong and
    another fits its data far better (a camera turned on its side, a header the default does not drop)."""
    from rmbvideo.io.geometry_guess import better_geometry

    try:
        stat = path.stat()
        key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
        if key in _checked:
            return
        _checked.add(key)
        found = better_geometry(path, assumed)
    except OSError:  # a hint only: the reading itself says what is wrong with the file
        return
    if found is not None:
        better, mine = found
        g = better.geometry
        header = f" with {g.header_cols} header columns" if g.header_cols else ""
        log.warning("%s: read as %dx%d, the default (nothing gives its size), but its data look like planes of "
                    "%dx%d%s (score %.2f against %.2f); if so, give %s or a sidecar (`rmbvideo info --guess-geometry` "
                    "lists more)", path, assumed.width, assumed.height, g.width, g.height, header, better.score,
                    mine.score, better.options)


def plane_windows(reader: DatReader, size: int, count: int, start: int = 0,
                  stop: int | None = None) -> Iterator[np.ndarray]:
    """Up to ``count`` consecutive windows of ``size`` raw planes (T, H, W) from ``start``, one read at a time."""
    stop = reader.n_planes if stop is None else min(stop, reader.n_planes)
    for first in range(start, min(stop, start + count * size) - size + 1, size):
        yield reader.read(first, first + size)


def capture_convention(reader: DatReader | RmbFileReader, path: Path, start: int = 0,
                       stop: int | None = None) -> str | None:
    """The sensor convention ``--convention auto`` reads a capture in: for one ``rmbvideo simulate`` made, its recorded
    pixel's (physical, or the rate convention for a pixel reset by subtraction); a native multi-bit one physical;
    else what its first spikes from ``start`` show (``convention_from_spikes``, ``PILE_UP_WINDOWS`` windows read one
    at a time), None when they cannot tell."""
    camera = simulated_camera(path)
    if camera is not None:
        return "spikezoo" if camera.reset == "subtract" else "physical"
    if isinstance(reader, RmbFileReader):
        return "physical"
    return convention_from_spikes(plane_windows(reader, PILE_UP_WINDOW, PILE_UP_WINDOWS, start, stop))
