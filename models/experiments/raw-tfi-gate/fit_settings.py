"""Is TFI-16's missing share a matter of fitting? Two fits of one recipe can differ: one learns TFI-16 shares that
fall with a pan's speed, the other gives TFI-16 none anywhere (``results.md``, "Slow camera pans in the fit"). This
fits the recipe's gate at ``frame_features.PIXELS`` a frame on the cached recipe captures with other Adam settings
(steps, learning rate) and reports the development gains, still captures and texture pans, the real streams and
TFI-16's mean share on the real streams. Run from the repository root, one thread (~10 minutes per 2,000 steps):

    python models/experiments/raw-tfi-gate/fit_settings.py DIR SEED STEPS LR
"""

import sys
from pathlib import Path

import numpy as np
import torch

import frame_features as ff
import rmbvideo.train.raw_gate as recipe_module
import still_scenes
from rmbvideo.net.raw_gate import gate_features
from rmbvideo.net.weights import default_model_path
from rmbvideo.train.raw_gate import RawGateRecipe


def long_share(folder: str, gate) -> list[float]:  # noqa: ANN001
    """TFI-16's mean share on each cached real stream's reference frame."""
    shares = []
    for path in sorted(Path(folder).glob("real-*.npz")):
        d = np.load(path)
        with torch.no_grad():
            features = gate_features(ff._tensor(d["binned"]), ff._tensor(d["tfi"]), ff._tensor(d["previous"]),
                                     float(d["convention"]), ff._tensor(d["long"]), frame=True)
            shares.append(float(gate.share(features)[0, 1].mean()))
    return shares


def main(folder: str, seed: int, steps: int, lr: float) -> None:
    ff._cached_recipe(Path(folder))
    recipe = RawGateRecipe(pixels=ff.PIXELS, seed=seed, steps=steps, lr=lr, restarts=1)  # one fit
    gate = recipe_module.fit_gate(recipe_module.gather_samples(recipe, default_model_path("binned")), recipe)[0]
    gate.eval()
    share = " / ".join(f"{s:.3f}" for s in long_share(folder, gate))
    print(f"| seed {seed}, {steps} steps, lr {lr:g} | {still_scenes.scores_row(folder, gate)} | {share} |", flush=True)

if __name__ == "__main__":
    torch.set_num_threads(1)
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]))
