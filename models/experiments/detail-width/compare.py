"""Detail stages of different widths side by side: their accuracy at full resolution on the development sequences
and the real-video streams (RMB-Net's binned frames, the same for each), and the detail network's own time at one
thread, alternated in one process. Run from the repository root:

    python models/experiments/detail-width/compare.py models/detail-binned.safetensors OTHER.safetensors ...
    python models/experiments/detail-width/compare.py --heldout A.safetensors B.safetensors   # once, to ship

``--heldout`` scores the evaluation's held-out sequences instead of the development ones (the learned row of
``rmbvideo evaluate --full-resolution``), for the one candidate chosen on the development sets.

The real-video streams are read from ``../shared/data/spikezoo-base`` when it is there.
"""

import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from rmbvideo.evaluate.full_resolution import full_ground_truth
from rmbvideo.evaluate.harness import SATURATION, SIMULATED_RESPONSE, rate_as_light, sequence_convention
from rmbvideo.evaluate.heldout import load_development, load_heldout, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.real_video import CONVENTION, RAW_STEP, find_streams, open_stream, scaled_psnr
from rmbvideo.net.weights import load_detail_model
from rmbvideo.recon.full_resolution import FullResolution, detail_inference_copy
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
from rmbvideo.recon.run import trained_readout
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

STREAMS = Path("../shared/data/spikezoo-base")


def full_frames(detail, source, convention: str, keep=None) -> dict[int, np.ndarray]:
    """The default RMB-Net at full resolution with ``detail`` on ``source`` (as ``evaluate --full-resolution``)."""
    recon = make_reconstructor("rmbnet", input_mode="binned", threads=1, convention=convention,
                               response=SIMULATED_RESPONSE)
    readout = RmbReadout(mode=ReadoutMode(trained_readout(recon)))
    full = FullResolution(recon, readout, step=RAW_STEP, detail=detail, threads=1)
    sink = FrameCollector(keep=keep)
    reconstruct_stream(source, full, sink, chunk_planes=128)
    return {i: rate_as_light("rmbnet", f.image, convention) for i, f in sink.frames.items()}


def accuracy(paths: list[Path], sequences: list) -> dict[str, dict[str, float]]:
    """Per detail file: sequence or stream -> PSNR (mu-law on sequences, linear with gain on streams)."""
    import cv2

    details = {p.name: load_detail_model(p)[0] for p in paths}
    scores: dict[str, dict[str, float]] = {name: {} for name in details}
    for seq in sequences:
        truth = {i: np.minimum(gt, SATURATION) for i, gt in full_ground_truth(seq).items()}
        for name, detail in details.items():
            frames = full_frames(detail, seq, sequence_convention(seq))
            scores[name][seq.name] = float(np.mean([mu_law_psnr(frames[i], truth[i]) for i in truth]))
            print(f"{seq.name}: {name} {scores[name][seq.name]:.2f} dB", flush=True)
    streams = find_streams(STREAMS) if STREAMS.is_dir() else []
    for stream in streams:
        reference = cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
        for name, detail in details.items():
            # made at the reference's moment, as the evaluation makes it (``open_stream``)
            frames = full_frames(detail, open_stream(stream), CONVENTION, keep=[stream.frame])
            image = frames[stream.frame][: reference.shape[0], : reference.shape[1]]
            scores[name][stream.name] = scaled_psnr(image, reference)
            print(f"{stream.name}: {name} {scores[name][stream.name]:.2f} dB", flush=True)
    return scores


def timing(paths: list[Path], size: tuple[int, int], pairs: int = 15) -> dict[str, float]:
    """Median ms of each detail network on one frame of binned ``size`` (h, w), alternated, one thread."""
    torch.set_num_threads(1)
    nets = {p.name: detail_inference_copy(load_detail_model(p)[0]) for p in paths}
    h, w = size
    binned = torch.rand(1, 1, h, w)
    times: dict[str, list[float]] = {name: [] for name in nets}
    with torch.no_grad():
        for rep in range(pairs):
            for name in (list(nets) if rep % 2 == 0 else list(nets)[::-1]):
                net = nets[name]
                rates = torch.rand(1, net.config.rate_channels, 2 * h, 2 * w).contiguous(
                    memory_format=torch.channels_last)
                began = time.perf_counter()
                net(binned, rates)
                times[name].append(time.perf_counter() - began)
    return {name: 1e3 * statistics.median(t[2:]) for name, t in times.items()}


def main() -> None:
    heldout = "--heldout" in sys.argv[1:]
    paths = [Path(p) for p in sys.argv[1:] if p != "--heldout"]
    if heldout:
        sequences = load_heldout(False) + load_video_heldout(False)
    else:
        sequences = load_development()
        for size in ((125, 200), (250, 250)):
            print(f"detail network at {size[1]}x{size[0]} binned, one thread, median ms:",
                  {k: round(v, 2) for k, v in timing(paths, size).items()}, flush=True)
    scores = accuracy(paths, sequences)
    names = list(scores)
    print("| set | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for key in scores[names[0]]:
        print(f"| {key} | " + " | ".join(f"{scores[n][key]:.2f}" for n in names) + " |")
    synthetic = [k for k in scores[names[0]] if k not in {s.name for s in find_streams(STREAMS)}] \
        if STREAMS.is_dir() else list(scores[names[0]])
    print(f"| mean of the {'held-out' if heldout else 'development'} sequences | "
          + " | ".join(f"{np.mean([scores[n][k] for k in synthetic]):.2f}" for n in names) + " |")


if __name__ == "__main__":
    main()
