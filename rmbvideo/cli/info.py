"""``rmbvideo info``: what is in a capture, without processing it."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rmbvideo.cli import verbose_option
from rmbvideo.cli.options import capture_options
from rmbvideo.io.capture import capture_convention, open_capture
from rmbvideo.io.dat import DatReader
from rmbvideo.io.rmbfile import RmbFileReader


#: What ``capture_convention`` says of a capture's pixel (its sidecar's record, or the pile-up test), in words.
PIXEL_WORDS = {
    "physical": "reset to zero at a spike: read with --convention physical",
    "spikezoo": "keeps the charge past its threshold: read in the rate convention (--convention spikezoo)",
    None: "cannot tell from the first planes (too few pixels near half the planes): read as physical",
}


@click.command()
@verbose_option
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@capture_options
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object on stdout.")
@click.option("--guess-geometry", is_flag=True,
              help="Rank likely plane geometries from the data itself instead (geometry options are ignored).")
def info(input_path: Path, width, height, flip, header_cols, rate_hz, as_json: bool,
         guess_geometry: bool) -> None:
    """Planes, duration, geometry, mean firing rate, saturated pixels and trailing bytes of a .dat capture."""
    if guess_geometry:
        show_geometry_guesses(input_path, as_json)
        return
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
        "saturated_fraction": reader.saturated_fraction(),
        "trailing_bytes": reader.trailing_bytes,
        "pixel": capture_convention(reader, input_path),  # what `reconstruct --convention auto` reads it as
        "multi_bit": multi_bit_record(reader),
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
    saturated = record["saturated_fraction"]
    click.echo("saturated       " + ("n/a (too few planes to tell)" if saturated is None else
                                     f"{100 * saturated:.1f} % of pixels fire every plane (light there is clipped)"))
    click.echo(f"trailing bytes  {record['trailing_bytes']}")
    click.echo(f"pixel           {PIXEL_WORDS[record['pixel']]}")
    multi_bit = record["multi_bit"]
    if multi_bit is not None:
        rows = ("every row" if multi_bit["band_rows"] is None else
                f"a band of {multi_bit['band_rows']} rows moving {multi_bit['band_shift']} a readout")
        click.echo(f"multi-bit       {multi_bit['file']}: {multi_bit['bits']}-bit values (up to {multi_bit['level']}) "
                   f"of {rows}; reconstruct reads the pair natively "
                   f"(full resolution; by default RMB-Net's native model)")


def multi_bit_record(reader: DatReader | RmbFileReader) -> dict | None:
    """What a native multi-bit capture's ``.mbit`` holds (None for a 1-bit capture)."""
    if not isinstance(reader, RmbFileReader):
        return None
    band = reader.readout
    return {"file": str(reader.mbit), "bits": reader.bits, "level": reader.level,
            "band_rows": None if band is None else band.band, "band_shift": None if band is None else band.shift}


def show_geometry_guesses(input_path: Path, as_json: bool) -> None:
    """Print the likeliest geometries of ``input_path``, best first, with the options selecting them."""
    from rmbvideo.io.geometry_guess import CONVINCING_SCORE, TIE_SCORE, guess_geometry, tied_with_best

    guesses = guess_geometry(input_path)
    convincing = bool(guesses) and guesses[0].score >= CONVINCING_SCORE
    tied = tied_with_best(guesses) if convincing else []
    records = [{"width": g.geometry.width, "height": g.geometry.height, "header_cols": g.geometry.header_cols,
                "score": round(g.score, 4), "row_correlation": round(g.row_correlation, 4),
                "plane_correlation": round(g.plane_correlation, 4), "planes": g.planes,
                "trailing_bytes": g.trailing_bytes, "options": g.options} for g in guesses]
    if as_json:
        click.echo(json.dumps({"file": str(input_path), "guesses": records, "ambiguous": len(tied) > 1}))
        return
    click.echo(f"likely geometries of {input_path} (best first; orientation cannot be told, flip assumed):")
    click.echo("  score  row-corr  plane-corr  stored WxH   whole planes  trailing bytes  options")
    for r in records:
        size = f"{r['width']}x{r['height']}"
        click.echo(f"  {r['score']:5.3f}  {r['row_correlation']:8.3f}  {r['plane_correlation']:10.3f}  {size:<10}  "
                   f"{r['planes']:>12}  {r['trailing_bytes']:>14}  {r['options']}")
    if not convincing:
        click.echo("no geometry makes this data look like images: is it a spike capture?")
    elif len(tied) > 1:
        click.echo(f"the first {len(tied)} score within {TIE_SCORE} of each other: the data cannot tell them apart "
                   "(a scene with little structure down its columns?); give the geometry with --width/--height or a "
                   "capture.json sidecar")
