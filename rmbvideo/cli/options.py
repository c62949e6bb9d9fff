"""Click options shared by the commands that read captures (geometry, rate, time range)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import click

from rmbvideo.io.sidecar import read_sidecar

DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_RATE_HZ = 400, 250, 20000.0


def capture_options(func: Callable) -> Callable:
    """Geometry and rate of the input capture; ``None`` defaults so a sidecar can fill them."""
    options = [
        click.option("--width", type=click.IntRange(min=8), default=None,
                     help=f"Stored plane width in pixels, header columns included [default: {DEFAULT_WIDTH}]."),
        click.option("--height", type=click.IntRange(min=2), default=None,
                     help=f"Plane height in pixels [default: {DEFAULT_HEIGHT}]."),
        click.option("--flip/--no-flip", default=None,
                     help="Flip stored rows upside down, as the camera stores them [default: flip]."),
        click.option("--header-cols", type=click.IntRange(min=0), default=None,
                     help="Columns at the end of each stored row that are a header to drop [default: 0]."),
        click.option("--rate", "rate_hz", type=click.FloatRange(min=0, min_open=True), default=None,
                     help=f"Readout rate of the capture in Hz [default: {DEFAULT_RATE_HZ:g}]."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def open_capture(path: Path, width: int | None, height: int | None, flip: bool | None,
                 header_cols: int | None, rate_hz: float | None):
    """Open ``path`` as a ``DatReader``: options override the sidecar, which overrides defaults.

    A capture with a ``.mbit`` multi-bit sidecar (a native multi-bit/RMB sensor, see
    ``rmbvideo.io.rmbfile``) opens as an ``RmbFileReader``, whose header fixes its geometry.
    """
    from rmbvideo.io.dat import DatGeometry, DatReader
    from rmbvideo.io.rmbfile import RmbFileReader, mbit_path

    if Path(path).is_file() and mbit_path(Path(path)).is_file():
        return RmbFileReader(Path(path))

    info = read_sidecar(Path(path)).override(width=width, height=height, flip=flip,
                                             header_cols=header_cols, rate_hz=rate_hz)
    geometry = DatGeometry(
        width=info.width if info.width is not None else DEFAULT_WIDTH,
        height=info.height if info.height is not None else DEFAULT_HEIGHT,
        header_cols=info.header_cols if info.header_cols is not None else 0,
        flip=info.flip if info.flip is not None else True,
    )
    return DatReader(Path(path), geometry, rate_hz=info.rate_hz or DEFAULT_RATE_HZ)
