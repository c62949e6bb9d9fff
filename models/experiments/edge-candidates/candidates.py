"""Which blend candidate an edge frame loses, on the development video clips only (never the held-out ones), with the
shipped model and no retraining. For each clip's middle frame made three ways (mid-clip, as a cut clip's first frame,
as a cut clip's last: the same content and spikes, ``edge_report``'s edge cost), the mu-law PSNR of the blended output
and of every blend candidate (the network's own estimate and the box filters it blends), and the blend's mean weight
on each. Run from the repository root (a few minutes, one core):

    python models/experiments/edge-candidates/candidates.py
"""

import sys

import numpy as np
import torch

import rmbvideo.net.model as model_module
from rmbvideo.evaluate.harness import MethodSpec, run_frames
from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.video_checks import clip_frames

NAMES = ["own", "reference", "pool 3", "pool 7", "centre 2", "centre 4", "centre 6", "aligned"]
RECORD: list = []
_blend = model_module.blend


def blend(own, candidates, logits):
    weights = torch.softmax(logits.float(), 1)
    RECORD.append((torch.cat([own.float(), *(c.float() for c in candidates)], 1).numpy().copy(), weights.numpy().copy()))
    return _blend(own, candidates, logits)


model_module.blend = blend


def run(seq):
    RECORD.clear()
    spec = MethodSpec("default", "rmbnet", {"threads": 1, "input_mode": "binned", "precision": "fp32"}, "pure-m")
    frames, _, _ = run_frames(spec, seq)
    records = RECORD[len(RECORD) - len(frames):]
    order = sorted(f.index for f in frames)
    return {f.index: f.image for f in frames}, dict(zip(order, records))


def report(label, image, record, truth):
    cands, weights = record
    h, w = truth.shape
    cands, weights = cands[0, :, :h, :w], weights[0, :, :h, :w]
    scores = [mu_law_psnr(c, truth) for c in cands]
    print(f"| {label} | {mu_law_psnr(image, truth):.2f} | "
          + " | ".join(f"{s:.2f} ({100 * wt:.0f})" for s, wt in zip(scores, weights.mean(axis=(1, 2)))) + " |")


def main() -> None:
    print("| clip, middle frame made | output | " + " | ".join(f"{n} (weight %)" for n in NAMES) + " |")
    print("|---|" + "---:|" * (1 + len(NAMES)))
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        count = len(seq.gt)
        mid = count // 2
        truth = np.minimum(seq.gt[mid], 1.0)
        images, records = run(seq)
        report(f"{seq.name} mid-clip", images[mid], records[mid], truth)
        images, records = run(clip_frames(seq, mid, count))
        report(f"{seq.name} as first", images[0], records[0], truth)
        images, records = run(clip_frames(seq, 0, mid + 1))
        report(f"{seq.name} as last", images[mid], records[mid], truth)
        sys.stdout.flush()


if __name__ == "__main__":
    main()
