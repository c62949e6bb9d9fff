"""Capture simulation: a scene rendered over time, through a sensor's emission model, into the
chunks a camera would produce. The layer above ``scenes`` (what is seen) and ``sensor`` (how a
pixel responds): ``CaptureSimulator`` for TOML scenes, ``capture_planes`` for video-like scenes.
"""

from __future__ import annotations

import logging
from contextlib import ExitStack

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from rmbvideo.chunks import RmbChunk, SpikeChunk
from rmbvideo.errors import InputError, OptionError, OutputError
from rmbvideo.io.atomic import MEDIA_SUFFIXES
from rmbvideo.io.dat import DatGeometry, DatWriter
from rmbvideo.io.rmbfile import RmbFileWriter
from rmbvideo.scenes.render import SceneRenderer
from rmbvideo.scenes.scene import Scene
from rmbvideo.scenes.video import VideoScene
from rmbvideo.sensor.effects import REALISTIC_EFFECTS, row_delay
from rmbvideo.sensor.emission import ArrivalSpikeEmitter, RateIntegrateFire, SpikeEmitter, arrivals_apply
from rmbvideo.sensor.params import SensorParams

log = logging.getLogger(__name__)
#: Pixel-readouts simulated per chunk at most (the simulator holds a few float arrays of this size):
#: ``--chunk`` is lowered for large sensors so memory stays ~1 GB whatever the geometry.
CHUNK_PIXEL_READOUTS = 1 << 24


class CaptureSimulator:
    """Simulates a capture of a scene: radiance integrated over each interval -> spikes, in chunks.

    The expected photo-charge of interval ``k`` is ``exposure`` times the mean radiance over
    ``[k, k+1) / rate`` (``[k + r/H, k + 1 + r/H) / rate`` for row ``r`` with ``rolling_readout``),
    integrated with the trapezoid rule on ``scene.subsamples`` segments; the render at an interval's
    end is reused as the next one's start, so one segment costs one render per readout.
    """

    def __init__(self, scene: Scene, duration_s: float | None = None) -> None:
        self.scene = scene
        self.renderer = SceneRenderer(scene)
        self.row_delay: np.ndarray | float = row_delay(scene.effects, scene.height)
        total = scene.total_readouts
        if duration_s is not None:
            total = min(total, int(np.floor(duration_s * scene.rate_hz + 1e-9)))
            total -= total % 2 if scene.readout.kind == "binned" else 0
        self.total_readouts = total
        self._boundary: tuple[float, np.ndarray] | None = None

    def _render_boundary(self, boundary: float) -> np.ndarray:
        if self._boundary is not None and self._boundary[0] == boundary:
            return self._boundary[1]
        image = self.renderer.render((boundary + self.row_delay) / self.scene.rate_hz)
        self._boundary = (boundary, image)
        return image

    def expected_photo(self, k: int) -> np.ndarray:
        """Expected photo-electrons (H, W) float64 of readout interval ``k``."""
        n = self.scene.subsamples
        total = 0.5 * self._render_boundary(float(k)).astype(np.float64)
        for j in range(1, n):
            total += self.renderer.render((k + j / n + self.row_delay) / self.scene.rate_hz)
        total += 0.5 * self._render_boundary(float(k + 1))
        return total * (self.scene.exposure / n)

    def new_emitter(self) -> SpikeEmitter | ArrivalSpikeEmitter:
        """A pixel array as a running camera's is when a capture starts (every pixel at a random point of
        its integration cycle: ``settle``), with the scene's effects: photon arrivals where they give the
        same statistics (1-bit readout, shot noise; much faster), else per readout."""
        scene = self.scene
        level = scene.readout.level if scene.readout.is_multibit else 1
        kind = ArrivalSpikeEmitter if arrivals_apply(scene.effects, level) else SpikeEmitter
        emitter = kind(scene.height, scene.width, scene.sensor, scene.effects, scene.seed, scene.dark_correlation_px)
        emitter.settle(scene.seed)
        return emitter

    def chunks(self, chunk_readouts: int = 64) -> Iterator[SpikeChunk | RmbChunk]:
        """The whole capture from its start, as consecutive chunks: ``SpikeChunk`` for 1bit/binned
        (raw planes), ``RmbChunk`` for Lbit/rmb. Each call simulates afresh (same seed, same result)."""
        emitter = self.new_emitter()
        readout = self.scene.readout
        height = self.scene.height
        for start in range(0, self.total_readouts, chunk_readouts):
            count = min(chunk_readouts, self.total_readouts - start)
            multi_rows = readout.multi_rows(start, count, height)
            levels = np.where(multi_rows, readout.level, 1)
            values = np.empty((count, height, self.scene.width), dtype=np.uint8)
            for t in range(count):
                values[t] = emitter.emit_one(self.expected_photo(start + t), levels[t][:, None])
            if not readout.is_multibit:
                yield SpikeChunk(planes=values, start=start, rate_hz=self.scene.rate_hz)
                continue
            single = np.where(multi_rows[:, :, None], values == readout.level, values).astype(np.uint8)
            multi = np.where(multi_rows[:, :, None], values, np.uint8(0)).astype(np.uint8)
            yield RmbChunk(single=single, multi=multi, multi_rows=multi_rows, start=start,
                           rate_hz=self.scene.rate_hz, level=readout.level, raw_per_readout=1)


