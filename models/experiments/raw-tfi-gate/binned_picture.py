"""``--resolution binned`` on the real-video streams: RMB-Net's frames alone (``--raw-gate off``), the gated frames
(the default since the third stop of 2026-11-29) and their difference x10, at a clip's first, middle and last frame.
Both share one display scale per frame (the ungated frame's 99.5th percentile, gamma 2.2). Writes
models/figures/binned-gate.png. Run from the repository root with ../shared present:

    python models/experiments/raw-tfi-gate/binned_picture.py
"""

from pathlib import Path

import numpy as np

from rmbvideo.io.png import write_png
from rmbvideo.recon.run import reconstruct_frames

STREAMS = Path("../shared/data/spikezoo-base")
rows = []
for name in ("203_part2", "200_part3"):  # people walking past a still camera; a slow pan over rocks
    path = STREAMS / f"{name}_key_id151.dat"
    options = dict(width=400, height=250, threads=1, resolution="binned")
    gated = list(reconstruct_frames(path, **options))
    plain = list(reconstruct_frames(path, raw_gate="off", **options))
    for k in (0, len(gated) // 2, len(gated) - 1):
        scale = max(float(np.percentile(plain[k].image, 99.5)), 1e-6)
        shown = [np.clip(plain[k].image / scale, 0, 1) ** (1 / 2.2), np.clip(gated[k].image / scale, 0, 1) ** (1 / 2.2),
                 np.clip(10 * np.abs(gated[k].image - plain[k].image) / scale, 0, 1)]
        rows.append(np.hstack([(255 * s).astype(np.uint8) for s in shown]))
        change = np.mean(np.abs(gated[k].image - plain[k].image)) / plain[k].image.mean()
        print(f"{name} frame {k}: mean change {100 * change:.1f} % of the mean level")
picture = np.repeat(np.repeat(np.vstack(rows), 2, axis=0), 2, axis=1)
write_png(Path("models/figures/binned-gate.png"), picture)
print("wrote models/figures/binned-gate.png")
