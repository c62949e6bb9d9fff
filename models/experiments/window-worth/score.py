"""The window-worth pair scored on the held-out sets: the two fine-tuned runs (``rmbvideo train window-worth-w3-cpu`` /
``window-worth-w0-cpu``) and, as their starting points, stage 19 as shipped and narrowed to w = 0 untrained
(``narrow.py``). Run from the repository root once both runs are done (about 20 minutes on one core):

    python models/experiments/window-worth/score.py models/training/window-worth/w3/window-worth-w3.safetensors \\
        models/training/window-worth/w0/window-worth-w0.safetensors

Each model is run as the default reads the binned stream (its pure-M readout, the simulated cameras' response), on
the held-out synthetic sequences and video sequences (the ablation pairs' set, ``score_pair.py``) and on the real
streams in ``../shared/data/spikezoo-base`` when present. Prints one markdown table: mean mu-law PSNR per sequence,
the first and last frames' mean drop below each clip's median, the real streams' linear PSNR, and w = 3 minus w = 0
for the pairs.
"""

import sys
from pathlib import Path

import numpy as np

from rmbvideo.evaluate.development import score_sequences, score_streams
from rmbvideo.evaluate.heldout import load_heldout, load_video_heldout
from rmbvideo.evaluate.real_video import find_streams
from rmbvideo.net.weights import default_model_path

HERE = Path(__file__).parent
REAL = Path("../shared/data/spikezoo-base")


def main(w3_run: str, w0_run: str) -> None:
    models = {"stage 19 (w = 3, shipped)": default_model_path("binned"),
              "stage 19 at w = 0, untrained": HERE / "stage19-w0.safetensors",
              "w = 3, fine-tuned": Path(w3_run), "w = 0, fine-tuned": Path(w0_run)}
    sequences = load_heldout(False) + load_video_heldout(False)
    streams = find_streams(REAL) if REAL.is_dir() else []
    rows = {}
    for name, path in models.items():
        scores, first, last, _, _ = score_sequences(path, sequences, pictured={})
        real = {s: r.psnr for s, r in score_streams(path, streams).items()}
        rows[name] = (scores, first, last, real)
        print(f"{name}: sequences {np.mean(list(scores.values())):.2f}, real {np.mean(list(real.values()) or [0]):.2f}",
              flush=True)
    names = [s.name for s in sequences]
    reals = [s.name for s in streams]
    print("\n| model | " + " | ".join(names + reals) + " | sequences | real video | first / last vs median |")
    print("|---|" + "---:|" * (len(names) + len(reals) + 2) + "---|")
    for name, (scores, first, last, real) in rows.items():
        cells = [f"{scores[n]:.2f}" for n in names] + [f"{real[n]:.2f}" for n in reals]
        print(f"| {name} | " + " | ".join(cells) + f" | {np.mean(list(scores.values())):.2f} | "
              f"{np.mean(list(real.values()) or [float('nan')]):.2f} | {first:+.2f} / {last:+.2f} |")
    for w3, w0 in (("stage 19 (w = 3, shipped)", "stage 19 at w = 0, untrained"),
                   ("w = 3, fine-tuned", "w = 0, fine-tuned")):
        diff = [rows[w3][0][n] - rows[w0][0][n] for n in names]
        real = [rows[w3][3][n] - rows[w0][3][n] for n in reals]
        print(f"\n{w3} minus {w0}: sequences {np.mean(diff):+.2f} dB (least {min(diff):+.2f}, most {max(diff):+.2f}; "
              f"ahead on {sum(d > 0 for d in diff)} of {len(diff)})"
              + (f", real video {np.mean(real):+.2f} dB" if real else ""))


if __name__ == "__main__":
    main(*sys.argv[1:3])
