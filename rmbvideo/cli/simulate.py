"""``rmbvideo simulate``: a spike capture (and optionally its HDR ground truth) from a scene.

Output: ``-o NAME.dat`` in the camera's orientation (rows flipped) plus ``NAME.capture.json``
(geometry, rate, readout) so other commands pick the settings up; ``Lbit``/``rmb`` readouts add
``NAME.mbit`` (``rmbvideo.io.rmbfile``). ``1bit`` and ``binned`` scenes both write a plain 1-bit
``.dat`` at the raw size; they differ in the ground truth (``binned``: half size, as the binned
pipeline outputs).

Ground truth (``--gt DIR``): see ``rmbvideo.simulate.ground_truth``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import click

from rmbvideo.cli import progress_enabled, quiet_option, verbose_option

log = logging.getLogger(__name__)


@click.command()
@click.argument("scene_name", metavar="SCENE", required=False)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Output .dat capture (Lbit/rmb readouts also write a .mbit beside it).")
@click.option("--gt", "gt_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Folder for ground-truth EXR frames, flow (.npy) and index.csv.")
@click.option("--gt-step", type=click.IntRange(min=1), default=20, show_default=True,
              help="Raw readouts per ground-truth frame.")
@click.option("--duration", "duration_s", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Simulate only the first S seconds of the scene.")
@click.option("--chunk", "chunk_readouts", type=click.IntRange(min=1), default=64, show_default=True,
              help="Readouts simulated and written per chunk (memory vs. overhead; no effect on results).")
@click.option("--overwrite", is_flag=True,
              help="Replace an existing capture at -o, and earlier ground truth in --gt.")
@quiet_option
@verbose_option
@click.option("--list", "list_scenes", is_flag=True, help="List bundled scenes and exit.")
def simulate(scene_name: str | None, output: Path | None, gt_dir: Path | None, gt_step: int,
             duration_s: float | None, chunk_readouts: int, overwrite: bool, quiet: bool,
             list_scenes: bool) -> None:
    """Simulate a spiking-camera capture of SCENE (a bundled name or a TOML file)."""
    from rmbvideo.scenes.scene import bundled_scenes, resolve_scene

    if list_scenes:
        for name, description in bundled_scenes().items():
            click.echo(f"{name}\t{description}")
        return
    if scene_name is None or output is None:
        raise click.UsageError("SCENE and -o/--output are required (or use --list)")
    from rmbvideo.errors import OptionError
    from rmbvideo.simulate.capture import simulate_capture

    try:
        simulate_capture(resolve_scene(scene_name), output, duration_s=duration_s, gt_dir=gt_dir, gt_step=gt_step,
                         chunk_readouts=chunk_readouts, progress=progress_enabled(quiet), overwrite=overwrite)
    except OptionError as exc:
        raise click.UsageError(str(exc)) from None
