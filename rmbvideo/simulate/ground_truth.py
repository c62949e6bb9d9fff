"""Exact ground truth of a simulated capture, written beside it.

Ground truth (``--gt DIR``): frame ``i`` is at ``t_i = (i*step + step/2) / rate`` (``step`` raw
readouts, default 20, centred like reconstruction frames), for every frame whose interval fits in
the capture. ``gt_NNNNNN.exr`` holds exposure * radiance / Q_r (expected photo-charge per raw
readout relative to the threshold, float32), ``flow_NNNNNN.npy`` the exact forward flow
(H, W, 2) float32 (dx, dy) in output pixels from ``t_i`` to ``t_{i+1}``, and ``index.csv`` lists
``index,time_s,file``.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import numpy as np

from rmbvideo.io.atomic import atomic_path, atomic_write_text, make_dir
from rmbvideo.io.exr import write_exr
from rmbvideo.scenes.render import ground_truth, ground_truth_flow
from rmbvideo.simulate.capture import CaptureSimulator


_GROUND_TRUTH_FILE = re.compile(r"gt_\d{6,}\.exr|flow_\d{6,}\.npy|index\.csv")


def is_ground_truth_file(name: str) -> bool:
    """Whether a file of this name is one ``write_ground_truth`` writes (an earlier run's, replaceable)."""
    return _GROUND_TRUTH_FILE.fullmatch(name) is not None


def write_ground_truth(simulator: CaptureSimulator, gt_dir: Path, step: int) -> int:
    """Write GT frames, flows and ``index.csv`` for ``simulator``'s capture; returns the frame count."""
    make_dir(gt_dir)
    rate = simulator.scene.rate_hz
    count = simulator.total_readouts // step
    table = io.StringIO()
    rows = csv.writer(table, lineterminator="\n")
    rows.writerow(["index", "time_s", "file"])
    for i in range(count):
        t = (i * step + step / 2) / rate
        name = f"gt_{i:06d}.exr"
        write_exr(gt_dir / name, ground_truth(simulator.renderer, t), time_s=t, dtype="float")
        with atomic_path(gt_dir / f"flow_{i:06d}.npy") as temp:
            with open(temp, "wb") as handle:
                np.save(handle, ground_truth_flow(simulator.renderer, t, t + step / rate))
        rows.writerow([i, repr(t), name])
    atomic_write_text(gt_dir / "index.csv", table.getvalue())
    return count
