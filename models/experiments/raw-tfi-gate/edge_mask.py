"""The gate at a clip's start with TFI's cut pixels left out (development clips only; the stop of 2026-11-29, fourth).

At a cut clip's first frames a pixel that has not fired since the data began has no spike before TFI's central planes:
its interval is cut by the data's start and reads an upper bound on its rate. The gate sees those pixels' TFI as it
sees any other, and their share of the frame's pixels lifts its frame features (the mean disagreement of TFI with
the binned frame), so it keeps the binned frame everywhere (share 0.01 against 0.34 mid-clip, ``edge_tfi.py``).
Here, per TFI candidate, a binned pixel is *cut* when one of its four raw pixels' first spike in the data comes after
that candidate's reference plane (``Tfi``'s ``p``) and the search reached the data's start. Variants:

- shipped: the gate as it is;
- masked: cut pixels' share set to 0, and the frame features averaged over the uncut pixels only;
- features: only the frame features over the uncut pixels;
- zeroed: only the cut pixels' share set to 0.

Printed per development video clip: the edge's own cost as ``evaluate``'s checks measure it (the middle frame made
mid-clip against the same frame made as a cut clip's first), binned and for each variant, and the first frame's
distance below the clip's median. Run from the repository root: python models/experiments/raw-tfi-gate/edge_mask.py
"""

from __future__ import annotations

import numpy as np
import torch

from rmbvideo.evaluate.harness import sequence_convention
from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.video_checks import clip_frames
from rmbvideo.net.raw_gate import FEATURES, gate_features
from rmbvideo.net.weights import default_model_path, default_raw_gate_path, load_raw_gate
from rmbvideo.train.raw_gate import gate_frames

VARIANTS = ("shipped", "masked", "features", "zeroed")
STEP = 20  # raw planes a frame


def first_spikes(seq) -> np.ndarray:
    """Each raw pixel's first spike plane in ``seq``'s raw capture (a plane past the end where it never fires)."""
    first = None
    for chunk in seq.raw_chunks(128):
        if first is None:
            first = np.full(chunk.planes.shape[1:], len(seq.raw_packed), np.int64)
        fired = chunk.planes.any(axis=0)
        at = chunk.start + chunk.planes.argmax(axis=0)
        first = np.where(fired & (first == len(seq.raw_packed)), at, first)
    return first


def cut_blocks(first: np.ndarray, frame: int, window: int, reach: int) -> np.ndarray:
    """(H/2, W/2) True where a raw pixel of the block has no spike at or before TFI's reference plane for ``frame``
    (``window`` central planes) and the search back from it reached the data's start."""
    centre2 = 2 * STEP * frame + STEP  # twice the frame's centre, as ``Tfi`` counts it
    p = (centre2 - window + 1) // 2 - 1
    cut = (first > p) & (p - reach + 1 <= 0)
    h, w = cut.shape
    return cut.reshape(h // 2, 2, w // 2, 2).any(axis=(1, 3))


@torch.no_grad()
def gated(gate, frame, previous, code: float, cuts: list[np.ndarray], variant: str) -> np.ndarray:
    t = lambda x: torch.from_numpy(np.ascontiguousarray(x, np.float32))[None, None]  # noqa: E731
    images = [t(frame.binned), t(frame.tfi), t(previous)]
    longs = [t(x) for x in frame.candidates[1:]]
    features = gate_features(*images, code, *longs, frame=gate.config.frame_features)
    uncut = [t(~c) for c in cuts]
    if variant in ("masked", "features") and gate.config.frame_features:
        n = len(FEATURES) + (3 if longs else 0)
        both = uncut[0] * (uncut[-1] if longs else 1)
        for k, (source, weight) in enumerate([(2, uncut[0]), (len(FEATURES) + 1, both)][: 1 + bool(longs)]):
            mean = (features[:, source:source + 1].abs() * weight).sum() / weight.sum().clamp(min=1.0)
            features[:, n + k] = torch.log(mean + 1e-3)
    share = gate.share(features)
    if variant in ("masked", "zeroed"):
        share = share * torch.cat(uncut, dim=1)
    candidates = torch.cat([images[1], *longs], dim=1)
    mixed = (1.0 - share.sum(1, keepdim=True)) * images[0] + (share * candidates).sum(1, keepdim=True)
    if variant == "shipped":  # the gate's own forward, reproduced
        assert torch.allclose(mixed, gate(*images, code, *longs), atol=1e-6)
    return mixed[0, 0].numpy()


def run(seq, gate, frames, variant: str) -> list[np.ndarray]:
    code = float(sequence_convention(seq) != "physical")
    windows = (gate.config.tfi_window, gate.config.long_window)[: gate.config.candidates]
    first = first_spikes(seq)
    out, previous = [], frames[0].binned
    for i, frame in enumerate(frames):
        cuts = [cut_blocks(first, i, w, gate.config.tfi_reach) for w in windows]
        out.append(gated(gate, frame, previous, code, cuts, variant))
        previous = frame.binned
    return out


def main() -> None:
    torch.set_num_threads(1)
    gate = load_raw_gate(default_raw_gate_path())[0]
    model = default_model_path("binned")
    print("| clip | cut blocks at the cut first frame (TFI-4 / TFI-16) | edge cost as first: binned | "
          + " | ".join(VARIANTS) + " | first below median: " + " | ".join(VARIANTS) + " |")
    print("|---|---:|---:|" + "---:|" * (2 * len(VARIANTS)))
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        frames = gate_frames(seq, model, gate.config)
        count, mid = len(frames), len(frames) // 2
        truth = frames[mid].truth
        clip = clip_frames(seq, mid, count)
        cut = gate_frames(clip, model, gate.config)
        windows = (gate.config.tfi_window, gate.config.long_window)[: gate.config.candidates]
        fraction = [cut_blocks(first_spikes(clip), 0, w, gate.config.tfi_reach).mean() for w in windows]
        whole_shipped = run(seq, gate, frames, "shipped")[mid]
        costs, below = [], []
        for variant in VARIANTS:
            whole = run(seq, gate, frames, variant)
            as_first = run(clip, gate, cut, variant)[0]
            costs.append(mu_law_psnr(whole[mid], truth) - mu_law_psnr(as_first, truth))
            scores = [mu_law_psnr(image, f.truth) for image, f in zip(whole, frames)]
            below.append(float(np.median(scores)) - scores[0])
        assert np.array_equal(whole_shipped, run(seq, gate, frames, "masked")[mid])  # mid-clip: nothing cut
        binned = mu_law_psnr(frames[mid].binned, truth) - mu_law_psnr(cut[0].binned, truth)
        print(f"| {seq.name} | {' / '.join(f'{f:.2f}' for f in fraction)} | {binned:.2f} | "
              + " | ".join(f"{c:.2f}" for c in costs) + " | " + " | ".join(f"{b:.2f}" for b in below) + " |",
              flush=True)


if __name__ == "__main__":
    main()
