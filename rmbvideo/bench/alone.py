"""A benchmark row run once in a process of its own, for its peak memory (``runner.peak_memory_alone``). It loads
what the row's method needs and no more, as ``reconstruct`` does: a classical row's process holds no torch (about
200 MB that a user's TFP run never maps), an RMB-Net row's the network and its model."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from rmbvideo.chunks import Frame
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import reconstruct_stream
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

CHUNK_PLANES = 1024


class KeepFrames:
    """A sink that keeps the frames whose times are in ``wanted`` (seconds, matched to 1 us)."""

    def __init__(self, wanted: dict[int, float]) -> None:
        self._wanted = {round(t * 1e6): i for i, t in wanted.items()}
        self.kept: dict[int, np.ndarray] = {}
        self.count = 0

    def write(self, frame: Frame) -> None:
        self.count += 1
        index = self._wanted.get(round(frame.time_s * 1e6))
        if index is not None:
            self.kept[index] = frame.image


def run_alone(spec: str) -> None:
    """Run one row once on one capture, as ``runner.run_config`` times it. ``spec``: JSON of the row's
    ``BenchConfig`` fields, the capture (path, width, height, rate), models folder, threads and, for a classical
    row, the readout design its binned input is read through (``runner.classical_readout_design``)."""
    from rmbvideo.allocator import keep_freed_memory

    keep_freed_memory()  # the allocator policy of every command
    job: dict[str, Any] = json.loads(spec)
    reader = DatReader(Path(job["dat"]), DatGeometry(width=job["width"], height=job["height"]), rate_hz=job["rate_hz"])
    fields = job["config"]
    if fields["method"] == "rmbnet":
        from rmbvideo.bench.configs import BenchConfig
        from rmbvideo.bench.runner import make_row_method, row_readout
        from rmbvideo.bench.models import build_network, find_model

        config = BenchConfig(**fields)
        models = Path(job["models"])
        network = build_network(config.w, config.width, find_model(config.w, config.width, models))
        recon = make_row_method(config, network, job["threads"])
        readout = row_readout(config, recon, models)
    else:
        recon = make_reconstructor(fields["method"], **fields["options"])
        readout = RmbReadout(mode=ReadoutMode(job["readout"])) if recon.input_kind == "rmb" else None
    reconstruct_stream(reader, recon, KeepFrames({}), chunk_planes=CHUNK_PLANES, readout=readout)
