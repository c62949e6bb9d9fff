"""What the edge model changes besides the edge checks, the shipped model with ``--edges off`` against ``auto``: the
dark-end check (``dark_bias``: the relative bias and the spatial spread of a flat field's last frame, an edge frame)
and the held-out video sequences' scores as ``evaluate`` takes them (``evaluate_rows``: no scored frame is an edge
frame, so they should not move). Run from the repository root (about three minutes, one core):

    python models/experiments/edge-candidates/edge_side_effects.py
"""

import torch

from rmbvideo.evaluate.harness import MethodSpec, evaluate_rows
from rmbvideo.evaluate.heldout import load_video_heldout
from rmbvideo.evaluate.video_checks import dark_bias
from rmbvideo.net.weights import default_model_path


def main() -> None:
    torch.set_num_threads(1)
    model = str(default_model_path())
    options = {"model": model, "threads": 1, "precision": "fp32"}
    print("| level | bias, edges off | bias, auto | spread (CV), edges off | spread, auto |")
    print("|---:|---:|---:|---:|---:|")
    off, auto = (dark_bias("rmbnet", {**options, "edges": edges}) for edges in ("off", "auto"))
    for level in off:
        print(f"| {level:g} | {100 * off[level][0]:+.1f} % | {100 * auto[level][0]:+.1f} % | {off[level][1]:.3f} "
              f"| {auto[level][1]:.3f} |")
    specs = [MethodSpec(f"edges {edges}", "rmbnet", {**options, "device": "cpu", "input_mode": "binned",
                                                     "edges": edges}, "pure-m") for edges in ("off", "auto")]
    for row in evaluate_rows(specs, load_video_heldout(False, None)):
        print(row.name, ", ".join(f"{name} {value:.2f}" for name, value in row.per_sequence.items()))


if __name__ == "__main__":
    main()
