"""The window-worth pair scored on the held-out sets: the two fine-tuned runs (``rmbvideo train window-worth-w3-cpu`` /
``window-worth-w0-cpu``) and, as their starting points, stage 19 as shipped and without its window, untrained
(``rmbvideo.net.weights.without_window``, as the w = 0 recipe starts). Run from the repository root (a few minutes a model on one core):

    python models/experiments/window-worth/score.py

The runs are read from ``models/training/window-worth/w3`` and ``w0`` (``rmbvideo train window-worth-w3-cpu -o
models/training/window-worth/w3``, likewise w0: 700 steps each) and ``w0-equal-time`` (``rmbvideo train
window-worth-w0-cpu --steps 1750 -o models/training/window-worth/w0-equal-time``: w = 0 makes 2.5x the steps in w = 3's
time); ``seed80-w3`` and ``seed80-w0`` are the pair again with other scenes, trained in bf16 (``--seed 80 --precision
bf16``); a model not there yet is left out. Each model's scores are kept in
``scores/`` here and read back on the next call, so a model is scored once.

Each model is run as the default reads the binned stream (its pure-M readout, the simulated cameras' response), on
the held-out synthetic sequences and video sequences (the ablation pairs' set, ``score_pair.py``) and on the real
streams in ``../shared/data/spikezoo-base`` when present. Prints one markdown table: mean mu-law PSNR per sequence,
the first and last frames' mean drop below each clip's median, the real streams' linear PSNR, and w = 3 minus w = 0
for the pairs.
"""

import json
import tempfile
from pathlib import Path

import numpy as np

from rmbvideo.evaluate.development import score_sequences, score_streams
from rmbvideo.evaluate.heldout import load_heldout, load_video_heldout
from rmbvideo.evaluate.real_video import find_streams
from rmbvideo.net.weights import ModelCard, default_model_path, load_model, save_model, without_window

HERE = Path(__file__).parent
REAL = Path("../shared/data/spikezoo-base")
RUNS = Path("models/training/window-worth")
#: label -> (the file its scores are kept in, under ``scores/``; the weights)
MODELS = {"stage 19 (w = 3, shipped)": ("stage19", default_model_path("binned")),
          "stage 19 at w = 0, untrained": ("stage19-w0", None),
          "w = 3, fine-tuned": ("w3", RUNS / "w3" / "window-worth-w3.safetensors"),
          "w = 0, fine-tuned": ("w0", RUNS / "w0" / "window-worth-w0.safetensors"),
          "w = 0, fine-tuned at equal time": ("w0-equal-time", RUNS / "w0-equal-time" / "window-worth-w0.safetensors"),
          "w = 3, fine-tuned, seed 80, bf16": ("seed80-w3", RUNS / "seed80-w3" / "window-worth-w3.safetensors"),
          "w = 0, fine-tuned, seed 80, bf16": ("seed80-w0", RUNS / "seed80-w0" / "window-worth-w0.safetensors")}


def scored(key: str, path: Path, sequences: list, streams: list) -> tuple[dict, float, float, dict]:
    """The model's per-sequence scores, first/last-frame drops and real-stream scores, from ``scores/key.json`` when
    kept."""
    kept = HERE / "scores" / f"{key}.json"
    if kept.is_file():
        data = json.loads(kept.read_text())
        return data["sequences"], data["first"], data["last"], data["real"]
    scores, first, last, _, _ = score_sequences(path, sequences, pictured={})
    real = {s: r.psnr for s, r in score_streams(path, streams).items()}
    kept.parent.mkdir(exist_ok=True)
    kept.write_text(json.dumps({"model": str(path), "sequences": scores, "first": first, "last": last, "real": real},
                               indent=1) + "\n")
    return scores, first, last, real


def main() -> None:
    sequences = load_heldout(False) + load_video_heldout(False)
    streams = find_streams(REAL) if REAL.is_dir() else []
    rows = {}
    made = tempfile.TemporaryDirectory()
    for name, (key, path) in MODELS.items():
        if path is None:  # stage 19 without its window, as the w = 0 run starts
            path = Path(made.name) / "stage19-w0.safetensors"
            save_model(path, without_window(load_model(default_model_path("binned"))[0]), ModelCard(name="stage19-w0"))
        if not path.is_file():
            print(f"{name}: {path} not trained yet")
            continue
        rows[name] = scored(key, path, sequences, streams)
        scores, real = rows[name][0], rows[name][3]
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
                   ("w = 3, fine-tuned", "w = 0, fine-tuned"), ("w = 3, fine-tuned", "w = 0, fine-tuned at equal time"),
        ("w = 3, fine-tuned, seed 80, bf16", "w = 0, fine-tuned, seed 80, bf16")):
        if w3 not in rows or w0 not in rows:
            continue
        diff = [rows[w3][0][n] - rows[w0][0][n] for n in names]
        real = [rows[w3][3][n] - rows[w0][3][n] for n in reals]
        print(f"\n{w3} minus {w0}: sequences {np.mean(diff):+.2f} dB (least {min(diff):+.2f}, most {max(diff):+.2f}; "
              f"ahead on {sum(d > 0 for d in diff)} of {len(diff)})"
              + (f", real video {np.mean(real):+.2f} dB" if real else ""))


if __name__ == "__main__":
    main()