def capture_planes(scene: VideoScene, planes: int, rate_hz: float, chunk: int = 64,
                   reset: str = "zero", mismatch: float = 1.0) -> Iterator[SpikeChunk]:
    """The raw 1-bit capture of ``scene`` (``planes`` planes from time 0) in chunks: the physical
    emission model with a real camera's noise (its pixel reset as ``reset`` says, ``SensorParams.reset``; its
    threshold mismatch, the fixed pattern, ``mismatch`` times the paper's), or spikezoo's accumulate-and-subtract rate
    convention (``scene.convention``). Plane k integrates the scene at its midpoint k + 1/2. The capture starts
    mid-stream, as a running camera's does: every pixel at a random point of its integration cycle."""
    height, width = scene.height, scene.width
    if scene.convention == "physical":
        params = SensorParams(reset=reset, cap_std=SensorParams.cap_std * mismatch)  # x 1.0 is exact: the paper's
        emitter = SpikeEmitter(height, width, params, REALISTIC_EFFECTS, scene.seed)
        emitter.settle(scene.seed)
        emit = lambda value: emitter.emit_one(value * params.q_r, 1)  # noqa: E731
    else:
        emit = RateIntegrateFire((height, width), scene.seed).emit_one
    for start in range(0, planes, chunk):
        block = np.stack([emit(scene.render(k + 0.5)) for k in range(start, min(start + chunk, planes))])
        yield SpikeChunk(planes=block, start=start, rate_hz=rate_hz)


def open_writer(output: Path, scene: Scene) -> DatWriter | RmbFileWriter:
    """The writer for ``scene``'s capture: a 1-bit ``.dat``, or ``.dat`` + ``.mbit`` for Lbit/rmb readouts."""
    readout = scene.readout
    if readout.kind == "Lbit":
        return RmbFileWriter(output, scene.width, scene.height, readout.level, scene.rate_hz)
    if readout.kind == "rmb":
        return RmbFileWriter(output, scene.width, scene.height, readout.level, scene.rate_hz,
                             band=readout.band, shift=readout.shift)
    return DatWriter(output, DatGeometry(width=scene.width, height=scene.height, flip=True))


def capture_bytes(scene: Scene, readouts: int) -> int:
    """Bytes of the capture files ``simulate`` writes for ``readouts`` raw readouts of ``scene``."""
    pixels = scene.width * scene.height
    plane = (pixels + 7) // 8
    bits = scene.readout.level.bit_length()
    multi = 0
    if scene.readout.kind == "Lbit":
        multi = (pixels * bits + 7) // 8
    elif scene.readout.kind == "rmb":
        multi = (min(scene.readout.band, scene.height) * scene.width * bits + 7) // 8
    return readouts * (plane + multi)


def check_free_space(output: Path, needed: int) -> None:
    """``OutputError`` up front when the output's file system cannot hold ``needed`` bytes."""
    import shutil

    folder = output.resolve().parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if needed > free:
        raise OutputError(f"{output}: the capture needs {needed / 1e9:.3g} GB but {folder} has {free / 1e9:.3g} GB "
                          "free; shorten it with --duration")


#: Names of pictures, videos and data a capture is never given: simulate refuses them as a slip (-o demo.mp4)
NOT_CAPTURE_SUFFIXES = MEDIA_SUFFIXES | {".npy", ".npz", ".json", ".csv", ".md", ".h5"}


def check_capture_writable(output: Path, overwrite: bool) -> None:
    """``OutputError`` up front when ``output``'s folder is missing, or a capture (``.dat`` or ``.mbit``) is
    already there and ``overwrite`` is not given: a real capture is never replaced by a simulated one unasked."""
    from rmbvideo.io.atomic import check_file_writable
    from rmbvideo.io.rmbfile import mbit_path

    output = Path(output)
    if output.suffix.lower() in NOT_CAPTURE_SUFFIXES:
        dat = output.with_suffix(".dat")
        raise OutputError(f"{output}: simulate writes a spike capture, not a {output.suffix.lower()} file: name it "
                          f"e.g. {dat}, then `rmbvideo reconstruct {dat}` makes the video or pictures")
    check_file_writable(output, overwrite, example="capture.dat")
    mbit = mbit_path(output)
    if mbit.exists() and not overwrite:
        raise OutputError(f"{mbit}: exists; use --overwrite to replace it")


