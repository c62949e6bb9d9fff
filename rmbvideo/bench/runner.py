"""Run one benchmark configuration over the held-out sequences: accuracy, speed and peak memory.

End to end means what ``rmbvideo reconstruct --format null`` does: each sequence's raw 1-bit planes
are written once as a ``.dat`` capture and streamed through decode, 2x2x2 binning, the method and a
sink (one that keeps the scored frames). As in the evaluation harness (``rmbvideo.evaluate.harness``),
methods on the binned stream read it through the readout design of the default model (RMB-Net rows:
their own model's), frames of methods on raw planes (TFI) are 2x2 area-averaged to the ground-truth
size, and scores are per-sequence means of mu-law
PSNR/SSIM (a row: the mean over sequences). For RMB-Net the network alone (the streaming engine on
precomputed preliminary frames, window alignment included) is timed separately. Each sequence runs
``TIMING_RUNS`` times and the fastest run is timed: a shared machine slows single runs by 5-10 % at random. A row's
peak memory is that of a fresh process running it once on the largest sequence (``peak_memory_alone``): within one
process the resident set keeps the high-water mark of every row before, so each row would read at least the last's.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rmbvideo.bench.alone import CHUNK_PLANES, KeepFrames
from rmbvideo.bench.configs import BenchConfig
from rmbvideo.bench.memory import PeakMemory, child_peak_memory
from rmbvideo.bench.models import ModelChoice, build_network, find_model
from rmbvideo.evaluate.heldout import Sequence
from rmbvideo.evaluate.harness import downsample_2x, score_frames
from rmbvideo.io.dat import DatGeometry, DatReader, DatWriter
from rmbvideo.net.weights import model_readout
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import reconstruct_stream
from rmbvideo.recon.run import trained_readout
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout
from rmbvideo.threads import default_threads

log = logging.getLogger(__name__)

#: end-to-end runs per sequence; the fastest is timed (the frames of every run are the same)
TIMING_RUNS = 2
_MIB = 1024.0 * 1024.0


@dataclass
class BenchRecord:
    """One benchmark row. Accuracy is None ("n/a") for an untrained (random-init) network.

    ``fps``: output frames per wall second end to end; ``net_fps``: the network alone (RMB-Net
    only); ``realtime_factor``: seconds of capture processed per wall second end to end (>= 1 is real
    time); ``peak_rss_mib``: peak resident memory of a fresh process running the row once on the largest sequence
    (imports, model and all), ``peak_anon_mib`` its anonymous part (heap and arrays, without mapped file pages);
    None where not measured.
    """

    name: str
    method: str
    w: int | None
    align: str | None
    width: float | None
    precision: str | None
    device: str
    threads: int
    model: str
    trained: bool
    frames: int
    scored_frames: int
    psnr: float | None
    ssim: float | None
    fps: float
    net_fps: float | None
    realtime_factor: float
    peak_rss_mib: float | None
    peak_anon_mib: float | None
    pareto: bool = False

    @property
    def seconds_per_frame(self) -> float:
        """Wall seconds per output frame end to end (inf when nothing was produced)."""
        return 1.0 / self.fps if self.fps > 0 else math.inf

    def to_dict(self) -> dict[str, Any]:
        """JSON/CSV-ready dictionary."""
        return asdict(self)


def write_sequence_dat(sequence: Sequence, folder: Path) -> tuple[Path, DatGeometry]:
    """The sequence's raw planes as a .dat capture in ``folder`` (camera orientation, flipped rows)."""
    height, width = sequence.raw_shape
    geometry = DatGeometry(width=width, height=height)
    path = folder / f"heldout-{sequence.seed}.dat"
    if not path.exists():
        with DatWriter(path, geometry) as writer:
            for chunk in sequence.raw_chunks():
                writer.write(chunk.planes)
    return path, geometry


def make_row_method(config: BenchConfig, network, threads: int | None):
    """The row's reconstructor: a classical method with its options, or RMB-Net's engine (at full resolution with
    the raw stream's detail stage and gate, as ``reconstruct`` runs it)."""
    if not config.is_rmbnet:
        return make_reconstructor(config.method, **config.options)
    from rmbvideo.recon.rmbnet import RmbNetReconstructor

    engine = RmbNetReconstructor(network, device=config.device, align=config.align or "none",
                                 precision=config.precision or "auto", threads=threads)
    if config.resolution != "full":
        return engine
    from rmbvideo.recon.full_resolution import FullResolution, detail_stage, raw_gate_stage

    readout = RmbReadout(mode=ReadoutMode(trained_readout(engine)))
    return FullResolution(engine, readout, detail=detail_stage("auto"), threads=threads,
                          precision=config.precision or "auto", raw_gate=raw_gate_stage("auto"))


def classical_readout_design(models_dir: Path) -> str:
    """The readout design a classical row's binned input is read through: the default model's, as in ``evaluate``."""
    return model_readout(models_dir / "rmbnet-binned.safetensors")


