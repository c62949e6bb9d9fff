"""The benchmark's configurations: every baseline of paper Table 2 and the RMB-Net speed knobs.

RMB-Net knobs (window half-width w, alignment, width multiplier, precision, device) are varied one
at a time around the shipped default model (w = 3, no alignment, width 0.5, the default precision "auto",
named with what it resolves to on this machine) unless the full grid is asked for, which multiplies them
out (4 x 3 x 2 x 2 = 48 runs per device, fp32 and bf16).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import torch

from rmbvideo.evaluate.harness import BASELINE_SPECS, RAW_SPECS
from rmbvideo.recon.precision import uses_bf16

#: name -> (method, options): the RMB-input baselines of ``rmbvideo evaluate`` (paper Table 2) and
#: the classical methods on the raw capture that ``reconstruct`` runs at full resolution (scored
#: after 2x2 averaging). TFI on the RMB 1-bit plane is an evaluation-only input and is left out.
BASELINES: dict[str, tuple[str, dict[str, Any]]] = {
    spec.name: (spec.method, spec.options) for spec in (*BASELINE_SPECS, *RAW_SPECS) if spec.name != "TFI"}
W_VALUES = (0, 1, 2, 3)
ALIGNMENTS = ("none", "dis", "tvl1")
WIDTHS = (0.5, 1.0)
DEFAULT_WIDTH = 0.5  # the shipped models' width
PRECISIONS = ("fp32", "bf16")


@dataclass(frozen=True)
class BenchConfig:
    """One row of the benchmark: a baseline (``method`` + ``options``) or an RMB-Net setting."""

    name: str
    method: str
    options: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    w: int | None = None
    align: str | None = None
    width: float | None = None
    precision: str | None = None
    device: str = "cpu"
    resolution: str = "binned"  # "full": the default of reconstruct, binned network + the raw stream's detail
    threads: int | None = None  # None: the run's thread count (the policy's or --threads)

    @property
    def is_rmbnet(self) -> bool:
        """Whether this row runs the network (and so has network-alone timing)."""
        return self.method == "rmbnet"


def precision_label(precision: str, device: str) -> str:
    """``precision`` as a row shows it: "auto" with what it resolves to on ``device`` here, e.g. "auto=bf16"."""
    if precision != "auto":
        return precision
    return "auto=" + ("bf16" if uses_bf16("auto", torch.device(device)) else "fp32")


def rmbnet_config(w: int = 3, align: str = "none", width: float = DEFAULT_WIDTH, precision: str = "auto",
                  device: str = "cpu", resolution: str = "binned", threads: int | None = None) -> BenchConfig:
    """An RMB-Net row named after its knobs, e.g. ``RMB-Net w3 none x1 auto=bf16 cpu`` (`` full res`` added
    for the camera's resolution: the binned network plus the learned detail stage, scored 2x2-averaged;
    `` N threads`` where the row sets its own thread count)."""
    name = f"RMB-Net w{w} {align} x{width:g} {precision_label(precision, device)} {device}"
    name += " full res" if resolution == "full" else ""
    name += f" {threads} threads" if threads is not None else ""
    return BenchConfig(name=name, method="rmbnet", w=w, align=align, width=width, precision=precision,
                       device=device, resolution=resolution, threads=threads)


def default_configs(devices: tuple[str, ...] = ("cpu",), full_grid: bool = False,
                    baselines: bool = True, alignments: tuple[str, ...] = ALIGNMENTS,
                    beside: bool = False) -> list[BenchConfig]:
    """Baselines (on CPU, where they run) then RMB-Net rows for each device.

    One-at-a-time: the default model plus each other value of each knob; ``full_grid``: every
    combination. ``alignments`` restricts the alignment knob (TV-L1 takes seconds per flow field).
    ``beside``: whether the run's rows compute a model's aligned window means in a thread beside the
    network; the CPU's default row is also run the other way (1 thread: inline; 2: beside).
    """
    rows = [BenchConfig(name=name, method=method, options=dict(options))
            for name, (method, options) in BASELINES.items()] if baselines else []
    for device in devices:
        default = rmbnet_config(device=device)
        if full_grid:
            combos = itertools.product(W_VALUES, alignments, WIDTHS, PRECISIONS)
            rows += [rmbnet_config(w, a, wd, p, device) for w, a, wd, p in combos]
            continue
        rows.append(default)
        if device == "cpu":  # what reconstruct writes by default; its detail stage runs on the CPU
            rows.append(rmbnet_config(device=device, resolution="full"))
            rows.append(rmbnet_config(device=device, threads=1 if beside else 2))
        rows += [rmbnet_config(w, "none", DEFAULT_WIDTH, "auto", device) for w in W_VALUES if w != 3]
        rows += [rmbnet_config(3, a, DEFAULT_WIDTH, "auto", device) for a in alignments if a != "none"]
        rows += [rmbnet_config(3, "none", wd, "auto", device) for wd in WIDTHS if wd != DEFAULT_WIDTH]
        rows += [rmbnet_config(3, "none", DEFAULT_WIDTH, p, device) for p in PRECISIONS]
    return rows
