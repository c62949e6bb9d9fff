"""How precisely one frame's time offset is measured, against the clip-edge offsets of the default model: the offset
(``video_checks.best_time_offset_ms``, 0.05 ms steps) of every frame of each video sequence, and of the middle frame
made as a clip's first and last frame (the stream cut there, content and spikes unchanged). Run from the repository
root (a few minutes on one core):

    python models/experiments/clip-edge-offsets/offsets.py heldout|development

Prints per sequence: the mid-clip frames' offsets (median, the spread between their 10th and 90th percentiles), the
first and last frames' offsets, and the middle frame's offset made mid-clip, as a first and as a last frame.
"""

import sys

import numpy as np
import torch

from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.video_checks import best_time_offset_ms, clip_frames, run_rmb, video_scene_of
from rmbvideo.evaluate.heldout import FRAME_STEP


def main(which: str) -> None:
    torch.set_num_threads(1)
    first = DEVELOPMENT_VIDEO_FIRST if which == "development" else 0
    print("| sequence | mid-clip frames: median offset ms | 10-90 % spread ms | first | last | middle mid-clip | "
          "middle as first | middle as last |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for seq in load_video_heldout(False, first=first):
        options = {"threads": 1}
        frames = run_rmb("rmbnet", options, seq)
        count, scene, mid = len(seq.gt), video_scene_of(seq), len(seq.gt) // 2
        centre = lambda i: 2 * FRAME_STEP * i + FRAME_STEP  # noqa: E731  raw plane at frame i's centre
        offsets = [best_time_offset_ms(frames[i], scene, centre(i)) for i in range(count)]
        inner = offsets[3:count - 3]
        as_first = run_rmb("rmbnet", options, clip_frames(seq, mid, count))[0]
        as_last = run_rmb("rmbnet", options, clip_frames(seq, 0, mid + 1))[mid]
        p10, p90 = np.percentile(inner, [10, 90])
        print(f"| {seq.name} | {np.median(inner):+.2f} | {p90 - p10:.2f} | {offsets[0]:+.2f} | {offsets[-1]:+.2f} | "
              f"{offsets[mid]:+.2f} | {best_time_offset_ms(as_first, scene, centre(mid)):+.2f} | "
              f"{best_time_offset_ms(as_last, scene, centre(mid)):+.2f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "heldout")
