"""The real-motion issue's per-sequence targets for a gate on a 1-bit capture: its held-out frames (cached by
``frame_features.py cache``, scored as ``frame_features.py score``) against the rows of an evaluation table
(``rmbvideo evaluate`` writes ``evaluation.md``; ``--reset subtract`` the same set with the other pixel). Per pixel
kind: the mean and its lead over the best method on the same RMB input, the least lead on any sequence, and how far it
trails the best classical method on the raw capture at worst. Run from the repository root, one thread:

    python models/experiments/raw-tfi-gate/targets.py DIR models/raw-gate.safetensors \
        models/figures/evaluation.md models/figures/evaluation-reset-subtract.md
"""

import sys
from pathlib import Path

import numpy as np
import torch

import frame_features as ff
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.net.weights import load_raw_gate

#: The rows of ``evaluation.md`` that read the binned stream (the same RMB input as the default).
RMB_INPUT = ("TFW-S", "TFW-L", "TFI", "GC20", "MG20", "RMB-Net, RMB readout")


def per_sequence(path: str) -> dict[str, dict[str, float]]:
    """``evaluation.md``'s per-sequence mu-PSNR table: row -> sequence -> dB."""
    lines = Path(path).read_text().split("## μ-PSNR (dB) per sequence")[1].strip().split("\n")
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = {}
    for line in lines[2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = {name: float(v) for name, v in zip(head[1:], cells[1:]) if v not in ("", "—")}
    return rows


def main(folder: str, gate_path: str, zero: str, subtract: str) -> None:
    gate = load_raw_gate(gate_path)[0].eval()
    for reset, table in (("zero", per_sequence(zero)), ("subtract", per_sequence(subtract))):
        gated = {}
        for seq in ff._evaluation_sets("heldout")[reset]:
            d = dict(np.load(Path(folder) / f"heldout-{reset}-{seq.name}.npz"))
            mixed = ff._mixed(gate, d)
            gated[seq.name] = float(np.mean([mu_law_psnr(mixed[i], d["truth"][i]) for i in seq.scored_frames]))
        inputs = [r for r in RMB_INPUT if r in table]
        raw = [r for r in table if r.endswith("(raw)")]
        mean = np.mean(list(gated.values()))
        best_input = max(np.mean([table[r][s] for s in gated]) for r in inputs)
        lead, behind = ({s: (v - max(table[r][s] for r in rows), max(rows, key=lambda r: table[r][s]))
                         for s, v in gated.items()} for rows in (inputs, raw))
        least, worst = min(lead, key=lambda s: lead[s][0]), min(behind, key=lambda s: behind[s][0])
        print(f"{reset}: mean {mean:.2f} dB, {mean - best_input:+.2f} over the best RMB-input method; least per "
              f"sequence {lead[least][0]:+.2f} ({least}, over {lead[least][1]}); against the best classical method "
              f"at worst {behind[worst][0]:+.2f} ({worst}, {behind[worst][1]})")


if __name__ == "__main__":
    torch.set_num_threads(1)
    main(*sys.argv[1:5])
