"""Development video clips (never the held-out ones): the middle frame made mid-clip and as a cut clip's first frame:
binned and gated mu-law PSNR, the gate's mean TFI share, and each TFI candidate's PSNR (read as light, 2x2-averaged)
against the truth; with ``picture``, the middle frames of two clips both ways, side by side, as a PNG.
Run from the repository root: python models/experiments/raw-tfi-gate/edge_tfi.py [picture [OUT.png]]
"""

import sys

import cv2
import numpy as np
import torch

sys.path.insert(0, "models/experiments/raw-tfi-gate")
from gate import apply_gate
from rmbvideo.evaluate.harness import sequence_convention
from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.video_checks import clip_frames
from rmbvideo.mulaw import mu_law
from rmbvideo.net.weights import default_model_path, default_raw_gate_path, load_raw_gate
from rmbvideo.train.raw_gate import gate_frames

PICTURE_CLIPS = ("dark-107", "low-contrast-407")


def label(image: np.ndarray, text: str) -> np.ndarray:
    out = image.copy()
    cv2.putText(out, text, (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, 255, 1, cv2.LINE_AA)
    return out


def main(picture: str | None = None) -> None:
    torch.set_num_threads(1)
    gate = load_raw_gate(default_raw_gate_path())[0]
    rows = []
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        code = float(sequence_convention(seq) != "physical")
        frames = gate_frames(seq, default_model_path("binned"), gate.config)
        mid = len(frames) // 2
        cut = gate_frames(clip_frames(seq, mid, len(frames)), default_model_path("binned"), gate.config)
        row = [seq.name]
        for name, fr, k in (("mid", frames, mid), ("first", cut, 0)):
            mixed, shares = apply_gate(gate, fr, code)
            f = fr[k]
            cells = [f"{mu_law_psnr(c, f.truth):.2f}" for c in f.candidates]
            row.append(f"{name}: binned {mu_law_psnr(f.binned, f.truth):.2f} gated {mu_law_psnr(mixed[k], f.truth):.2f} "
                       f"share {float(np.mean(shares[k])):.3f} TFI {' / '.join(cells)}")
            if picture and seq.name in PICTURE_CLIPS:
                tiles = [(f"{seq.name} {name}: truth", mu_law(np.clip(f.truth, 0, 1))),
                         ("binned", mu_law(np.clip(f.binned, 0, 1))), ("gated", mu_law(np.clip(mixed[k], 0, 1))),
                         ("TFI-16", mu_law(np.clip(f.candidates[-1], 0, 1))), ("TFI share (linear)", shares[k])]
                rows.append(np.hstack([label((255 * np.clip(image, 0, 1)).astype(np.uint8), text)
                                       for text, image in tiles]))
        print(" | ".join(row), flush=True)
    if picture:
        cv2.imwrite(picture, np.vstack(rows))


if __name__ == "__main__":
    main(sys.argv[2] if len(sys.argv) > 2 else "models/figures/raw-gate-edge.png" if sys.argv[1:2] == ["picture"]
         else None)
