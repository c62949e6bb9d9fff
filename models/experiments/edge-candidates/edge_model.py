"""An edge model of its own, on the development video clips only: a clip's first and last w frames made by EDGE (a
model trained on the edge frames alone, ``optim.edge_only``), every other frame by the shipped model, as an engine
with a second model for the edges would make them. Prints, per clip, the edge check (``edge_report``'s figures) of
the shipped model alone and of that composite; the composite's mid-clip frames are the shipped model's, so its
median and its edge costs' mid-clip side are the shipped model's too. Run from the repository root (about two minutes
a model, one core):

    python models/experiments/edge-candidates/edge_model.py EDGE.safetensors
"""

import sys

import numpy as np

from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.video_checks import (
    FRAME_STEP,
    best_time_offset_ms,
    clip_frames,
    run_rmb,
    video_scene_of,
)
from rmbvideo.net.weights import default_model_path, load_model


def edge_figures(seq, shipped: str, edge: str, w: int) -> list[float]:
    """First / last frame below the clip's median (dB), their time offsets (ms) and the edge costs as a first and as a
    last frame (dB) of the clip made by ``shipped`` with its first and last ``w`` frames made by ``edge``."""
    options = {"threads": 1, "input_mode": "binned", "precision": "fp32"}
    count, mid = len(seq.gt), len(seq.gt) // 2
    whole = run_rmb("rmbnet", {**options, "model": shipped}, seq)
    edges = run_rmb("rmbnet", {**options, "model": edge}, seq)
    frames = {i: edges[i] if i < w or i >= count - w else whole[i] for i in range(count)}
    psnr = [mu_law_psnr(frames[i], np.minimum(seq.gt[i], 1.0)) for i in range(count)]
    median = float(np.median(psnr))
    scene = video_scene_of(seq)
    first = best_time_offset_ms(frames[0], scene, FRAME_STEP)
    last = best_time_offset_ms(frames[count - 1], scene, 2 * FRAME_STEP * (count - 1) + FRAME_STEP)
    truth = np.minimum(seq.gt[mid], 1.0)
    as_first = run_rmb("rmbnet", {**options, "model": edge}, clip_frames(seq, mid, count))[0]
    as_last = run_rmb("rmbnet", {**options, "model": edge}, clip_frames(seq, 0, mid + 1))[mid]
    return [median - psnr[0], median - psnr[-1], first, last,
            psnr[mid] - mu_law_psnr(as_first, truth), psnr[mid] - mu_law_psnr(as_last, truth)]


def main(edge: str) -> None:
    shipped = str(default_model_path())
    w = load_model(shipped)[0].config.w
    print("| clip | edge frames by | first below median (dB) | last below median | first offset (ms) | last offset "
          "| edge cost, first (dB) | edge cost, last |")
    print("|---|---|" + "---:|" * 6)
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        for label, path in (("shipped", shipped), ("edge model", edge)):
            values = edge_figures(seq, shipped, path, w)
            print(f"| {seq.name} | {label} | " + " | ".join(f"{v:+.2f}" for v in values) + " |", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
