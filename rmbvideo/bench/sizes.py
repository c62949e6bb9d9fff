"""RMB-Net's speed by frame size and precision on one device: the library run end to end (after a
warm-up in the same process) with the network's share of it, and the ``reconstruct`` command end to end
in a fresh process (its own start-up, lazy initialisation and autotuning included). Captures are random
Bernoulli planes: the network's work does not depend on their content."""

from __future__ import annotations

import logging
import re
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.recon.run import run_reconstruction

#: Raw sizes measured by default: 200x125 and 500x500 binned (a 1000x1000 camera).
DEFAULT_SIZES = ((400, 250), (1000, 1000))
_CLI_RATE = re.compile(r"\(([\d.]+) frames/s\)")

log = logging.getLogger(__name__)


@dataclass
class SizeResult:
    """One size and precision: frames/s of the library run end to end and of its network stage, of
    the ``reconstruct`` command, and the library run's milliseconds per frame by stage."""

    raw: str
    binned: str
    device: str
    precision: str
    frame_batch: int | None
    threads: int | None
    cuda_graphs: bool
    frames: int
    fps: float
    network_fps: float
    cli_fps: float | None
    stage_ms: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)


def _cli_fps(path: Path, width: int, height: int, device: str, precision: str, frame_batch: int | None,
             threads: int | None, cuda_graphs: bool, out: Path) -> float | None:
    """Frames/s that ``rmbvideo reconstruct --format null`` reports for ``path`` (None if it failed)."""
    batch = [] if frame_batch is None else ["--frame-batch", str(frame_batch)]
    batch += [] if threads is None else ["--threads", str(threads)]
    batch += [] if cuda_graphs else ["--no-cuda-graphs"]
    done = subprocess.run([sys.executable, "-m", "rmbvideo", "reconstruct", str(path), "-o", str(out),
                           "--format", "null", "--width", str(width), "--height", str(height), "--device", device,
                           "--precision", precision, "--overwrite", *batch], capture_output=True, text=True)
    match = _CLI_RATE.search(done.stderr)
    if done.returncode == 0 and match:
        return float(match.group(1))
    last = done.stderr.strip().splitlines()[-1:] or ["no message"]
    log.warning("reconstruct on %s (%s, %s) gave no rate (exit %d): %s", path.name, device, precision,
                done.returncode, last[0])
    return None


def bench_sizes(device: str, sizes: tuple[tuple[int, int], ...] = DEFAULT_SIZES,
                precisions: tuple[str, ...] = ("fp32", "bf16"), frames: int = 120,
                cli: bool = True, frame_batches: tuple[int | None, ...] = (None,),
                threads: int | None = None, cuda_graphs: bool = True) -> list[SizeResult]:
    """Measure the default model at each raw ``size`` (width, height), precision and frame batch (None: the
    engine's default for the device): ``frames`` output frames per run (20 raw planes each). ``threads``: the
    engine's (``RmbNetReconstructor``; on a GPU the aligned means' threads), None for the thread policy; ``cuda_graphs``
    the engine's."""
    results = []
    with tempfile.TemporaryDirectory(prefix="rmbvideo-sizes-") as folder:
        work = Path(folder)
        for width, height in sizes:
            path = write_random_capture(work / f"c{width}x{height}.dat", 20 * frames, width, height)
            capture = dict(width=width, height=height)
            for precision in precisions:
                for batch in frame_batches:
                    options = dict(device=device, precision=precision, frame_batch=batch, threads=threads,
                                   cuda_graphs=cuda_graphs)
                    run_reconstruction(path, work / "warm", fmt="null", duration_s=0.1, capture=capture,
                                       extra_options=options, overwrite=True)
                    summary = run_reconstruction(path, work / "out", fmt="null", capture=capture,
                                                 extra_options=options, overwrite=True)
                    network_s = summary.stages.get("network", 0.0)
                    results.append(SizeResult(
                        raw=f"{width}x{height}", binned=f"{width // 2}x{height // 2}", device=device,
                        precision=precision, frame_batch=batch, threads=threads, cuda_graphs=cuda_graphs,
                        frames=summary.frames,
                        fps=summary.frames_per_second, network_fps=summary.frames / network_s if network_s > 0 else 0.0,
                        cli_fps=(_cli_fps(path, width, height, device, precision, batch, threads, cuda_graphs,
                                         work / "cli") if cli
                                 else None),
                        stage_ms={k: 1e3 * v / max(summary.frames, 1) for k, v in summary.stages.items()},
                    ))
            path.unlink()
    return results


def sizes_table(results: list[SizeResult]) -> str:
    """Markdown table of ``results``."""
    stages = ("read", "readout", "preliminary frames", "network", "aligned mean", "detail")
    lines = ["| binned (raw) | device | precision | frame batch | threads | CUDA graphs | frames/s end to end | frames/s network "
             "| frames/s `reconstruct` | " + " | ".join(f"{s} ms/frame" for s in stages) + " |",
             "|---|---|---|---:|---:|---|---:|---:|---:|" + "---:|" * len(stages)]
    for r in results:
        cli = f"{r.cli_fps:.1f}" if r.cli_fps is not None else "n/a"
        batch = "default" if r.frame_batch is None else str(r.frame_batch)
        threads = "policy" if r.threads is None else str(r.threads)
        lines.append(f"| {r.binned} ({r.raw}) | {r.device} | {r.precision} | {batch} | {threads} | "
                     f"{'yes' if r.cuda_graphs and r.device == 'cuda' else 'no'} | {r.fps:.1f} | "
                     f"{r.network_fps:.1f} | {cli} | " + " | ".join(f"{r.stage_ms.get(s, 0.0):.2f}" for s in stages)
                     + " |")
    return "\n".join(lines) + "\n"
