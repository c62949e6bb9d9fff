"""Does the default's video shimmer? Frame-to-frame consistency against the truth's, on the development sequences.

A user watching the video sees what changes between frames: flicker and shimmer on still parts, or a gate that
switches its source from one frame to the next, cost little per-frame PSNR but show at once. The temporal error
here is ``rmbvideo.evaluate.metrics.temporal_mu_law_psnr``: the PSNR of the mu-law frame differences,
(T(o_i) - T(o_i-1)) against (T(g_i) - T(g_i-1)), both frames of a pair divided by one scale. Printed next to each
method's per-frame mu-law PSNR, for the development sequences the default was never scored on for its targets. Run from the repository root (a minute; ``--full``: the
default job at full resolution against the full-resolution truth, beside TFI-4 and TFI-16 there, a few minutes):

    python models/experiments/temporal-consistency/measure.py [--heldout] [--full]
    python models/experiments/temporal-consistency/measure.py picture OUT.png [SEQUENCE]

``picture``: x-t slices of a held-out sequence (fast-0 unless named): the row whose truth changes most over the clip,
one line per frame, time downwards, for the truth and each binned method; ghosting shows as a trail beside an edge's
path, flicker as streaks across it.
"""

import sys
import time
from dataclasses import replace

import numpy as np
import torch

from rmbvideo.evaluate.full_resolution import (FULL_LEARNED, NO_RAW_GATE, at_full_resolution, full_ground_truth,
                                               full_rows, run_row)
from rmbvideo.evaluate.harness import (GATED_ROW, RAW_SPECS, SATURATION, MethodSpec, baseline_specs, run_method,
                                       scored_truth, sequence_convention, temporal_score)
from rmbvideo.evaluate.heldout import load_development, load_heldout, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.net.weights import default_model_path, model_readout

def specs() -> list[MethodSpec]:
    model = default_model_path()
    readout = model_readout(model)
    rmbnet = MethodSpec("RMB-Net (RMB input)", "rmbnet", {"model": str(model), "input_mode": "binned", "threads": 1},
                        readout)
    baselines = {s.name: s for s in baseline_specs(readout)}
    raw = {s.name: s for s in RAW_SPECS}
    return [replace(rmbnet, name=GATED_ROW, gated=True), rmbnet, baselines["MG20"], baselines["TFW-L"],
            raw["TFI-4 (raw)"], raw["TFI-16 (raw)"], raw["TFP-80 (raw)"]]


#: the full-resolution rows measured with ``--full`` (``rmbvideo.evaluate.full_resolution.full_rows``)
FULL_ROWS = (FULL_LEARNED, NO_RAW_GATE, "TFI-4", "TFI-16")


def picture(out: str, name: str = "fast-0") -> None:
    """``picture`` (the module's docstring): x-t slices of ``name`` side by side, written to ``out``."""
    import cv2

    from rmbvideo.io.png import write_png

    seq = next(s for s in load_heldout(False) + load_video_heldout(False) if s.name == name)
    made = {spec.name: run_method(spec, seq).frames for spec in specs()[:5]}
    keys = sorted(next(iter(made.values())))
    truth = np.stack(list(scored_truth(seq, keys).values()))
    row = int(np.argmax(np.log1p(truth / truth.mean()).std(axis=0).mean(axis=1)))
    scale = float(np.percentile(truth, 99.9)) or 1.0
    tiles = []
    for label, video in [("truth", truth), *((k, np.stack([v[i] for i in keys])) for k, v in made.items())]:
        slice_ = np.clip(np.nan_to_num(video[:, row, :] / scale), 0.0, 1.0)
        tone = np.log1p(5000.0 * slice_) / np.log1p(5000.0)
        tile = cv2.resize((tone * 255).astype(np.uint8), (2 * tone.shape[1], 12 * tone.shape[0]),
                          interpolation=cv2.INTER_NEAREST)
        tile = np.vstack([np.zeros((18, tile.shape[1]), np.uint8), tile])
        cv2.putText(tile, label[:48], (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 255, 1, cv2.LINE_AA)
        tiles.append(np.hstack([tile, np.zeros((tile.shape[0], 6), np.uint8)]))
    write_png(out, np.vstack([np.hstack(tiles[:3]), np.hstack(tiles[3:] + [np.zeros_like(tiles[0])] * (6 - len(tiles)))]))
    print(f"{name}: row {row}, frames {keys[0]}-{keys[-1]} -> {out}")


def main() -> None:
    torch.set_num_threads(1)
    heldout = "--heldout" in sys.argv[1:]
    sequences = load_heldout(False) + load_video_heldout(False) if heldout else load_development()
    full = "--full" in sys.argv[1:]
    rows = [row for row in full_rows() if row.name in FULL_ROWS] if full else specs()
    spatial: dict[str, dict[str, float]] = {s.name: {} for s in rows}
    temporal: dict[str, dict[str, float]] = {s.name: {} for s in rows}
    began = time.perf_counter()
    for seq in sequences:
        full_truth = {i: np.minimum(gt, SATURATION) for i, gt in full_ground_truth(seq).items()} if full else None
        for spec in rows:
            if full_truth is None:
                frames = run_method(spec, seq).frames
                truth = scored_truth(seq, frames)
            else:
                made = run_row(spec, seq, convention=sequence_convention(seq))[0]
                truth = full_truth
                frames = {i: at_full_resolution(spec, made[i]) for i in truth}
            spatial[spec.name][seq.name] = float(np.mean([mu_law_psnr(frames[i], truth[i]) for i in truth]))
            temporal[spec.name][seq.name] = temporal_score(frames, truth)
        print(seq.name, " | ".join(f"{s.name}: {spatial[s.name][seq.name]:.2f} / {temporal[s.name][seq.name]:.2f}"
                                   for s in rows), flush=True)
    names = [seq.name for seq in sequences]
    print(f"\n{time.perf_counter() - began:.0f} s; each cell: per-frame mu-law PSNR / temporal PSNR (dB)\n")
    print("| method | " + " | ".join(names) + " | mean |\n|---|" + "---:|" * (len(names) + 1))
    for spec in rows:
        cells = [f"{spatial[spec.name][n]:.2f} / {temporal[spec.name][n]:.2f}" for n in names]
        mean = f"{np.mean(list(spatial[spec.name].values())):.2f} / {np.mean(list(temporal[spec.name].values())):.2f}"
        print(f"| {spec.name} | " + " | ".join(cells) + f" | {mean} |")


if __name__ == "__main__":
    if sys.argv[1:2] == ["picture"]:
        picture(*sys.argv[2:4])
    else:
        main()
