"""Detail stages side by side in the default job at full resolution (RMB-Net, the raw gate, the detail stage), on
cameras with the paper's threshold mismatch and with half of it, and on the real-video streams; and on car.dat, a
picture. Development sequences only. Run from the repository root:

    python models/experiments/camera-fixed-pattern/detail_mismatch.py models/detail-binned.safetensors OTHER ...

The half-mismatch cameras are the development video sequences simulated again with ``capture_planes(mismatch=0.5)``
(a flat field's spread about its 2x2 mean 2.0 % against 3.8 %: about car.dat's camera, ``results.md``), in memory.
"""

from __future__ import annotations

import functools
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

import rmbvideo.simulate.capture as capture
from rmbvideo.evaluate.full_resolution import full_ground_truth
from rmbvideo.evaluate.harness import SATURATION, SIMULATED_RESPONSE, rate_as_light, sequence_convention
from rmbvideo.evaluate.heldout import (DEVELOPMENT_VIDEO_FIRST, FULL, VIDEO_KINDS, VIDEO_SEED_START, load_development,
                                       simulate_video_sequence)
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.real_video import CONVENTION, RAW_STEP, find_streams, open_stream, scaled_psnr
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.io.png import write_png
from rmbvideo.net.weights import load_detail_model
from rmbvideo.recon.full_resolution import FullResolution, raw_gate_stage
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
from rmbvideo.recon.run import trained_readout
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

SHARED = Path("../shared/data")


def default_job(detail, source, convention: str, response: str = SIMULATED_RESPONSE, keep=None) -> dict:
    """The default job's full-resolution frames (the raw gate on) with ``detail`` as its detail stage."""
    recon = make_reconstructor("rmbnet", input_mode="binned", threads=1, convention=convention, response=response)
    readout = RmbReadout(mode=ReadoutMode(trained_readout(recon)))
    full = FullResolution(recon, readout, step=RAW_STEP, detail=detail, threads=1, raw_gate=raw_gate_stage("auto"))
    sink = FrameCollector(keep=keep)
    reconstruct_stream(source, full, sink, chunk_planes=128)
    return {i: rate_as_light("rmbnet", f.image, convention) for i, f in sink.frames.items()}


def half_mismatch() -> list:
    """The development video sequences of the physical kinds, both pixels, their cameras at half the mismatch."""
    plain = capture.capture_planes
    capture.capture_planes = functools.partial(plain, mismatch=0.5)
    try:
        out = []
        for reset in ("zero", "subtract"):
            for k, kind in enumerate(VIDEO_KINDS):
                if kind.convention == "physical":
                    seq = simulate_video_sequence(VIDEO_SEED_START + 100 * k + DEVELOPMENT_VIDEO_FIRST, kind,
                                                  replace(FULL, reset=reset))
                    out.append((f"{seq.name} ({reset}, half mismatch)", seq))
        return out
    finally:
        capture.capture_planes = plain


def main(paths: list[Path]) -> None:
    torch.set_num_threads(1)
    details = {p.parent.name or p.stem: load_detail_model(p)[0] for p in paths}
    sets = ([(f"{s.name} (zero)", s) for s in load_development()]
            + [(f"{s.name} (subtract)", s) for s in load_development(reset="subtract")
               if sequence_convention(s) != "spikezoo" or "subtract" in (s.description or "")]
            + half_mismatch())
    rows: dict[str, dict[str, float]] = {}
    for label, seq in sets:
        truth = {i: np.minimum(gt, SATURATION) for i, gt in full_ground_truth(seq).items()}
        rows[label] = {}
        for name, detail in details.items():
            frames = default_job(detail, seq, sequence_convention(seq))
            rows[label][name] = float(np.mean([mu_law_psnr(frames[i], truth[i]) for i in truth]))
        print(label, {k: round(v, 2) for k, v in rows[label].items()}, flush=True)
    streams = find_streams(SHARED / "spikezoo-base") if (SHARED / "spikezoo-base").is_dir() else []
    for stream in streams:
        reference = cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
        rows[stream.name] = {}
        for name, detail in details.items():
            image = default_job(detail, open_stream(stream), CONVENTION, keep=[stream.frame])[stream.frame]
            rows[stream.name][name] = scaled_psnr(image[: reference.shape[0], : reference.shape[1]], reference)
        print(stream.name, {k: round(v, 2) for k, v in rows[stream.name].items()}, flush=True)
    names = list(details)
    print("\n| set | " + " | ".join(names) + " |\n|---|" + "---:|" * len(names))
    for label, scores in rows.items():
        print(f"| {label} | " + " | ".join(f"{scores[n]:.2f}" for n in names) + " |")
    groups = {"paper's mismatch, paper's pixel": lambda k: k.endswith("(zero)"),
              "paper's mismatch, subtracting pixel": lambda k: k.endswith("(subtract)"),
              "half the mismatch": lambda k: "half mismatch" in k,
              "real-video streams": lambda k: k in {s.name for s in streams}}
    for group, member in groups.items():
        keys = [k for k in rows if member(k)]
        if keys:
            print(f"| **mean: {group}** | " + " | ".join(f"{np.mean([rows[k][n] for k in keys]):.2f}" for n in names)
                  + " |")
    car = SHARED / "real" / "car.dat"
    if car.is_file():  # the middle frame's brightest textured corner at full size, 3x, per stage
        tiles = []
        for name, detail in details.items():
            frames = default_job(detail, DatReader(car, DatGeometry(400, 250)), "spikezoo", response="closed-form")
            image = frames[sorted(frames)[len(frames) // 2]]
            crop = image[60:140, 20:180] / max(float(np.percentile(image, 99.5)), 1e-6)
            tile = cv2.resize((np.clip(crop, 0, 1) * 255).astype(np.uint8), None, fx=3, fy=3,
                              interpolation=cv2.INTER_NEAREST)
            cv2.putText(tile, name, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, 255, 2, cv2.LINE_AA)
            tiles.append(tile)
        print("wrote", write_png(Path("models/figures/detail-mismatch-car.png"), np.vstack(tiles)))


if __name__ == "__main__":
    main([Path(p) for p in sys.argv[1:]])
