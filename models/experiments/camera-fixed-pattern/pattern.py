"""How strong is a camera's fixed pattern inside 2x2 blocks, on the real capture against the simulated cameras?

A pixel's rate over each half of a capture, as its deviation from its 2x2 block's mean; the two halves' deviations
correlated over pixels whose block level changed by more than 10 % between the halves (something moved there, so the
scene's own detail changed) and over those whose level stayed within 1 % (still). Where content moved, only what is
fixed to the pixel (the threshold's mismatch) makes the halves' deviations agree. Lit pixels only (block rates 0.15 to
0.85 a plane in both halves); the first 200 raw planes of each capture.

Real: ``car.dat`` (a real camera, no ground truth) and spikezoo's REDS streams (noise-free: no fixed pattern).
Simulated: the development captures of the evaluation's cache (never the held-out seeds), the paper's pixel and the
one reset by subtraction. Run from the repository root, after any `rmbvideo evaluate --development` has filled the
cache: python models/experiments/camera-fixed-pattern/pattern.py [SHARED]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from rmbvideo.evaluate.heldout import load_development
from rmbvideo.io.dat import DatGeometry, DatReader

PLANES = 200


def deviation(rate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's rate relative to its 2x2 block's mean, minus 1, and that mean spread to the pixels."""
    h, w = rate.shape
    mean = np.repeat(np.repeat(rate.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3)), 2, 0), 2, 1)
    return rate / np.maximum(mean, 1e-3) - 1.0, mean


def halves(planes: np.ndarray) -> str:
    """The table cells of one capture's first ``PLANES`` planes."""
    planes = planes[:PLANES].astype(np.float32)
    n = len(planes) // 2
    (da, ma), (db, mb) = deviation(planes[:n].mean(0)), deviation(planes[n:2 * n].mean(0))
    lit = (ma > 0.15) & (mb > 0.15) & (ma < 0.85) & (mb < 0.85)
    change = np.abs(ma - mb) / np.maximum(ma + mb, 1e-3)
    cells = []
    for mask in (lit & (change > 0.1), lit & (change < 0.01)):
        if mask.sum() < 500:
            cells += [f"{mask.sum()}", "—", "—"]
        else:
            cells += [f"{mask.sum()}", f"{np.corrcoef(da[mask], db[mask])[0, 1]:+.2f}", f"{da[mask].std():.3f}"]
    return " | ".join(cells)


def main(shared: Path) -> None:
    print("| capture | moving pixels | their correlation | spread | still pixels | their correlation | spread |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    real = [shared / "real" / "car.dat", *sorted((shared / "spikezoo-base").glob("*.dat"))]
    for path in real:
        if path.is_file():
            print(f"| {path.stem} | {halves(DatReader(path, DatGeometry(400, 250)).read())} |", flush=True)
    simulated = load_development() + load_development(reset="subtract")
    done = set()
    for seq in simulated:
        pixel = "subtract" if "subtract" in (seq.description or "") else "zero"
        if (seq.name, pixel) in done:  # spikezoo's kind comes with one pixel only
            continue
        done.add((seq.name, pixel))
        planes = np.concatenate([c.planes for c in seq.raw_chunks(128)])
        print(f"| {seq.name} ({pixel}) | {halves(planes)} |", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("../shared/data"))
