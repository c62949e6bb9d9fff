"""TFI over whole intervals (TFI-M, ``Tfi(window=M)``): why it helps on spikezoo's streams and how the window trades
on the synthetic sets. Run from the repository root (each a few minutes on one core once the caches exist):

    python models/experiments/raw-tfi-gate/tfi_window.py regularity ../shared/data/spikezoo-base
        # per rate band: how often consecutive intervals of a pixel differ by more than one plane (a noise-free
        # integrate-and-fire pixel under steady light: never), and the spike-train correlation of neighbouring
        # pixels of equal rate (independent phases: about 0)
    python models/experiments/raw-tfi-gate/tfi_window.py sweep development|heldout
        # TFI-M (raw, 2x2-averaged, read as light, mu-law PSNR) for M = 0, 2, 4, 8, 16, 32, and TFP-20/41, per sequence
        # and on average, with both pixels

The real-video table of the same windows is ``rmbvideo evaluate --real-video ../shared/data/spikezoo-base``.
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from rmbvideo.evaluate.harness import MethodSpec, run_method, score_frames
from rmbvideo.evaluate.heldout import (DEVELOPMENT_RANDOM_OFFSET, DEVELOPMENT_VIDEO_FIRST, FULL, load_development,
                                       load_heldout, load_heldout_config, load_video_heldout)
from rmbvideo.evaluate.real_video import find_streams
from rmbvideo.io.dat import DatReader

BANDS = ((0.05, 0.15), (0.15, 0.3), (0.3, 0.45), (0.45, 0.6))
WINDOWS = (0, 2, 4, 8, 16, 32)


def regularity(folder: str, pixel_stride: int = 7, per_band: int = 3000) -> None:
    print("| stream | rate band | pixels | consecutive intervals differing by > 1 plane | neighbour correlation |")
    print("|---|---|---:|---:|---:|")
    for stream in find_streams(Path(folder)):
        planes = DatReader(stream.capture, stream.geometry).read().astype(np.float32)
        flat = planes.reshape(len(planes), -1)
        rate = flat.mean(0)
        left, right = planes[:, :, :-1], planes[:, :, 1:]
        left_rate, right_rate = left.mean(0), right.mean(0)
        for lo, hi in BANDS:
            picked = np.arange(0, flat.shape[1], pixel_stride)
            picked = picked[(rate[picked] >= lo) & (rate[picked] < hi)][:per_band]
            jumps = [np.abs(np.diff(np.diff(np.flatnonzero(flat[:, p])))) for p in picked]
            total = sum(len(j) for j in jumps)
            irregular = sum(int((j > 1).sum()) for j in jumps) / max(total, 1)
            pairs = (np.abs(left_rate - right_rate) < 0.01) & (left_rate >= lo) & (left_rate < hi)
            a, b = left[:, pairs], right[:, pairs]
            cov = ((a - a.mean(0)) * (b - b.mean(0))).mean(0)
            corr = float(np.mean(cov / np.sqrt(a.var(0) * b.var(0) + 1e-9))) if pairs.any() else float("nan")
            print(f"| {stream.name} | {lo}-{hi} | {len(picked)} | {irregular:.3f} | {corr:.3f} |", flush=True)


def sweep(which: str) -> None:
    torch.set_num_threads(1)
    if which == "development":
        sets = {"zero": load_heldout_config(replace(FULL, count=16, first_seed_offset=DEVELOPMENT_RANDOM_OFFSET))
                + load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST),
                "subtract": load_development(reset="subtract")}
    else:
        sets = {reset: load_heldout(False, reset=reset) + load_video_heldout(False, reset=reset)
                for reset in ("zero", "subtract")}
    specs = [MethodSpec(f"TFI-{m}", "tfi", {"step": 20, "window": m}, raw=True) for m in WINDOWS]
    specs += [MethodSpec(f"TFP-{w}", "tfp", {"window": w, "step": 20}, raw=True) for w in (20, 41)]
    for reset, sequences in sets.items():
        print(f"\n{which}, pixel reset: {reset}\n")
        print("| sequence | " + " | ".join(s.name for s in specs) + " |")
        print("|---|" + "---:|" * len(specs))
        rows = []
        for seq in sequences:
            rows.append([score_frames(run_method(s, seq).frames, seq)[0] for s in specs])
            print(f"| {seq.name} | " + " | ".join(f"{v:.2f}" for v in rows[-1]) + " |", flush=True)
        print("| mean | " + " | ".join(f"{v:.2f}" for v in np.mean(rows, axis=0)) + " |")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "regularity":
        regularity(sys.argv[2])
    elif len(sys.argv) == 3 and sys.argv[1] == "sweep":
        sweep(sys.argv[2])
    else:
        sys.exit(__doc__)
