"""The development measurements behind how RMB-Net reads a camera (README "Where the default stands"; this stop's
closing note), with the shipped model, on development seeds only. Run from the repository root:

    python models/experiments/camera-response/compare.py pans          # ~5 min on 2 cores
    python models/experiments/camera-response/compare.py conventions   # ~1 min once the sequences are cached
    python models/experiments/camera-response/compare.py heldout       # ~1 min: the held-out set, read once

``pans``: the 16 development panorama pans (evaluation seeds 50-65, never the held-out 0-5) scored with the box
candidates' closed-form inverse and with the emission model's tabulated response (``--response``), beside MG20.
``conventions``: the development sequences in the camera's convention, made with the paper's pixel (reset to zero)
and with a pixel reset by subtraction (``SensorParams.reset``, like car.dat's camera), each read by RMB-Net in
either convention (``--convention``): what a wrong reading costs either way. ``heldout``: the same two readings of
the held-out set made with the pixel reset by subtraction (``rmbvideo evaluate --reset subtract`` scores the default
reading with every other method); a figure to report, never to choose on.
"""

import sys
from dataclasses import replace

from rmbvideo.evaluate.harness import MethodSpec, run_frames, score_frames, sequence_convention
from rmbvideo.evaluate.heldout import (
    DEVELOPMENT_RANDOM_OFFSET,
    DEVELOPMENT_VIDEO_FIRST,
    FULL,
    load_heldout_config,
    load_video_heldout,
)


def score(spec: MethodSpec, seq) -> float:
    frames, _, _ = run_frames(spec, seq)
    images = {f.index: f.image for f in frames}
    return score_frames({i: images[i] for i in seq.scored_frames}, seq)[0]


def rmbnet(name: str, **options: str) -> MethodSpec:
    return MethodSpec(name, "rmbnet", {"threads": 1, "input_mode": "binned", **options}, "pure-m")


def table(rows: dict[str, list[float]], names: list[str]) -> None:
    print("| | " + " | ".join(names) + " | mean |")
    print("|---|" + "---:|" * (len(names) + 1))
    for label, values in rows.items():
        print(f"| {label} | " + " | ".join(f"{v:.2f}" for v in values) + f" | {sum(values) / len(values):.2f} |")


def pans() -> None:
    sequences = load_heldout_config(replace(FULL, count=16, first_seed_offset=DEVELOPMENT_RANDOM_OFFSET))
    specs = [rmbnet("closed form", response="closed-form"), rmbnet("emission model", response="emission-model"),
             MethodSpec("MG20", "mg20", {}, "pure-m")]
    table({s.name: [score(s, seq) for seq in sequences] for s in specs}, [seq.name for seq in sequences])


def readings(sequences: list) -> None:
    """RMB-Net reading the camera sequences among ``sequences`` in each convention."""
    sequences = [s for s in sequences if s.name.split("-")[0] != "spikezoo"]
    print(f"\nthe streams' convention: {sequence_convention(sequences[0])}")
    specs = [rmbnet("read as physical", convention="physical", response="closed-form"),
             rmbnet("read in the rate convention", convention="spikezoo")]
    table({s.name: [score(s, seq) for seq in sequences] for s in specs}, [seq.name for seq in sequences])


def conventions() -> None:
    for reset in ("zero", "subtract"):
        config = replace(FULL, count=2, first_seed_offset=DEVELOPMENT_RANDOM_OFFSET, reset=reset)
        readings(load_heldout_config(config) + load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST, reset=reset))


def heldout() -> None:
    readings(load_heldout_config(replace(FULL, reset="subtract")) + load_video_heldout(False, reset="subtract"))


if __name__ == "__main__":
    {"pans": pans, "conventions": conventions, "heldout": heldout}[sys.argv[1] if len(sys.argv) > 1 else "pans"]()
