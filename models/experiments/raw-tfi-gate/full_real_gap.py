"""Where the default job at full resolution still trails TFI-4 on a real-video stream (203_part3 by default): the
squared error of each, after the least-squares gain, split by the reference's local gradient (flat half, 50-80 %,
80-95 %, the top 5 % of edges) and by its level (dark < 0.1, mid, bright > 0.4). Run from the repository root (a
minute):

    python models/experiments/raw-tfi-gate/full_real_gap.py [STREAM]
"""

import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from rmbvideo.evaluate.full_resolution import FULL_LEARNED, full_rows, run_row
from rmbvideo.evaluate.real_video import CONVENTION, find_streams, least_squares_gain, open_stream

STREAMS = Path("../shared/data/spikezoo-base")


def main(name: str = "203_part3") -> None:
    torch.set_num_threads(1)
    stream = next(s for s in find_streams(STREAMS) if name in s.name)
    reference = cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
    rows = {r.name: r for r in full_rows()}
    errors = {}
    for row in (FULL_LEARNED, "TFI-4"):
        frames, _, _ = run_row(rows[row], open_stream(stream), keep=[stream.frame], convention=CONVENTION)
        image = frames[stream.frame][: reference.shape[0], : reference.shape[1]]
        errors[row] = (least_squares_gain(image, reference) * image - reference) ** 2
    made, tfi = errors[FULL_LEARNED], errors["TFI-4"]
    print(f"{stream.name}: mean squared error, the default {made.mean():.6f}, TFI-4 {tfi.mean():.6f}")
    gradient = np.hypot(cv2.Sobel(reference, cv2.CV_32F, 1, 0), cv2.Sobel(reference, cv2.CV_32F, 0, 1))
    q50, q80, q95 = np.quantile(gradient, [0.5, 0.8, 0.95])
    print("| region | pixels | the default's share of its error | the default | TFI-4 |\n|---|---:|---:|---:|---:|")
    for label, mask in (("flat half", gradient < q50), ("gradient 50-80 %", (gradient >= q50) & (gradient < q80)),
                        ("gradient 80-95 %", (gradient >= q80) & (gradient < q95)), ("top 5 % edges", gradient >= q95),
                        ("dark (< 0.1)", reference < 0.1), ("mid", (reference >= 0.1) & (reference < 0.4)),
                        ("bright (> 0.4)", reference >= 0.4)):
        print(f"| {label} | {mask.mean():.2f} | {made[mask].sum() / made.sum():.2f} | {made[mask].mean():.5f} "
              f"| {tfi[mask].mean():.5f} |")


if __name__ == "__main__":
    main(*sys.argv[1:2])
