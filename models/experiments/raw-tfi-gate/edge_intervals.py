"""TFI-M at a clip's first frame, where the data's start cuts the search before the frame: the shipped rule (the
range's bound stands in for a missing previous spike: an upper bound on the rate) against reading the intervals after
it (the central planes' first spike to the next one, or, with no central spike, the interval between the two spikes
after them). Development video clips only; the middle frame made as a cut clip's first frame, scored as the
evaluation scores raw TFI (read as light, 2x2-averaged), beside the same frame made mid-clip. No gate involved: this
says how much evidence an edge frame's TFI could have.
Run from the repository root: python models/experiments/raw-tfi-gate/edge_intervals.py
"""

import numpy as np
import torch

from rmbvideo.evaluate.harness import SATURATION, downsample_2x, rate_as_light, sequence_convention
from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.video_checks import clip_frames
from rmbvideo.net.weights import default_model_path, default_raw_gate_path, load_raw_gate
from rmbvideo.train.raw_gate import gate_frames

STEP, REACH = 20, 200


def first_index(spikes: np.ndarray, nth: int = 1) -> np.ndarray:
    """Per pixel, the plane offset of the ``nth`` spike along axis 0 (-1: fewer spikes)."""
    cumulative = np.cumsum(spikes, axis=0, dtype=np.int32)
    hit = cumulative >= nth
    return np.where(hit.any(axis=0), hit.argmax(axis=0), -1)


def tfi_first_frame(planes: np.ndarray, window: int, after: bool) -> np.ndarray:
    """Frame 0's TFI-M rate per raw pixel (the data starts at plane 0): ``Tfi``'s rule, or with ``after`` the
    intervals after the frame where no previous spike was found."""
    p = (STEP - window + 1) // 2 - 1  # Tfi._reference(0): the plane before the central planes
    lo, hi = 0, min(p + window + REACH, len(planes) - 1)
    before = planes[: p + 1][::-1]
    last = first_index(before)
    prev = np.where(last >= 0, p - last, lo - 1)
    central = planes[p + 1 : p + window + 1]
    count = central.sum(axis=0, dtype=np.int64)
    beyond = planes[p + window + 1 : hi + 1]
    first_after, second_after = first_index(beyond), first_index(beyond, 2)
    nxt = np.where(first_after >= 0, p + window + 1 + first_after, hi + 1)
    rate = (count + 1) / (nxt - prev)
    if not after:
        return rate
    missing = last < 0
    first_central = p + 1 + first_index(central)
    from_central = missing & (count >= 1)
    rate = np.where(from_central, count / np.maximum(nxt - first_central, 1), rate)
    two_after = missing & (count == 0) & (second_after >= 0)
    return np.where(two_after, 1.0 / np.maximum(second_after - first_after, 1), rate)


def main() -> None:
    torch.set_num_threads(1)
    gate = load_raw_gate(default_raw_gate_path())[0]
    windows = (gate.config.tfi_window, gate.config.long_window)
    print("| clip | TFI-M | mid-clip | as first, shipped | as first, intervals after |")
    print("|---|---|---:|---:|---:|")
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        frames = gate_frames(seq, default_model_path("binned"), gate.config)
        mid = len(frames) // 2
        cut = clip_frames(seq, mid, len(frames))
        planes = np.concatenate([c.planes for c in cut.raw_chunks()])
        truth = np.minimum(cut.gt[0], SATURATION)
        convention = sequence_convention(seq)
        shipped = gate_frames(cut, default_model_path("binned"), gate.config)[0].candidates
        for k, window in enumerate(windows):
            light = [downsample_2x(rate_as_light("tfi", tfi_first_frame(planes, window, after).astype(np.float32),
                                                 convention), seq.shape) for after in (False, True)]
            assert np.allclose(light[0], shipped[k], rtol=1e-5, atol=1e-7), "the shipped rule, reproduced"
            print(f"| {seq.name} | {window} | {mu_law_psnr(frames[mid].candidates[k], frames[mid].truth):.2f} | "
                  f"{mu_law_psnr(light[0], truth):.2f} | {mu_law_psnr(light[1], truth):.2f} |", flush=True)


if __name__ == "__main__":
    main()
