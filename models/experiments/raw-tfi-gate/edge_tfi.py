"""Development video clips (never the held-out ones): the middle frame made mid-clip and as a cut clip's first frame:
binned and gated mu-law PSNR, the gate's mean TFI share, and each TFI candidate's PSNR (read as light, 2x2-averaged)
against the truth. Run from the repository root: python models/experiments/raw-tfi-gate/edge_tfi.py
"""

import sys

import numpy as np
import torch

sys.path.insert(0, "models/experiments/raw-tfi-gate")
from gate import apply_gate
from rmbvideo.evaluate.harness import sequence_convention
from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.video_checks import clip_frames
from rmbvideo.net.weights import default_model_path, default_raw_gate_path, load_raw_gate
from rmbvideo.train.raw_gate import gate_frames

torch.set_num_threads(1)
gate = load_raw_gate(default_raw_gate_path())[0]
for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
    code = float(sequence_convention(seq) != "physical")
    frames = gate_frames(seq, default_model_path("binned"), gate.config)
    mid = len(frames) // 2
    cut = gate_frames(clip_frames(seq, mid, len(frames)), default_model_path("binned"), gate.config)
    row = [seq.name]
    for label, fr, k in (("mid", frames, mid), ("first", cut, 0)):
        mixed, shares = apply_gate(gate, fr, code)
        f = fr[k]
        cells = [f"{mu_law_psnr(c, f.truth):.2f}" for c in f.candidates]
        row.append(f"{label}: binned {mu_law_psnr(f.binned, f.truth):.2f} gated {mu_law_psnr(mixed[k], f.truth):.2f} "
                   f"share {float(np.mean(shares[k])):.3f} TFI {' / '.join(cells)}")
    print(" | ".join(row), flush=True)
