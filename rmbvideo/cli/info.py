"""``rmbvideo info``: what is in a capture, without processing it."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rmbvideo.cli.options import capture_options, open_capture


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@capture_options
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object on stdout.")
def info(input_path: Path, width, height, flip, header_cols, rate_hz, as_json: bool) -> None:
    """Planes, duration, geometry, mean firing rate and trailing bytes of a .dat capture."""
    reader = open_capture(input_path, width, height, flip, header_cols, rate_hz)
    geometry = reader.geometry
    record = {
        "file": str(input_path),
        "planes": reader.n_planes,
        "rate_hz": reader.rate_hz,
        "duration_s": reader.duration_s,
        "width": geometry.image_width,
        "height": geometry.height,
        "stored_width": geometry.width,
        "header_cols": geometry.header_cols,
        "flip": geometry.flip,
        "mean_firing_rate": reader.mean_firing_rate(),
        "trailing_bytes": reader.trailing_bytes,
    }
    if as_json:
        click.echo(json.dumps(record))
        return
    click.echo(f"file            {record['file']}")
    click.echo(f"planes          {record['planes']}")
    click.echo(f"duration        {record['duration_s']:.6f} s at {record['rate_hz']:g} Hz")
    click.echo(f"geometry        {record['width']}x{record['height']}"
               f" (stored width {record['stored_width']}, header columns {record['header_cols']},"
               f" {'flipped' if record['flip'] else 'not flipped'})")
    click.echo(f"mean firing     {record['mean_firing_rate']:.4f} spikes/pixel/plane")
    click.echo(f"trailing bytes  {record['trailing_bytes']}")
