"""Where the raw gate takes TFI, should the detail inside each 2x2 block come from TFI too? At full resolution the
default job shapes the gated binned frame G with the learned detail stage (output D, whose 2x2 block means are G).
The variant gives each TFI candidate's own intra-block detail its share s_k of every block:

    add: full = (1 - sum s_k) D + sum s_k (T_k - block_mean(T_k) + G)
    mul: full = (1 - sum s_k) D + sum s_k G T_k / block_mean(T_k)

(T_k: the candidate's light per raw pixel; the shares are constant in a block, so the 2x2 means stay G; ``short``:
TFI-4's detail alone, in the share of both candidates, as TFI-16 smears what moves). Scored as
``rmbvideo evaluate --full-resolution`` scores its learned row, on the held-out synthetic sequences and the
real-video streams. Run from the repository root, one thread (about 10 minutes):

    python models/experiments/tfi-detail/tfi_detail.py ../shared/data/spikezoo-base add|mul [short]
"""

import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

import rmbvideo.recon.full_resolution as fr
from rmbvideo.evaluate.full_resolution import FULL_LEARNED, FullScores, full_rows, score_sequences, score_streams
from rmbvideo.evaluate.heldout import load_heldout, load_video_heldout
from rmbvideo.evaluate.real_video import find_streams
from rmbvideo.net.raw_gate import gate_features, tfi_light

_plain_gated, _plain_learned = fr.FullResolution._gated, fr.FullResolution._learned


def _gated(self, coarse, tfis):  # noqa: ANN001, ANN202
    """The shipped gate's frames, keeping each frame's shares and its candidates' full-resolution light."""
    convention, tabulated = self._reading
    previous = self._previous
    out = _plain_gated(self, coarse, tfis)
    stash = self.__dict__.setdefault("_stash", [])
    with torch.inference_mode():
        for image, candidates in zip(coarse, tfis):
            binned = torch.from_numpy(np.ascontiguousarray(image, np.float32))[None, None]
            prev = binned if previous is None else torch.from_numpy(previous)[None, None]
            full = [tfi_light(torch.as_tensor(t).float()[None, None], convention, tabulated) for t in candidates]
            light = [F.avg_pool2d(x, 2) for x in full]
            clean = [torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0).clamp(min=0.0)
                     for x in (binned, light[0], prev, *light[1:])]
            share = self.raw_gate.share(gate_features(*clean[:3], convention, *clean[3:],
                                                      frame=self.raw_gate.config.frame_features))
            stash.append((share[0].numpy(), [x[0, 0].numpy() for x in full], [x[0, 0].numpy() for x in light]))
            previous = np.ascontiguousarray(image, np.float32)
    return out


def _learned(self, coarse, rates):  # noqa: ANN001, ANN202
    images = _plain_learned(self, coarse, rates)
    if not MIX or self.raw_gate is None:
        return images
    out = []
    for gated, image in zip(coarse, images):
        shares, full, light = self._stash.pop(0)
        up = lambda x: np.repeat(np.repeat(x, 2, 0), 2, 1)  # noqa: E731
        h, w = image.shape
        mixed = (1.0 - up(shares.sum(0)))[:h, :w] * image
        pairs = [(shares.sum(0), full[0], light[0])] if SHORT else zip(shares, full, light)
        for s, t, tb in pairs:
            if MODE == "add":
                mixed += up(s)[:h, :w] * (t - up(tb) + up(gated))[:h, :w]
            else:
                mixed += up(s)[:h, :w] * (up(gated) * t / np.maximum(up(tb), 1e-6))[:h, :w]
        out.append(np.maximum(mixed, 0.0).astype(np.float32))
    return out


MIX, MODE, SHORT = True, "add", False
fr.FullResolution._gated, fr.FullResolution._learned = _gated, _learned


def main(streams: str, mode: str = "add", short: bool = False) -> None:
    global MIX, MODE, SHORT
    MODE, SHORT = mode, short
    torch.set_num_threads(1)
    row = [r for r in full_rows() if r.name in (FULL_LEARNED, "TFI-4")]  # a raw row: the table's best-raw column needs one
    sequences = load_heldout(False) + load_video_heldout(False)
    real = find_streams(Path(streams))
    results = {}
    for mix in (False, True):
        MIX = mix
        scores = FullScores()
        score_sequences(sequences, row, scores)
        score_streams(real, row, scores)
        results[mix] = scores
    print("| sequence | learned detail (shipped) | TFI's own detail in its share | binned check: shipped / variant |")
    print("|---|---:|---:|---:|")
    for name in results[False].psnr:
        a, b = (results[m].psnr[name][FULL_LEARNED] for m in (False, True))
        check = [results[m].binned_check.get(name, {}).get(FULL_LEARNED) for m in (False, True)]
        cells = f"{check[0]:.2f} / {check[1]:.2f}" if check[0] is not None else "—"
        print(f"| {name} | {a:.2f} | {b:.2f} ({b - a:+.2f}) | {cells} |")
    for label, names in (("synthetic", [s.name for s in sequences]), ("real", [s.name for s in real])):
        a, b = (np.mean([results[m].psnr[n][FULL_LEARNED] for n in names]) for m in (False, True))
        print(f"| {label} mean | {a:.2f} | {b:.2f} ({b - a:+.2f}) | |")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], len(sys.argv) > 3 and sys.argv[3] == "short")
