"""A candidate chosen on the development sets against the shipped model, on the held-out sets: run once per
candidate, never to choose. Run from the repository root (each a few minutes on one core):

    python models/experiments/blend-hedging/heldout_candidate.py rows CANDIDATE.safetensors [zero|subtract]
    python models/experiments/blend-hedging/heldout_candidate.py edges CANDIDATE.safetensors
    python models/experiments/blend-hedging/heldout_candidate.py edges edge-model

``rows``: the RMB-Net row of both models on the held-out synthetic and video sequences, as ``rmbvideo evaluate``
scores them (``evaluate_rows``; ``subtract``: the cameras' pixels reset by subtraction, ``evaluate --reset
subtract``); the baselines' rows do not depend on the model. ``edges``: the clip-edge check (``edge_report``, as
``evaluate`` writes it into checks.md), of both models as they make their edge frames themselves (``--edges off``);
with ``edge-model``, of the shipped model with ``--edges off`` and with its edge model (``rmbvideo.recon.clip_edges``).
"""

import sys
from pathlib import Path

from rmbvideo.evaluate.harness import MethodSpec, evaluate_rows
from rmbvideo.evaluate.heldout import load_heldout, load_video_heldout
from rmbvideo.evaluate.video_checks import edge_report
from rmbvideo.net.weights import default_model_path


def rows(candidate: str, reset: str = "zero") -> None:
    sequences = load_heldout(False, None, reset) + load_video_heldout(False, None, reset=reset)
    specs = [MethodSpec(str(model), "rmbnet", {"model": str(model), "device": "cpu", "input_mode": "binned",
                                               "threads": 1}, "pure-m")
             for model in (default_model_path(), Path(candidate))]
    for row in evaluate_rows(specs, sequences):
        print(f"{row.name} ({reset}): {row.status}, mu-law PSNR {row.psnr:.3f}, PU21 {row.pu21:.3f}")
        print("   " + ", ".join(f"{name} {value:.2f}" for name, value in row.per_sequence.items()), flush=True)


def edges(candidate: str) -> None:
    shipped = default_model_path()
    runs = ([("the model", shipped, "off"), ("its edge model", shipped, "auto")] if candidate == "edge-model"
            else [(str(shipped), shipped, "off"), (candidate, Path(candidate), "off")])
    print("| sequence | model | first: dB below median | last | first: offset ms | last | middle "
          "| edge cost as first frame (dB) | as last |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for seq in load_video_heldout(False):
        for label, model, edge_setting in runs:
            r = edge_report(seq, "rmbnet", {"model": model, "threads": 1, "edges": edge_setting})
            print(f"| {seq.name} | {label} | {r.first_drop_db:.2f} | {r.last_drop_db:.2f} | {r.first_offset_ms:+.2f} "
                  f"| {r.last_offset_ms:+.2f} | {r.middle_offset_ms:+.2f} | {r.first_edge_cost_db:.2f} "
                  f"| {r.last_edge_cost_db:.2f} |", flush=True)


if __name__ == "__main__":
    {"rows": rows, "edges": edges}[sys.argv[1]](*sys.argv[2:])
