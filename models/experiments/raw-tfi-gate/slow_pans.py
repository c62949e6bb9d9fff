"""Do display-referred slow camera pans teach the gate when TFI-16 is worth its share? On the development texture pans
at 0.07 raw px a plane TFI-16 reads 42.07 / 37.60 dB against the binned frame's 37.80 / 35.47, and on 200_part3 36.86
against 35.46, yet the shipped gate never gives TFI-16 a share. The recipe's display-referred captures are still
scenes, or video with movers, shake and zoom; a camera panning slowly over a still scene, video's commonest motion, is
rare among them. ``cache`` simulates such pans (training seeds, spikezoo's convention, rigid pans at 0.01-0.2 raw px
a plane, no movers) and stores what the gate reads (``candidate-pan-*``, beside ``frame_features.py cache``'s);
``variant`` fits the recipe's gate at ``frame_features.PIXELS`` a frame on the recipe's cached captures with and
without them and scores both on the development set, the still captures and texture pans, and the real streams.
Run from the repository root, one thread, on a folder with the recipe's captures as ``train-*`` (the shipped fit's):

    python models/experiments/raw-tfi-gate/slow_pans.py cache DIR [COUNT]     # ~5 min for 6
    python models/experiments/raw-tfi-gate/slow_pans.py variant DIR SEED      # ~25 min (two fits)
"""

import sys
from dataclasses import replace
from pathlib import Path

import torch

import frame_features as ff
import rmbvideo.train.raw_gate as recipe_module
import still_scenes
from rmbvideo.evaluate.heldout import FULL, VideoHeldout, simulate_video_sequence
from rmbvideo.net.weights import default_model_path
from rmbvideo.scenes.video import VideoSceneRanges
from rmbvideo.train.raw_gate import RawGateRecipe, gate_frames

#: A camera panning slowly over a still scene, in spikezoo's convention.
SLOW_PAN = VideoHeldout("slow-pan-display", VideoSceneRanges(pan_probability=1.0, pan_speed=(0.01, 0.2)), "spikezoo")
FIRST_SEED = 790_000  # apart from the recipe's (700,000-780,002) and the other experiments' training seeds


def cache(folder: str, count: int = 6) -> None:
    out, model = Path(folder), default_model_path("binned")
    for j in range(count):
        seq = simulate_video_sequence(FIRST_SEED + j, SLOW_PAN, replace(FULL, reset="zero"), training=True)
        ff._save(out / f"candidate-pan-{SLOW_PAN.name}-{FIRST_SEED + j}.npz", seq, gate_frames(seq, model, ff.WINDOWS))
        print(f"cached {SLOW_PAN.name}-{FIRST_SEED + j}", flush=True)


def variant(folder: str, seed: int) -> None:
    ff._cached_recipe(Path(folder))
    recipe_paths = sorted(Path(folder).glob("train-*.npz"))
    pans = sorted(Path(folder).glob("candidate-pan-*.npz"))
    print("| gate (seed) | development: paper's pixel / reset by subtraction | still captures | texture pans "
          "| real streams | real mean |\n|---|---:|---:|---:|---:|---:|")
    for label, paths in (("recipe", recipe_paths), (f"recipe + {len(pans)} slow pans", recipe_paths + pans)):
        recipe_module.training_sequences = lambda recipe, paths=paths: (ff._stand_in(p) for p in paths)
        recipe = RawGateRecipe(pixels=ff.PIXELS, seed=seed, **ff.ONE_FIT)
        gate = recipe_module.fit_gate(recipe_module.gather_samples(recipe, default_model_path("binned")), recipe)[0]
        gate.eval()
        torch.save(gate.state_dict(), Path(folder) / f"gate-slowpans-{len(paths)}-{seed}.pt")
        print(f"| {label} ({seed}) | {still_scenes.scores_row(folder, gate)} |", flush=True)


if __name__ == "__main__":
    torch.set_num_threads(1)
    command, args = sys.argv[1], sys.argv[2:]
    if command == "cache":
        cache(args[0], *(int(a) for a in args[1:]))
    else:
        variant(args[0], int(args[1]))
