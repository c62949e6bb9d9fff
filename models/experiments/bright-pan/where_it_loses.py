"""Where the default loses to TFI on the raw capture on a bright pan: each method's mu-law squared error (as
``evaluate`` scores it) split by the ground truth's level, on one held-out sequence, and how often its bins are
clamped (2x2x2 = 8 raw spikes read as ``MULTI_LEVEL`` = 7). Diagnosis only: nothing is chosen on it. Run from the
repository root (about a minute on one core; the held-out cache is made by ``rmbvideo evaluate --reset subtract``):

    python models/experiments/bright-pan/where_it_loses.py [SEQUENCE] [zero|subtract] [PNG]

With PNG, also writes the truth and each method side by side (mu-law, as scored) at the first, middle and last
scored frames, one row each.
"""

import sys
from pathlib import Path

import numpy as np
import torch

from rmbvideo.evaluate.harness import RAW_SPECS, SATURATION, baseline_specs, run_method, table2_specs
from rmbvideo.evaluate.heldout import load_heldout
from rmbvideo.evaluate.metrics import normalise_pair
from rmbvideo.mulaw import mu_law
from rmbvideo.sensor.binning import MULTI_LEVEL

BANDS = (0.0, 0.1, 0.5, 0.8, 0.95, 1.0, np.inf)  # ground-truth levels (charge per plane per threshold); the last: 1


def main(name: str, reset: str, png: str | None = None) -> None:
    torch.set_num_threads(1)
    seq = next(s for s in load_heldout(False, reset=reset) if s.name == name)
    full_bins = np.mean(seq.multi == MULTI_LEVEL)
    print(f"{name}, reset {reset}: {100 * full_bins:.1f} % of bins at {MULTI_LEVEL} (clamped from 8 or a true 7)")
    wanted = {"RMB-Net", "TFW-L", "MG20", "TFP-140 (raw)", "TFI (raw)"}
    specs = [s for s in table2_specs(Path("models")) + baseline_specs("pure-m") + list(RAW_SPECS) if s.name in wanted]
    specs = list({s.name: s for s in specs}.values())
    header = " | ".join(f"GT {lo:g}-{hi:g}" if hi < np.inf else f"GT {lo:g} (saturated)" for lo, hi in zip(BANDS, BANDS[1:]))
    print(f"| method | PSNR | median output where saturated | share of the squared error by GT level: {header} |")
    print("|---|---:|---:|" + "---:|" * (len(BANDS) - 1))
    scored = {}
    for spec in specs:
        result = run_method(spec, seq)
        scored[spec.name] = result.frames
        errors, levels, saturated = [], [], []
        for i, image in result.frames.items():
            truth = np.minimum(seq.gt[i], SATURATION)
            a, b = normalise_pair(image, truth, 99.9)
            errors.append(((mu_law(a) - mu_law(b)) ** 2).ravel())
            levels.append(truth.ravel())
            saturated.append(image[truth >= SATURATION])
        err, lev = np.concatenate(errors), np.concatenate(levels)
        shares = [err[(lev >= lo) & (lev < hi)].sum() / err.sum() for lo, hi in zip(BANDS, BANDS[1:])]
        at_ceiling = np.concatenate(saturated)
        print(f"| {spec.name} | {result.psnr:.2f} | {np.median(at_ceiling) if at_ceiling.size else float('nan'):.3f} | "
              + " | ".join(f"{100 * s:.0f} %" for s in shares) + " |", flush=True)
    shares = [np.mean((lev >= lo) & (lev < hi)) for lo, hi in zip(BANDS, BANDS[1:])]
    print("| pixels in each band | | | " + " | ".join(f"{100 * c:.0f} %" for c in shares) + " |")
    if png:
        import cv2

        frames = sorted(next(iter(scored.values())))
        rows = []
        for i in (frames[0], frames[len(frames) // 2], frames[-1]):
            truth = np.minimum(seq.gt[i], SATURATION)
            tiles = [mu_law(normalise_pair(truth, truth, 99.9)[1])]
            tiles += [mu_law(normalise_pair(images[i], truth, 99.9)[0]) for images in scored.values()]
            rows.append(np.concatenate(tiles, axis=1))
        cv2.imwrite(png, (np.concatenate(rows) * 255).clip(0, 255).astype(np.uint8))
        print(f"{png}: columns truth, {', '.join(scored)}; rows the first, middle and last scored frames")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "random-1000002", sys.argv[2] if len(sys.argv) > 2 else "subtract",
         sys.argv[3] if len(sys.argv) > 3 else None)
