"""RMB-Net alone on one device: the encoders over a run's frames and its batched pass (``RmbNet.step_run``) on
tensors already there, synchronised, with and without CUDA graphs; on a CPU also frame by frame, as the engine runs
there (the encoders in batches of ``ENCODE_BATCH``, then ``RmbNet.step`` per frame with its pair cache). It is what
the engine's network stage would cost with no pipeline around it (reading, preliminary frames, aligned means, copies
back), so the two figures side by side show where a run's time goes. Inputs are random counts: the network's work
does not depend on them."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import torch

from rmbvideo.net.model import PairCache, RmbNet, evict_pairs, window_indices
from rmbvideo.net.weights import default_model_path, load_model
from rmbvideo.recon.rmbnet import ENCODE_BATCH, inference_copy

#: binned sizes (width, height) and frames per batched pass measured by default: the engine's GPU defaults there
DEFAULT_RUNS = ((200, 125, 128), (500, 500, 16))


@dataclass
class NetworkResult:
    """Milliseconds per frame of the encoders and of the batched pass (best of ``repeats``), and the frames/s of
    both. ``frame_by_frame``: the pass is ``frame_batch`` calls of ``step`` (the CPU engine's path), not one
    ``step_run``."""

    binned: str
    device: str
    precision: str
    frame_batch: int
    cuda_graphs: bool
    encode_ms: float
    step_run_ms: float
    frame_by_frame: bool = False

    @property
    def fps(self) -> float:
        return 1e3 / (self.encode_ms + self.step_run_ms)

    def to_dict(self) -> dict:
        return {**asdict(self), "fps": self.fps}


def _inputs(model: RmbNet, width: int, height: int, count: int, device: torch.device) -> tuple[torch.Tensor, ...]:
    """Random preliminary sums for ``count`` output frames (2w more frames around them) and their aligned means (with
    their statistics for a model that reads them)."""
    config, frames = model.config, count + 2 * model.config.w
    g = torch.Generator().manual_seed(0)
    i_s = torch.randint(0, 81, (frames, height, width), generator=g).float()
    i_m = torch.randint(0, 7 * 81, (frames, height, width), generator=g).float()
    i_c = torch.randint(0, 7 * 8 * 4, (frames, max(1, len(config.centre_windows)), height, width), generator=g).float()
    aligned = torch.rand(count, config.aligned_channels + config.evidence_channels, height, width, generator=g)
    aligned[:, : config.aligned_channels] *= 7 * 80  # the means in sums, then their statistics
    return tuple(t.to(device) for t in (i_s, i_m, i_c, aligned))


def _frame_by_frame(net: RmbNet, inputs: tuple[torch.Tensor, ...], count: int) -> tuple[float, float]:
    """Seconds of the encoders (in batches of ``ENCODE_BATCH``, as the engine encodes) and of ``count`` calls of
    ``step``, each with the pair cache the engine keeps (evicting what the next frame no longer needs)."""
    i_s, i_m, i_c, aligned = inputs
    w, frames = net.config.w, count + 2 * net.config.w
    began = time.perf_counter()
    encoded = {}
    for first in range(0, frames, ENCODE_BATCH):
        ids = range(first, min(first + ENCODE_BATCH, frames))
        for frame in net.encode(i_s[first : ids.stop], i_m[first : ids.stop], ids,
                                i_c[first : ids.stop] if net.config.centre_windows else None):
            encoded[frame.index] = frame
    middle = time.perf_counter()
    cache: PairCache = {}
    state = None
    for i in range(w, w + count):
        window = [encoded[j] for j in window_indices(i, w, None)]
        _, state = net.step(window, state, cache, aligned=aligned[i - w : i - w + 1] if net.config.aligned else None)
        evict_pairs(cache, i + 1 - w)  # as the engine: the next frame looks w frames back
    return middle - began, time.perf_counter() - middle


def bench_network(device: str, runs: tuple[tuple[int, int, int], ...] = DEFAULT_RUNS,
                  precisions: tuple[str, ...] = ("fp32", "bf16"), graphs: tuple[bool, ...] = (False, True),
                  repeats: int = 5) -> list[NetworkResult]:
    """Time the shipped default at each binned (width, height, frames per pass), precision and CUDA-graph setting:
    ``repeats`` passes after a warm-up one (the graphs are captured in the warm-up), each carrying the last state.
    On a CPU each run's frames are also made frame by frame (``_frame_by_frame``), the path the engine takes there."""
    dev = torch.device(device)
    model = load_model(default_model_path())[0].to(dev).eval()
    config = model.config

    def sync() -> None:
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)

    results = []
    for width, height, count in runs:
        i_s, i_m, i_c, aligned = _inputs(model, width, height, count, dev)
        frames = range(count + 2 * config.w)
        for precision in precisions:
            bf16 = precision == "bf16"
            net = inference_copy(model, bf16=bf16)
            for graphed in graphs:
                encode, passes, state = [], [], None
                with torch.inference_mode(), torch.autocast(dev.type, dtype=torch.bfloat16, enabled=bf16):
                    for repeat in range(repeats + 2):  # a shape's graph is captured on its second pass
                        sync()
                        began = time.perf_counter()
                        encoded = net.encode(i_s, i_m, frames, i_c if config.centre_windows else None)
                        sync()
                        middle = time.perf_counter()
                        _, state = net.step_run(encoded, state, aligned=aligned if config.aligned else None,
                                                graphed=graphed)
                        sync()
                        if repeat >= 2:
                            encode.append(middle - began)
                            passes.append(time.perf_counter() - middle)
                results.append(NetworkResult(f"{width}x{height}", device, precision, count, graphed,
                                             1e3 * min(encode) / count, 1e3 * min(passes) / count))
            if dev.type == "cpu":
                with torch.inference_mode(), torch.autocast(dev.type, dtype=torch.bfloat16, enabled=bf16):
                    timed = [_frame_by_frame(net, (i_s, i_m, i_c, aligned), count) for _ in range(repeats + 1)][1:]
                results.append(NetworkResult(f"{width}x{height}", device, precision, count, False,
                                             1e3 * min(t[0] for t in timed) / count,
                                             1e3 * min(t[1] for t in timed) / count, frame_by_frame=True))
    return results


def network_table(results: list[NetworkResult]) -> str:
    """Markdown table of ``results``."""
    lines = ["| binned | device | precision | frames per pass | CUDA graphs | encode ms/frame | pass ms/frame "
             "| frames/s |", "|---|---|---|---|---|---:|---:|---:|"]
    for r in results:
        graphs = "yes" if r.cuda_graphs else "no"
        frames = f"1 (step, {r.frame_batch} frames)" if r.frame_by_frame else str(r.frame_batch)
        lines.append(f"| {r.binned} | {r.device} | {r.precision} | {frames} | {graphs} "
                     f"| {r.encode_ms:.3f} | {r.step_run_ms:.3f} | {r.fps:.0f} |")
    return "\n".join(lines) + "\n"
