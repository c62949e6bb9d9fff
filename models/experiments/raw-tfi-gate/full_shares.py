"""At full resolution, where the gate takes a raw TFI candidate's level, how much of the detail inside the block to
take from that candidate's own pixels (``FullResolution``'s ``candidate_detail``).

Until this experiment the default job gated the binned frame and then handed it to the detail stage, which shares
every 2x2 block's level among its pixels from the raw rates: where the gate took TFI-4's level for a block, the pixels
inside it still came from the detail stage's shape, never from TFI-4's own pixels. With ``candidate_detail`` a the
output is

    full + a * sum_k s_k * (TFI_k - block_mean(TFI_k) * full / gated)

(``rmbvideo.recon.full_resolution.with_candidate_detail``; s_k the gate's shares, TFI_k read as light per raw pixel):
at a = 1 a block taken wholly from a candidate is that candidate's pixels, at 0 it is the detail stage's as before.
Every block keeps the gated level. Each a is scored at full resolution as ``rmbvideo evaluate --full-resolution``
scores the default row, on the development sequences and the real-video streams (``--heldout``: the held-out
sequences, once, to ship). Run from the repository root (about 2 minutes once the sequences are cached):

    python models/experiments/raw-tfi-gate/full_shares.py [--heldout] [--detail STAGE.safetensors|classical] [--subtract]

``--detail``: another detail stage in place of the shipped one (``rmbvideo train-detail``'s output), or ``classical``
for ``reconstruct --detail classical`` (the raw rates' relative detail, no network); ``--subtract``:
the development sequences simulated with a pixel that resets by subtraction, like car.dat's camera (no real streams).
"""

import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from rmbvideo.evaluate.full_resolution import full_ground_truth
from rmbvideo.evaluate.harness import SATURATION, SIMULATED_RESPONSE, sequence_convention
from rmbvideo.evaluate.heldout import load_development, load_heldout, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.real_video import CONVENTION, RAW_STEP, find_streams, open_stream, scaled_psnr
from rmbvideo.net.weights import load_detail_model
from rmbvideo.recon.full_resolution import FullResolution, detail_stage, raw_gate_stage
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
from rmbvideo.recon.run import trained_readout
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

STREAMS = Path("../shared/data/spikezoo-base")
STRENGTHS = (0.0, 0.25, 0.5, 0.75, 1.0)


def frames(source_of, convention: str, strength: float, keep=None, detail=None) -> dict[int, np.ndarray]:
    """The default full-resolution job's frames with ``candidate_detail`` = ``strength`` (and ``detail`` in place of
    the shipped detail stage)."""
    recon = make_reconstructor("rmbnet", input_mode="binned", threads=1, convention=convention,
                               response=SIMULATED_RESPONSE)
    readout = RmbReadout(mode=ReadoutMode(trained_readout(recon)))
    stage = None if detail == "classical" else detail if detail is not None else detail_stage("learned")
    full = FullResolution(recon, readout, step=RAW_STEP, detail=stage, threads=1, raw_gate=raw_gate_stage("auto"),
                          candidate_detail=strength)
    sink = FrameCollector(keep=keep)
    reconstruct_stream(source_of(), full, sink, chunk_planes=128)
    return {i: f.image for i, f in sink.frames.items()}


def main() -> None:
    torch.set_num_threads(1)
    heldout = "--heldout" in sys.argv[1:]
    chosen = sys.argv[sys.argv.index("--detail") + 1] if "--detail" in sys.argv else None
    detail = "classical" if chosen == "classical" else load_detail_model(chosen)[0] if chosen else None
    subtract = "--subtract" in sys.argv[1:]
    if heldout and subtract:
        raise SystemExit("--subtract scores the development sequences only")
    sequences = (load_heldout(False) + load_video_heldout(False) if heldout
                 else load_development(reset="subtract" if subtract else "zero"))
    rows: dict[str, list[float]] = {}
    began = time.perf_counter()
    for seq in sequences:
        truth = {i: np.minimum(gt, SATURATION) for i, gt in full_ground_truth(seq).items()}
        rows[seq.name] = []
        for strength in STRENGTHS:
            made = frames(lambda: seq, sequence_convention(seq), strength, detail=detail)
            rows[seq.name].append(float(np.mean([mu_law_psnr(made[i], truth[i]) for i in truth])))
        print(seq.name, " ".join(f"{x:.2f}" for x in rows[seq.name]), flush=True)
    synthetic = list(rows)
    for stream in find_streams(STREAMS) if STREAMS.is_dir() and not subtract else []:
        reference = cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
        rows[stream.name] = []
        for strength in STRENGTHS:
            made = frames(lambda: open_stream(stream), CONVENTION, strength, keep=[stream.frame],
                          detail=detail)[stream.frame]
            rows[stream.name].append(scaled_psnr(made[: reference.shape[0], : reference.shape[1]], reference))
        print(stream.name, " ".join(f"{x:.2f}" for x in rows[stream.name]), flush=True)
    real = [k for k in rows if k not in synthetic]
    print(f"\n{time.perf_counter() - began:.0f} s\n\n| sequence | "
          + " | ".join(f"candidate detail {s:g}" for s in STRENGTHS) + " |\n|---|" + "---:|" * len(STRENGTHS))
    for name, row in rows.items():
        print(f"| {name} | " + " | ".join(f"{x:.2f}" for x in row) + " |")
    for label, names in (("synthetic mean", synthetic), ("real mean", real)):
        if names:
            print(f"| {label} | " + " | ".join(f"{np.mean([rows[k][v] for k in names]):.2f}"
                                               for v in range(len(STRENGTHS))) + " |")


if __name__ == "__main__":
    main()
