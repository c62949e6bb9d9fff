"""``rmbvideo simulate``: a spike capture (and optionally its HDR ground truth) from a scene.

Output: ``-o NAME.dat`` in the camera's orientation (rows flipped) plus ``NAME.capture.json``
(geometry, rate, readout) so other commands pick the settings up; ``Lbit``/``rmb`` readouts add
``NAME.mbit`` (``rmbvideo.io.rmbfile``). ``1bit`` and ``binned`` scenes both write a plain 1-bit
``.dat`` at the raw size; they differ in the ground truth (``binned``: half size, as the binned
pipeline outputs).

Ground truth (``--gt DIR``): frame ``i`` is at ``t_i = (i*step + step/2) / rate`` (``step`` raw
readouts, default 20, centred like reconstruction frames), for every frame whose interval fits in
the capture. ``gt_NNNNNN.exr`` holds exposure * radiance / Q_r (expected photo-charge per raw
readout relative to the threshold, float32), ``flow_NNNNNN.npy`` the exact forward flow
(H, W, 2) float32 (dx, dy) in output pixels from ``t_i`` to ``t_{i+1}``, and ``index.csv`` lists
``index,time_s,file``.
"""

from __future__ import annotations

import csv
import io
import logging
from pathlib import Path

import click
import numpy as np

from rmbvideo.cli import progress_enabled

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
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
@click.option("--list", "list_scenes", is_flag=True, help="List bundled scenes and exit.")
def simulate(scene_name: str | None, output: Path | None, gt_dir: Path | None, gt_step: int,
             duration_s: float | None, chunk_readouts: int, quiet: bool, list_scenes: bool) -> None:
    """Simulate a spiking-camera capture of SCENE (a bundled name or a TOML file)."""
    from rmbvideo.scenes.scene import bundled_scenes, resolve_scene

    if list_scenes:
        for name, description in bundled_scenes().items():
            click.echo(f"{name}\t{description}")
        return
    if scene_name is None or output is None:
        raise click.UsageError("SCENE and -o/--output are required (or use --list)")
    from tqdm import tqdm

    from rmbvideo.io.sidecar import CaptureInfo, write_sidecar
    from rmbvideo.simulate.capture import CaptureSimulator

    scene = resolve_scene(scene_name)
    simulator = CaptureSimulator(scene, duration_s)
    readout = scene.readout
    log.info("scene %s: %dx%d at %g Hz, %d readouts, %s readout, effects: %s", scene.name, scene.width,
             scene.height, scene.rate_hz, simulator.total_readouts, readout.kind,
             ", ".join(scene.effects) or "none (deterministic)")
    if simulator.total_readouts == 0:
        raise click.UsageError(f"--duration {duration_s} s is shorter than one readout")
    progress = tqdm(total=simulator.total_readouts, unit="readout", disable=not progress_enabled(quiet))
    with progress, _open_writer(output, scene) as writer:
        for chunk in simulator.chunks(chunk_readouts):
            writer.write(chunk.planes if not readout.is_multibit else chunk)
            progress.update(len(chunk.planes) if not readout.is_multibit else len(chunk.single))
    extra = {"readout": readout.kind, "scene": scene.name}
    if readout.is_multibit:
        extra.update(level=readout.level)
    if readout.kind == "rmb":
        extra.update(band=readout.band, shift=readout.shift)
    write_sidecar(output, CaptureInfo(width=scene.width, height=scene.height, rate_hz=scene.rate_hz,
                                      flip=True, header_cols=0), **extra)
    log.info("wrote %s (%d readouts)", output, simulator.total_readouts)
    if gt_dir is not None:
        frames = write_ground_truth(simulator, gt_dir, gt_step)
        log.info("wrote %d ground-truth frames to %s", frames, gt_dir)


def _open_writer(output: Path, scene):
    from rmbvideo.io.dat import DatGeometry, DatWriter
    from rmbvideo.io.rmbfile import RmbFileWriter

    readout = scene.readout
    if readout.kind == "Lbit":
        return RmbFileWriter(output, scene.width, scene.height, readout.level, scene.rate_hz)
    if readout.kind == "rmb":
        return RmbFileWriter(output, scene.width, scene.height, readout.level, scene.rate_hz,
                             band=readout.band, shift=readout.shift)
    return DatWriter(output, DatGeometry(width=scene.width, height=scene.height, flip=True))


def write_ground_truth(simulator, gt_dir: Path, step: int) -> int:
    """Write GT frames, flows and ``index.csv`` for ``simulator``'s capture; returns the frame count."""
    from rmbvideo.errors import OutputError
    from rmbvideo.io.atomic import atomic_path, atomic_write_text
    from rmbvideo.io.exr import write_exr
    from rmbvideo.scenes.render import ground_truth, ground_truth_flow

    try:
        gt_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{gt_dir}: cannot create folder: {exc.strerror or exc}") from None
    rate = simulator.scene.rate_hz
    count = simulator.total_readouts // step
    table = io.StringIO()
    rows = csv.writer(table, lineterminator="\n")
    rows.writerow(["index", "time_s", "file"])
    for i in range(count):
        t = (i * step + step / 2) / rate
        name = f"gt_{i:06d}.exr"
        write_exr(gt_dir / name, ground_truth(simulator.renderer, t), time_s=t, dtype="float")
        with atomic_path(gt_dir / f"flow_{i:06d}.npy") as temp:
            with open(temp, "wb") as handle:
                np.save(handle, ground_truth_flow(simulator.renderer, t, t + step / rate))
        rows.writerow([i, repr(t), name])
    atomic_write_text(gt_dir / "index.csv", table.getvalue())
    return count
