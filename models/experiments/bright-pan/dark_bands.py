"""Where the default and the classical methods lose on the development pans, by the ground truth's level: each
method's mean mu-law squared error (as ``evaluate`` scores it) per band of the truth, x 1e5, on the development
random scenes (never the held-out ones). Run from the repository root (a few minutes on one core):

    python models/experiments/bright-pan/dark_bands.py [zero|subtract]
"""

import sys
from pathlib import Path

import numpy as np
import torch

from rmbvideo.evaluate.harness import RAW_SPECS, SATURATION, run_method, table2_specs
from rmbvideo.evaluate.heldout import load_development
from rmbvideo.evaluate.metrics import normalise_pair
from rmbvideo.mulaw import mu_law

BANDS = (0.0, 0.003, 0.01, 0.03, 0.1, 0.5, 1.0, np.inf)  # charge per raw plane per threshold; the last: saturated
METHODS = ("RMB-Net", "TFW-L", "TFP-80 (raw)", "TFI (raw)")


def main(reset: str) -> None:
    torch.set_num_threads(1)
    specs = {s.name: s for s in list(table2_specs(Path("models"))) + list(RAW_SPECS)}
    names = " | ".join(f"{lo:g}-{hi:g}" if hi < np.inf else f"{lo:g} (saturated)" for lo, hi in zip(BANDS, BANDS[1:]))
    print(f"| sequence | method | PSNR | {names} |")
    print("|---|---|---:|" + "---:|" * (len(BANDS) - 1))
    for seq in (s for s in load_development(reset=reset) if s.name.startswith("random")):
        for name in METHODS:
            result = run_method(specs[name], seq)
            errors, levels = [], []
            for i, image in result.frames.items():
                truth = np.minimum(seq.gt[i], SATURATION)
                a, b = normalise_pair(image, truth, 99.9)
                errors.append(((mu_law(a) - mu_law(b)) ** 2).ravel())
                levels.append(truth.ravel())
            err, lev = np.concatenate(errors), np.concatenate(levels)
            cells = [err[(lev >= lo) & (lev < hi)].sum() / len(err) * 1e5 for lo, hi in zip(BANDS, BANDS[1:])]
            print(f"| {seq.name} | {name} | {result.psnr:.2f} | " + " | ".join(f"{c:.2f}" for c in cells) + " |",
                  flush=True)
        shares = [np.mean((lev >= lo) & (lev < hi)) for lo, hi in zip(BANDS, BANDS[1:])]
        print(f"| {seq.name} | pixels in the band | | " + " | ".join(f"{100 * s:.1f} %" for s in shares) + " |")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "zero")
