"""The detail stages at a clip's first, middle and last frames (development video clips, the default job at full
resolution with the raw gate): full-resolution mu-law PSNR of each, and a picture of the dark and low-contrast clips'
first frames. Run from the repository root:

    python models/experiments/camera-fixed-pattern/edge_frames.py BEFORE.safetensors AFTER.safetensors
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from dataclasses import replace

from rmbvideo.evaluate.full_resolution import full_ground_truth
from rmbvideo.evaluate.harness import SATURATION, sequence_convention
from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.io.png import write_png
from rmbvideo.mulaw import mu_law
from rmbvideo.net.weights import load_detail_model

sys.path.insert(0, str(Path(__file__).parent))
from detail_mismatch import default_job  # noqa: E402


def main(paths: list[Path]) -> None:
    torch.set_num_threads(1)
    details = {f"stage {k + 1}": load_detail_model(p)[0] for k, p in enumerate(paths)}
    print("| clip | frame | " + " | ".join(details) + " |\n|---|---|" + "---:|" * len(details))
    rows = []
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        every = replace(seq, edge_readouts=0)  # every frame scored, the clip's edges included
        truth = {i: np.minimum(gt, SATURATION) for i, gt in full_ground_truth(every).items()}
        frames = {name: default_job(detail, seq, sequence_convention(seq)) for name, detail in details.items()}
        last = max(truth)
        for label, i in (("first", 0), ("middle", last // 2), ("last", last)):
            print(f"| {seq.name} | {label} | " + " | ".join(f"{mu_law_psnr(frames[n][i], truth[i]):.2f}"
                                                          for n in details) + " |", flush=True)
        if seq.name.startswith(("dark", "low-contrast")):  # first frame, truth then each stage, mu-law shown
            scale = max(float(np.percentile(truth[0], 99.9)), 1e-6)
            images = [truth[0], *(frames[n][0] for n in details)]
            tiles = [(np.clip(mu_law(np.clip(x / scale, 0, 1), 5000.0), 0, 1) * 255).astype(np.uint8)[60:180, 120:280]
                     for x in images]
            for tile, label in zip(tiles, [f"{seq.name} first: truth", *details]):
                cv2.putText(tile, label, (3, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.33, 0, 2, cv2.LINE_AA)
                cv2.putText(tile, label, (3, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.33, 255, 1, cv2.LINE_AA)
            rows.append(np.hstack(tiles))
    picture = cv2.resize(np.vstack(rows), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    print("wrote", write_png(Path("models/figures/detail-mismatch-first-frames.png"), picture))


if __name__ == "__main__":
    main([Path(p) for p in sys.argv[1:]])