def simulate_capture(scene: Scene, output: Path, *, duration_s: float | None = None, gt_dir: Path | None = None,
                     gt_step: int = 20, chunk_readouts: int = 64, progress: bool = False,
                     overwrite: bool = False) -> CaptureSimulator:
    """Simulate ``scene`` into ``output`` (``.dat``, ``.mbit`` for multi-bit readouts, and the
    ``.capture.json`` sidecar other commands read), and its ground truth into ``gt_dir`` if given
    (``rmbvideo.simulate.ground_truth``). Returns the simulator (its renderer gives exact frames).
    An existing capture at ``output``, or earlier ground truth in ``gt_dir``, is replaced only with ``overwrite``."""
    from tqdm import tqdm

    from rmbvideo.io.atomic import staged_folder
    from rmbvideo.io.sidecar import CaptureInfo, write_sidecar
    from rmbvideo.simulate.ground_truth import is_ground_truth_file, write_ground_truth

    simulator = CaptureSimulator(scene, duration_s)
    readout = scene.readout
    size = capture_bytes(scene, simulator.total_readouts)
    log.info("scene %s: %dx%d at %g Hz, %d readouts (%.3g GB), %s readout, effects: %s", scene.name, scene.width,
             scene.height, scene.rate_hz, simulator.total_readouts, size / 1e9, readout.kind,
             ", ".join(scene.effects) or "none (deterministic)")
    if simulator.total_readouts == 0:
        if duration_s is not None:
            raise OptionError(f"--duration {duration_s:g} s is shorter than one readout ({1 / scene.rate_hz:g} s)")
        raise InputError(f"{scene.source or scene.name}: duration_s = {scene.duration_s:g} s is shorter than one readout at "
                         f"rate_hz = {scene.rate_hz:g} ({1 / scene.rate_hz:g} s)")
    above, below = simulator.renderer.rows_past_panorama(simulator.total_readouts / scene.rate_hz)
    if max(above, below) >= 1:
        log.warning("%s: the view reaches %.0f panorama rows above the top and %.0f below the bottom of %s (%d rows), "
                    "which show it mirrored; a smaller height, a larger zoom or another centre keeps it inside",
                    scene.source or scene.name, above, below, scene.background.panorama,
                    simulator.renderer.pano.shape[0])
    check_capture_writable(Path(output), overwrite)
    check_free_space(Path(output), size)
    chunk_readouts = max(1, min(chunk_readouts, CHUNK_PIXEL_READOUTS // (scene.width * scene.height)))
    with ExitStack() as stack:
        # Ground truth first, into a staging folder committed last: a failure anywhere leaves neither a
        # capture without its ground truth nor a half-written ground-truth folder.
        gt_staging = None
        if gt_dir is not None:
            gt_dir = Path(gt_dir)
            gt_staging = stack.enter_context(staged_folder(gt_dir, is_ground_truth_file, overwrite))
            try:
                frames = write_ground_truth(simulator, gt_staging, gt_step)
            except OutputError as exc:  # name the folder the user gave, not the staging folder
                raise OutputError(str(exc).replace(str(gt_staging), str(gt_dir))) from None
        bar = stack.enter_context(tqdm(total=simulator.total_readouts, unit="readout", disable=not progress))
        with open_writer(Path(output), scene) as writer:
            for chunk in simulator.chunks(chunk_readouts):
                writer.write(chunk.planes if not readout.is_multibit else chunk)
                bar.update(len(chunk.planes) if not readout.is_multibit else len(chunk.single))
        extra = {"readout": readout.kind, "scene": scene.name, "effects": list(scene.effects), "reset": scene.sensor.reset}
        if readout.is_multibit:
            extra.update(level=readout.level)
        if readout.kind == "rmb":
            extra.update(band=readout.band, shift=readout.shift)
        write_sidecar(Path(output), CaptureInfo(width=scene.width, height=scene.height, rate_hz=scene.rate_hz,
                                                flip=True, header_cols=0), **extra)
    log.info("wrote %s (%d readouts)", output, simulator.total_readouts)
    if gt_dir is not None:
        log.info("wrote %d ground-truth frames to %s", frames, gt_dir)
    return simulator
