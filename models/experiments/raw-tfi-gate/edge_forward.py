"""TFI at a capture's first frame from the first whole intervals after the data's start (development clips only).

At a cut clip's first frame a pixel that has not fired since the data began reads TFI's cut interval: from the plane
before the data to its next spike, an upper bound on its rate (for a reset-to-zero pixel of unknown phase at the
start, about twice the rate on average). The whole intervals after its first spike in the data are unbiased evidence on
the frame's own side. Here such a pixel reads ``k / (t_last - t_first)``: its spikes from the first in the data through
TFI's ``next`` (through the spike after it when that is the only one), as a ``Tfi`` would if it knew the data's start
cut the interval. Everything else is unchanged, the gate (shipped, no refit) included.

Printed per development video clip: the edge's own cost as ``evaluate``'s checks measure it (the middle frame made
mid-clip against the same frame made as a cut clip's first): binned, the shipped gate, the gate with the one-sided TFI,
and TFI-4 alone both ways. Run from the repository root: python models/experiments/raw-tfi-gate/edge_forward.py
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from rmbvideo.evaluate.harness import downsample_2x, rate_as_light, sequence_convention
from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.video_checks import clip_frames
from rmbvideo.net.weights import default_model_path, default_raw_gate_path, load_raw_gate
from rmbvideo.train.raw_gate import gate_frames

STEP = 20  # raw planes a frame


def raw_planes(seq) -> np.ndarray:
    return np.concatenate([c.planes for c in seq.raw_chunks(256)])


def tfi_rates(planes: np.ndarray, frame: int, window: int, reach: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(TFI's rate, the one-sided rate, where it applies) per raw pixel at ``frame``: TFI as ``Tfi`` reads it (cut
    intervals bounded by the data's edge), and for pixels with no spike at or before TFI's reference plane (the
    data's start cuts their interval) the rate over their whole intervals from the first spike through TFI's next
    spike (or the one after it when that is the only one), within the search."""
    p = ((2 * frame + 1) * STEP - window + 1) // 2 - 1
    hi = min(p + window + reach, len(planes) - 1)
    before = planes[: p + 1] if p >= 0 else planes[:0]
    seen = before.any(axis=0)
    last_before = np.where(seen, len(before) - 1 - np.argmax(before[::-1], axis=0), -1) if len(before) else \
        np.full(planes.shape[1:], -1)
    after = planes[p + 1: hi + 1].astype(np.int64)  # planes p+1 .. hi
    cum = after.cumsum(axis=0)
    central = cum[window - 1] if window else np.zeros(planes.shape[1:], np.int64)
    has_next = cum[-1] >= central + 1
    t_next = p + 1 + np.argmax(cum >= (central + 1)[None], axis=0)
    nxt = np.where(has_next, t_next, hi + 1)
    tfi = ((central + 1) / np.maximum(nxt - last_before, 1)).astype(np.float32)
    k_last = np.maximum(central + 1, 2)  # spikes from the first through the last taken
    has = cum[-1] >= k_last
    t_first = p + 1 + np.argmax(cum >= 1, axis=0)
    t_last = p + 1 + np.argmax(cum >= k_last[None], axis=0)
    cut = ~seen & has
    one = np.where(cut, (k_last - 1) / np.maximum(t_last - t_first, 1), tfi).astype(np.float32)
    return tfi, one, cut


def light(rate: np.ndarray, convention: str, shape) -> np.ndarray:
    return downsample_2x(rate_as_light("tfi", rate, convention), shape)


@torch.no_grad()
def gated(gate, binned, tfi, longs, previous, code) -> np.ndarray:
    t = lambda x: torch.from_numpy(np.ascontiguousarray(x, np.float32))[None, None]  # noqa: E731
    return gate(t(binned), t(tfi), t(previous), code, *(t(x) for x in longs))[0, 0].numpy()


def main() -> None:
    torch.set_num_threads(1)
    gate = load_raw_gate(default_raw_gate_path())[0]
    model = default_model_path("binned")
    windows = (gate.config.tfi_window, gate.config.long_window)[: gate.config.candidates]
    print("| clip | pixels one-sided (TFI-4 / TFI-16) | edge cost as first: binned | shipped gate | one-sided gate "
          "| TFI-4: mid-clip | as first | one-sided |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        convention = sequence_convention(seq)
        code = float(convention != "physical")
        frames = gate_frames(seq, model, gate.config)
        count, mid = len(frames), len(frames) // 2
        truth = frames[mid].truth
        clip = clip_frames(seq, mid, count)
        cut = gate_frames(clip, model, gate.config)
        planes = raw_planes(clip)
        whole = gated(gate, frames[mid].binned, frames[mid].tfi, frames[mid].candidates[1:], frames[mid - 1].binned,
                      code)
        first = cut[0]
        shipped = gated(gate, first.binned, first.tfi, first.candidates[1:], first.binned, code)
        fixed, fractions = [], []
        for window, image in zip(windows, first.candidates):
            tfi, one, where = tfi_rates(planes, 0, window, gate.config.tfi_reach)
            fractions.append(where.mean())
            mine = light(tfi, convention, seq.shape)
            assert np.allclose(mine, image, rtol=1e-4, atol=1e-6), np.abs(mine - image).max()
            fixed.append(light(one, convention, seq.shape))
        one_sided = gated(gate, first.binned, fixed[0], fixed[1:], first.binned, code)
        score = lambda x: mu_law_psnr(x, truth)  # noqa: E731
        print(f"| {seq.name} | {' / '.join(f'{f:.2f}' for f in fractions)} | "
              f"{score(frames[mid].binned) - score(first.binned):.2f} | {score(whole) - score(shipped):.2f} | "
              f"{score(whole) - score(one_sided):.2f} | {score(frames[mid].tfi):.2f} | {score(first.tfi):.2f} | "
              f"{score(fixed[0]):.2f} |", flush=True)


if __name__ == "__main__":
    main()
