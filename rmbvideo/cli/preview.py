"""``rmbvideo preview``: a contact sheet of a few time points, for a quick look before a long run."""

from __future__ import annotations

from pathlib import Path

import click
import cv2
import numpy as np

from rmbvideo.cli import verbose_option
from rmbvideo.cli.options import capture_options
from rmbvideo.io.capture import open_capture
from rmbvideo.io.png import write_png
from rmbvideo.mulaw import mu_law


def contact_sheet(reader, count: int = 6, window: int = 41, columns: int = 3) -> np.ndarray:
    """Tile TFP reconstructions at ``count`` evenly spaced times into one labelled 8-bit image.

    Only ``count * window`` planes are read, so this is fast on captures of any length.
    """
    n = reader.n_planes
    window = min(window, n)
    centres = np.linspace(window // 2, n - 1 - (window - 1 - window // 2), num=min(count, n)).round()
    tiles = []
    for centre in centres.astype(int):
        start = max(0, centre - window // 2)
        image = reader.read(start, min(n, start + window)).mean(axis=0, dtype=np.float32)
        tiles.append((centre, image))
    scale = max(float(np.percentile(np.concatenate([t.ravel() for _, t in tiles]), 99.5)), 1e-6)
    blank = np.zeros(tiles[0][1].shape, np.uint8)
    cells = []
    for centre, image in tiles:
        cell = (mu_law(image / scale) * 255.0).clip(0, 255).astype(np.uint8)
        label = f"{centre / reader.rate_hz * 1e3:.2f} ms"
        cv2.putText(cell, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 255, 1, cv2.LINE_AA)
        cells.append(cell)
    columns = min(columns, len(cells))
    while len(cells) % columns:
        cells.append(blank)
    return np.vstack([np.hstack(cells[r:r + columns]) for r in range(0, len(cells), columns)])


@click.command()
@verbose_option
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("preview.png"),
              show_default=True, help="PNG file to write.")
@click.option("--count", type=click.IntRange(1, 64), default=6, show_default=True,
              help="Number of time points.")
@click.option("--window", type=click.IntRange(1, 10000), default=41, show_default=True,
              help="Planes averaged per time point (TFP).")
@capture_options
def preview(input_path: Path, output: Path, count: int, window: int,
            width, height, flip, header_cols, rate_hz) -> None:
    """Write a contact sheet of a few time points of INPUT (TFP, mu-law tone-mapped)."""
    reader = open_capture(input_path, width, height, flip, header_cols, rate_hz)
    sheet = contact_sheet(reader, count=count, window=window)
    write_png(output, sheet)
    click.echo(f"wrote {output}")
