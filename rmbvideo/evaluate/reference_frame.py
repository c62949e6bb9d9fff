"""Score reconstructions of a 1-bit capture against an 8-bit reference image of one of its planes.

For streams from other simulators (e.g. spikezoo's REDS streams), whose ground truth is an 8-bit PNG
of one plane in unknown units: each reconstruction is scaled by least squares onto the reference
(downsampled 2x by area for the binned methods) and scored by PSNR. Used by the tests and runnable:
``python -m rmbvideo.evaluate.reference_frame CAPTURE.dat REFERENCE.png --plane 150``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.recon.classical import Tfw
from rmbvideo.sensor.readout import RmbReadout

N = 10  # binned readouts per RMB-Net / TFW frame


def scaled_psnr(prediction: np.ndarray, reference: np.ndarray) -> float:
    """PSNR (peak 1) of ``prediction`` scaled by least squares onto ``reference`` (both linear)."""
    pred = prediction.astype(np.float64)
    scale = float((pred * reference).sum() / max(float((pred * pred).sum()), 1e-12))
    mse = float(((scale * pred - reference) ** 2).mean())
    return 10.0 * np.log10(1.0 / max(mse, 1e-12))


def score_reference_frame(capture: Path, reference_png: Path, plane: int,
                          model: Path | None = None) -> dict[str, float]:
    """Linear PSNR of RMB-Net (shipped binned model unless ``model``) and TFW-L (the same 70
    readouts of evidence) at the binned frame containing raw ``plane``, against the reference PNG."""
    from rmbvideo.recon.rmbnet import make_rmbnet

    reader = DatReader(Path(capture), DatGeometry(400, 250))
    reference = cv2.imread(str(reference_png), cv2.IMREAD_GRAYSCALE)
    if reference is None:
        raise FileNotFoundError(reference_png)
    height, width = reader.shape[0] // 2, reader.shape[1] // 2
    reference = cv2.resize(reference.astype(np.float64) / 255.0, (width, height), interpolation=cv2.INTER_AREA)
    index = plane // 2 // N
    scores = {}
    for name, method in (("rmbnet", make_rmbnet(model, device="cpu", threads=1)), ("tfw-l", Tfw(window=70))):
        chunk = RmbReadout().apply(reader.read_binned())
        frames = {f.index: f.image for f in method.push(chunk) + method.flush()}
        scores[name] = scaled_psnr(frames[index], reference)
    return scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("reference", type=Path)
    parser.add_argument("--plane", type=int, required=True, help="raw plane the reference shows")
    parser.add_argument("--model", type=Path, default=None)
    args = parser.parse_args()
    for name, value in score_reference_frame(args.capture, args.reference, args.plane, args.model).items():
        print(f"{name:8s} {value:6.2f} dB")


if __name__ == "__main__":
    main()