def row_readout(config: BenchConfig, recon, models_dir: Path) -> RmbReadout | None:
    """The readout design a row's binned input is read through: an RMB-Net row's own model's, else the default's."""
    design = trained_readout(getattr(recon, "binned", recon)) if config.is_rmbnet \
        else classical_readout_design(models_dir)
    return RmbReadout(mode=ReadoutMode(design)) if recon.input_kind == "rmb" else None


def peak_memory_alone(config: BenchConfig, sequence: Sequence, workdir: Path, models_dir: Path,
                      threads: int | None) -> PeakMemory:
    """Peak memory of a fresh process running ``config`` once on ``sequence``."""
    path, geometry = write_sequence_dat(sequence, workdir)
    spec = {"config": asdict(config), "dat": str(path), "width": geometry.width, "height": geometry.height,
            "rate_hz": 2 * sequence.rate_hz, "models": str(models_dir), "threads": threads,
            "readout": None if config.is_rmbnet else classical_readout_design(models_dir)}
    return child_peak_memory("from rmbvideo.bench.alone import run_alone; run_alone(sys.argv[1])",
                             [json.dumps(spec)], what=f"bench row {config.name}")


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        import torch

        torch.cuda.synchronize()


def run_config(config: BenchConfig, sequences: list[Sequence], workdir: Path, models_dir: Path,
               threads: int | None = 1, runs: int = TIMING_RUNS, memory: bool = True) -> BenchRecord:
    """Benchmark ``config`` on ``sequences`` (their .dat files are cached in ``workdir``) with ``threads``
    threads (None: the thread policy) unless the row sets its own; each sequence ``runs`` times, the
    fastest timed; then, with ``memory``, its peak memory in a process of its own."""
    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    threads = config.threads or threads
    choice = ModelChoice(None)
    network = None
    if config.is_rmbnet:
        choice = find_model(config.w, config.width, models_dir)
        network = build_network(config.w, config.width, choice)
    frames = 0
    seconds = capture_s = 0.0
    net_frames, net_seconds = 0, 0.0
    psnrs: list[float] = []
    ssims: list[float] = []
    scored_frames = 0
    for sequence in sequences:
        path, geometry = write_sequence_dat(sequence, workdir)
        reader = DatReader(path, geometry, rate_hz=2 * sequence.rate_hz)
        scored = {i: sequence.frame_time(i) for i in sequence.scored_frames}
        summary = None
        for _ in range(runs):
            sink = KeepFrames(scored)
            recon = make_row_method(config, network, threads)
            run = reconstruct_stream(reader, recon, sink, chunk_planes=CHUNK_PLANES,
                                     readout=row_readout(config, recon, models_dir))
            _sync(config.device)
            summary = run if summary is None or run.seconds < summary.seconds else summary
        del reader
        frames += summary.frames
        seconds += summary.seconds
        capture_s += summary.planes / (2 * sequence.rate_hz)
        missing = sorted(set(scored) - set(sink.kept))
        if missing:
            log.warning("%s on %s: no output for scored frames %s", config.name, sequence.name, missing[:5])
        if (choice.trained or not config.is_rmbnet) and sink.kept:
            kept = {i: image if image.shape == sequence.shape else downsample_2x(image, sequence.shape)
                    for i, image in sink.kept.items()}
            psnr, ssim, _pu21 = score_frames(kept, sequence)
            psnrs.append(psnr)
            ssims.append(ssim)
            scored_frames += len(kept)
        if config.is_rmbnet:  # the network's share of the same run (RmbNetReconstructor.stage_seconds)
            net_frames += summary.frames
            net_seconds += summary.stages["network"]
    fps = frames / seconds if seconds > 0 else 0.0
    peak = None
    if memory:
        largest = max(sequences, key=lambda s: s.raw_shape[0] * s.raw_shape[1] * s.n_planes)
        peak = peak_memory_alone(config, largest, workdir, models_dir, threads)
    return BenchRecord(
        name=config.name, method=config.method, w=config.w, align=config.align, width=config.width,
        precision=config.precision, device=config.device, threads=threads or default_threads(), model=choice.label if config.is_rmbnet else "-",
        trained=choice.trained or not config.is_rmbnet, frames=frames, scored_frames=scored_frames,
        psnr=_finite_mean(psnrs), ssim=_finite_mean(ssims), fps=fps,
        net_fps=(net_frames / net_seconds if net_seconds > 0 else 0.0) if config.is_rmbnet else None,
        realtime_factor=capture_s / seconds if seconds > 0 else 0.0,
        peak_rss_mib=None if peak is None else peak.rss / _MIB,
        peak_anon_mib=None if peak is None else peak.anonymous / _MIB,
    )


def _finite_mean(values: list[float]) -> float | None:
    """Mean of the finite per-sequence values, or None when there are none."""
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else None

