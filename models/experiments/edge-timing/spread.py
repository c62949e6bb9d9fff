"""How much one clip's edge-frame timing says: the clip-edge check (``edge_report``) of the shipped default on
many clips of each video kind, drawn from seeds neither the held-out set (index 0) nor the development set
(index 7) uses, so a miss on one held-out clip can be read against the spread of the kind.

    python models/experiments/edge-timing/spread.py [KIND ...] [--clips N]   # default: fast-dark dark, 8 clips
    python models/experiments/edge-timing/spread.py KIND ... --model M.safetensors --out NAME.json

``--model``: another weight file than the shipped default (with its edge model where one is beside it, as the engine
uses it: ``rmbvideo.recon.clip_edges``), its figures in ``--out`` beside this script instead of ``spread.json``.
``--compare A.json B.json``: B's figures against A's, clip by clip (the mean change and how many clips gain), and
each one's targets met.

Prints per clip, and per kind the mean and standard error, of: the last and first frame's time offset against
the middle frame's (ms; the target is within 0.2 ms) and the edge costs (dB). Writes ``spread.json`` beside itself.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import torch

from rmbvideo.evaluate.heldout import load_video_heldout
from rmbvideo.evaluate.video_checks import edge_report

FIRST_INDEX = 8  # seeds from the kind's index 8 on: the held-out set has index 0, the development set index 7
OUT = Path(__file__).with_name("spread.json")


def summary(values: list[float]) -> str:
    mean = sum(values) / len(values)
    spread = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1)) if len(values) > 1 else 0.0
    return f"{mean:+.3f} ± {spread / math.sqrt(len(values)):.3f} (sd {spread:.3f}, n {len(values)})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("kinds", nargs="*", default=["fast-dark", "dark"])
    parser.add_argument("--clips", type=int, default=8)
    parser.add_argument("--model", default=None)
    parser.add_argument("--out", default=OUT.name)
    parser.add_argument("--compare", nargs=2, default=None)
    args = parser.parse_args()
    if args.compare:
        compare(*(json.loads(OUT.with_name(name).read_text()) for name in args.compare))
        return
    torch.set_num_threads(1)
    out = OUT.with_name(args.out)
    options = {"threads": 1, "input_mode": "binned", **({"model": args.model} if args.model else {})}
    results = json.loads(out.read_text()) if out.is_file() else {}
    for kind in args.kinds:
        rows = results.setdefault(kind, {})
        for seq in load_video_heldout(False, per_kind=args.clips, first=FIRST_INDEX, kinds={kind}):
            if seq.name in rows:
                continue
            r = edge_report(seq, "rmbnet", options)
            rows[seq.name] = {"last_offset_ms": r.last_offset_ms - r.middle_offset_ms,
                              "first_offset_ms": r.first_offset_ms - r.middle_offset_ms,
                              "middle_offset_ms": r.middle_offset_ms,
                              "first_drop_db": r.first_drop_db, "last_drop_db": r.last_drop_db,
                              "first_edge_cost_db": r.first_edge_cost_db, "last_edge_cost_db": r.last_edge_cost_db}
            print(seq.name, {key: round(v, 3) for key, v in rows[seq.name].items()}, flush=True)
            out.write_text(json.dumps(results, indent=1) + "\n")
        for key in ("last_offset_ms", "first_offset_ms", "first_edge_cost_db", "last_edge_cost_db",
                    "first_drop_db", "last_drop_db"):
            print(f"{kind} {key}: {summary([row[key] for row in rows.values()])}")
    overall(results)


def overall(results: dict) -> None:
    """Over every clip scored so far: how many edge frames meet each target, and the worst."""
    rows = [row for kind in results.values() for row in kind.values()]
    checks = [("within 0.2 ms of the middle frame's moment", ("first_offset_ms", "last_offset_ms"), 0.2, abs),
              ("within 1.5 dB of the clip's median frame", ("first_drop_db", "last_drop_db"), 1.5, float),
              ("edge cost within 1.5 dB", ("first_edge_cost_db", "last_edge_cost_db"), 1.5, float)]
    for label, keys, limit, measure in checks:
        values = [row[key] for row in rows for key in keys]
        within = sum(measure(v) <= limit + 1e-9 for v in values)
        worst = max(values, key=measure)
        print(f"all kinds, edge frames {label}: {within} of {len(values)} (worst {worst:+.2f})")


def compare(base: dict, other: dict) -> None:
    """``other``'s figures against ``base``'s on the clips both scored: per figure the mean change, and on how many clips
    the edge frame is nearer its target (a smaller drop, cost or absolute offset); then each one's targets met."""
    keys = [(kind, name) for kind in base for name in base[kind] if name in other.get(kind, {})]
    for key in ("first_drop_db", "last_drop_db", "first_edge_cost_db", "last_edge_cost_db", "first_offset_ms",
                "last_offset_ms"):
        measure = abs if key.endswith("_ms") else float
        changes = [measure(other[k][n][key]) - measure(base[k][n][key]) for k, n in keys]
        print(f"{key}: mean change {sum(changes) / len(changes):+.3f}, nearer on {sum(c < 0 for c in changes)}, "
              f"farther on {sum(c > 0 for c in changes)} of {len(changes)}")
    for label, results in (("base", base), ("other", other)):
        print(label)
        overall({kind: {n: results[kind][n] for k, n in keys if k == kind} for kind in results})


if __name__ == "__main__":
    main()
