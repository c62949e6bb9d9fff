"""Where a frame of the default full-resolution job goes, stage by stage, on one thread and everything inline: RMB-Net
with the raw gate and the learned detail stage on the first held-out capture (400x250), milliseconds a frame per stage
(``FullResolution.stage_seconds`` and the engine's own). Run from the repository root (a minute with the cache):

    python models/experiments/run-views/full_stages.py [auto|fp32|bf16]
"""

import sys
import time

import torch

from rmbvideo.evaluate.harness import SIMULATED_RESPONSE, sequence_convention
from rmbvideo.evaluate.heldout import load_heldout
from rmbvideo.recon.full_resolution import FullResolution, detail_stage, raw_gate_stage
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
from rmbvideo.recon.run import trained_readout
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout


def main(precision: str = "auto") -> None:
    torch.set_num_threads(1)
    seq = load_heldout(False)[0]
    recon = make_reconstructor("rmbnet", input_mode="binned", threads=1, convention=sequence_convention(seq),
                               response=SIMULATED_RESPONSE, precision=precision)
    readout = RmbReadout(mode=ReadoutMode(trained_readout(recon)))
    full = FullResolution(recon, readout, step=20, detail=detail_stage("learned"), threads=1,
                          raw_gate=raw_gate_stage("auto"), precision=precision)
    sink = FrameCollector()
    began = time.perf_counter()
    summary = reconstruct_stream(seq, full, sink, chunk_planes=128)
    count = len(sink.frames)
    print(f"{seq.name}: {count} frames, {1e3 * (time.perf_counter() - began) / count:.1f} ms a frame end to end")
    stages = {**summary.stages, **full.stage_seconds}
    print(", ".join(f"{name} {1e3 * seconds / count:.1f}" for name, seconds in stages.items()
                    if name not in ("method", "sink", "readout")), "(ms a frame)")


if __name__ == "__main__":
    main(*sys.argv[1:2])
