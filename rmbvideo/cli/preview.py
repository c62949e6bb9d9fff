"""``rmbvideo preview``: a contact sheet of a few time points, for a quick look before a long run."""

from __future__ import annotations

from pathlib import Path

import click
import cv2
import numpy as np

from rmbvideo.cli import quiet_option, verbose_option
from rmbvideo.cli.options import capture_options
from rmbvideo.io.atomic import check_file_writable
from rmbvideo.io.capture import open_capture
from rmbvideo.io.png import write_png
from rmbvideo.io.tonemap import TONE_METHODS, ToneMapConfig, ToneMapper


#: Raw planes decoded at a time for a tile's mean: memory stays bounded whatever --window asks
MEAN_BLOCK = 256


def contact_sheet(reader, count: int = 6, window: int = 41, columns: int | None = None,
                  tonemap: ToneMapConfig = ToneMapConfig()) -> np.ndarray:
    """Tile TFP reconstructions at ``count`` evenly spaced times into one labelled 8-bit image, ``columns`` wide
    (default: about as many columns as rows, at least 3).

    The tiles are tone-mapped as one image, with ``reconstruct``'s operator (default: its exposure), so the sheet
    looks as the video will and its tiles compare. Only ``count * window`` planes are read, ``MEAN_BLOCK`` at a time,
    so this is fast and small on captures of any length and size.
    """
    n = reader.n_planes
    window = min(window, n)
    centres = np.linspace(window // 2, n - 1 - (window - 1 - window // 2), num=min(count, n)).round()
    tiles = []
    for centre in centres.astype(int):
        start = max(0, centre - window // 2)
        tiles.append(_mean_of_planes(reader, start, min(n, start + window)))
    mapped = ToneMapper(tonemap)(np.hstack(tiles))  # one exposure for every tile
    cells = []
    for centre, cell in zip(centres.astype(int), np.hsplit(mapped, len(tiles))):
        cell = np.ascontiguousarray(cell)
        label = f"{centre / reader.rate_hz * 1e3:.2f} ms"
        cv2.putText(cell, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 255, 1, cv2.LINE_AA)
        cells.append(cell)
    columns = min(columns or max(3, round(len(cells) ** 0.5)), len(cells))
    while len(cells) % columns:
        cells.append(np.zeros_like(cells[0]))
    return np.vstack([np.hstack(cells[r:r + columns]) for r in range(0, len(cells), columns)])


def _mean_of_planes(reader, start: int, stop: int) -> np.ndarray:
    """The mean of raw planes ``start..stop`` (float32), decoded ``MEAN_BLOCK`` at a time."""
    total = None
    for a in range(start, stop, MEAN_BLOCK):
        part = reader.read(a, min(stop, a + MEAN_BLOCK)).sum(axis=0, dtype=np.float32)
        total = part if total is None else total + part
    return total / np.float32(stop - start)


@click.command()
@verbose_option
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("preview.png"),
              show_default=True, help="PNG file to write.")
@click.option("--count", type=click.IntRange(1, 64), default=6, show_default=True,
              help="Number of time points.")
@click.option("--window", type=click.IntRange(1, 10000), default=41, show_default=True,
              help="Planes averaged per time point (TFP).")
@click.option("--tonemap", type=click.Choice(TONE_METHODS), default="exposure", show_default=True,
              help="Tone mapping, as reconstruct's for mp4/png.")
@click.option("--overwrite", is_flag=True, help="Replace an existing file at -o.")
@capture_options
@quiet_option
def preview(input_path: Path, output: Path, count: int, window: int, tonemap: str, overwrite: bool,
            width, height, flip, header_cols, rate_hz, quiet: bool) -> None:
    """Write a contact sheet of a few time points of INPUT (TFP, tone-mapped as reconstruct's video)."""
    check_file_writable(output, overwrite, suffixes=(".png",))
    reader = open_capture(input_path, width, height, flip, header_cols, rate_hz)
    sheet = contact_sheet(reader, count=count, window=window, tonemap=ToneMapConfig(method=tonemap))
    write_png(output, sheet)
    if not quiet:
        click.echo(f"wrote {output}")
