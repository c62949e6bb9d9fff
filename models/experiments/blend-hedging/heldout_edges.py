"""The held-out clip-edge check (``edge_report``, as ``rmbvideo evaluate`` writes it into checks.md) of the shipped
model and one candidate chosen on the development sets, side by side: run once per candidate, never to choose.
Run from the repository root (about 3 minutes on one core):

    python models/experiments/blend-hedging/heldout_edges.py CANDIDATE.safetensors
"""

import sys
from pathlib import Path

from rmbvideo.evaluate.heldout import load_video_heldout
from rmbvideo.evaluate.video_checks import edge_report
from rmbvideo.net.weights import default_model_path


def main(candidate: str) -> None:
    print("| sequence | model | first: dB below median | last | first: offset ms | last | middle "
          "| edge cost as first frame (dB) | as last |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for seq in load_video_heldout(False):
        for model in (default_model_path(), Path(candidate)):
            r = edge_report(seq, "rmbnet", {"model": model, "threads": 1})
            print(f"| {seq.name} | {model} | {r.first_drop_db:.2f} | {r.last_drop_db:.2f} | {r.first_offset_ms:+.2f} "
                  f"| {r.last_offset_ms:+.2f} | {r.middle_offset_ms:+.2f} | {r.first_edge_cost_db:.2f} "
                  f"| {r.last_edge_cost_db:.2f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
