"""The first and last frames of the development clips where the edges cost most (dark-107, low-contrast-407): the
ground truth, the shipped model's own edge frames (``--edges off``) and the frames with its edge model (the default),
each with its mu-law PSNR, mu-law displayed at the truth's scale and shown twice as large. Development clips only.
Run from the repository root (about a minute, one core):

    python models/experiments/edge-candidates/edge_figure.py [OUT.png]
"""

import sys

import cv2
import numpy as np
import torch

from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.table import to_display
from rmbvideo.evaluate.video_checks import run_rmb

CLIPS = ("dark-107", "low-contrast-407")


def labelled(image: np.ndarray, label: str) -> np.ndarray:
    """``image`` (uint8 grey) twice as large, with ``label`` on a dark band above it."""
    big = cv2.resize(image, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    band = np.full((22, big.shape[1]), 30, np.uint8)
    cv2.putText(band, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, 255, 1, cv2.LINE_AA)
    return np.concatenate([band, big], axis=0)


def main(out: str = "models/figures/edge-model-frames.png") -> None:
    torch.set_num_threads(1)
    options = {"threads": 1, "input_mode": "binned"}
    rows = []
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        if seq.name not in CLIPS:
            continue
        runs = {edges: run_rmb("rmbnet", {**options, "edges": edges}, seq) for edges in ("off", "auto")}
        for which, i in (("first", 0), ("last", len(seq.gt) - 1)):
            truth = np.minimum(seq.gt[i], 1.0)
            scale = float(np.percentile(truth, 99.5))
            tiles = [labelled(to_display(truth, scale), f"{seq.name} {which} frame: truth")]
            for edges, name in (("off", "the model alone"), ("auto", "with its edge model")):
                image = runs[edges][i]
                tiles.append(labelled(to_display(image, scale), f"{name}: {mu_law_psnr(image, truth):.2f} dB"))
            rows.append(np.concatenate(tiles, axis=1))
    cv2.imwrite(out, np.concatenate(rows, axis=0), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print("wrote", out)


if __name__ == "__main__":
    main(*sys.argv[1:])
