"""The w = 3 / w = 0 ablation pair of a folder on the held-out sets, scored as ``rmbvideo evaluate --models`` scores its
"RMB-Net (ablation budget)" and "w = 0" rows (the same sequences, readout and harness), without the other rows. Run
from the repository root (a few minutes on one core each):

    python models/experiments/ablation-seeds/score_pair.py models/ablations/cpu-3022-seed2 [more folders]

Prints each folder's rows (mean mu-law PSNR and per sequence; a folder may hold one of the two) and, with both, their
difference; with several pairs, the mean difference and its standard error.
"""

import math
import sys
from pathlib import Path

from rmbvideo.evaluate.harness import ABLATIONS, MethodSpec, evaluate_rows
from rmbvideo.evaluate.heldout import load_heldout, load_video_heldout

PAIR = ("RMB-Net (ablation budget)", "w = 0")


def score(folder: Path, sequences: list) -> float | None:
    """The folder's rows (those of the pair it holds) and, with both, w = 3 minus w = 0."""
    paths = {name: folder / f"{ABLATIONS[name][0]}.safetensors" for name in PAIR}
    specs = [MethodSpec(name, "rmbnet", {"model": str(path), "device": "cpu", "input_mode": "binned", "threads": 1},
                        ABLATIONS[name][1]) for name, path in paths.items() if path.is_file()]
    rows = {row.name: row for row in evaluate_rows(specs, sequences)}
    for name, row in rows.items():
        print(f"{folder} | {name}: {row.status}, mu-law PSNR {row.psnr:.2f}")
        print("   " + ", ".join(f"{seq} {value:.2f}" for seq, value in row.per_sequence.items()), flush=True)
    if len(rows) < len(PAIR):
        return None
    difference = rows[PAIR[0]].psnr - rows[PAIR[1]].psnr
    print(f"{folder}: w = 3 minus w = 0 = {difference:+.2f} dB", flush=True)
    return difference


def main(folders: list[str]) -> None:
    sequences = load_heldout(False, None) + load_video_heldout(False, None)
    differences = [d for d in (score(Path(f), sequences) for f in folders) if d is not None]
    if len(differences) > 1:
        mean = sum(differences) / len(differences)
        sd = math.sqrt(sum((d - mean) ** 2 for d in differences) / (len(differences) - 1))
        error = sd / math.sqrt(len(differences))
        print(f"{len(differences)} pairs: mean {mean:+.2f} dB, sd {sd:.2f}, standard error {error:.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
