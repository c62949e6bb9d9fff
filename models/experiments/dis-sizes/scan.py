"""Which image sizes OpenCV's DIS optical flow refuses or crashes on (``rmbvideo.recon.flow.DIS_MIN_SIZE``).

    python models/experiments/dis-sizes/scan.py           # heights 8-40 x widths 8-80, then 32-128 x up to 4000

Each shape runs in a forked child (a crash is a segmentation fault that would end this process), on two different
random 8-bit images, with every preset and the aligned means' settings (``AlignedBoxConfig``); prints, per setting,
the shapes refused (cv2.error) and those that crashed, as height ranges with the first crashing width.
"""

from __future__ import annotations

import os
import sys
from collections import defaultdict

import cv2
import numpy as np

from rmbvideo.recon.aligned_box import DIS_PRESETS, AlignedBoxConfig


def make(setting: str) -> cv2.DISOpticalFlow:
    if setting != "aligned means":
        return cv2.DISOpticalFlow_create(DIS_PRESETS[setting])
    config = AlignedBoxConfig()
    dis = cv2.DISOpticalFlow_create(DIS_PRESETS[config.preset])
    dis.setGradientDescentIterations(config.descent_iterations)
    dis.setVariationalRefinementIterations(config.refinement_iterations)
    dis.setPatchStride(config.patch_stride)
    return dis


def outcome(height: int, width: int, setting: str) -> str:
    pid = os.fork()
    if pid == 0:
        rng = np.random.default_rng(height * 10_000 + width)
        a, b = (rng.integers(0, 256, (height, width), dtype=np.uint8) for _ in range(2))
        try:
            make(setting).calc(a, b, None)
        except cv2.error:
            os._exit(3)
        os._exit(0)
    _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status):
        return "crash"
    return "refused" if os.WEXITSTATUS(status) == 3 else "ok"


def main() -> None:
    shapes = [(h, w) for h in range(8, 41) for w in range(8, 81)]
    shapes += [(h, w) for h in (32, 33, 40, 48, 64, 65, 96, 128) for w in (32, 100, 160, 200, 400, 1000, 2000, 4000)]
    for setting in (*DIS_PRESETS, "aligned means"):
        crashed, refused = defaultdict(list), 0
        for h, w in shapes:
            result = outcome(h, w, setting)
            refused += result == "refused"
            if result == "crash":
                crashed[h].append(w)
        rows = ", ".join(f"{h}: from {min(ws)}" for h, ws in sorted(crashed.items()))
        print(f"{setting}: {refused} shapes refused; crashed (height: first crashing width) {rows or 'none'}",
              flush=True)


if __name__ == "__main__":
    sys.exit(main())
