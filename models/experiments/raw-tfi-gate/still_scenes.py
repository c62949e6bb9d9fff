"""Does the gate hold on still scenes? The development clips' still texture pans lose 5-7 dB to the gate (the
binned frame reads them best; TFI-4 is mixed in), and the recipe's captures are almost all moving. On frames cached
as ``frame_features.py cache`` does: still captures of evaluation seeds (``cache``: spikezoo's convention and both
camera pixels) and the development texture pans at their reference's moment, scored with a gate file (``score``);
still captures of training seeds, and gates fitted at ``frame_features.PIXELS`` a frame on the recipe's cached
captures with or without them (``variant``), scored on the development set, the still captures, the texture pans and
the real streams. Run from the repository root, one thread, after ``frame_features.py cache DIR STREAMS``:

    python models/experiments/raw-tfi-gate/still_scenes.py cache DIR PANS      # ~10 min (PANS: the texture pans)
    python models/experiments/raw-tfi-gate/still_scenes.py score DIR GATE
    python models/experiments/raw-tfi-gate/still_scenes.py variant DIR SEED none|-|display   # ~10 min
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

import frame_features as ff
import rmbvideo.train.raw_gate as recipe_module
from rmbvideo.evaluate.heldout import FULL, VideoHeldout, simulate_video_sequence
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.real_video import scaled_psnr
from rmbvideo.net.raw_gate import RawGate
from rmbvideo.net.weights import default_model_path, load_raw_gate
from rmbvideo.scenes.random_scenes import EVAL_SEED_START
from rmbvideo.scenes.video import VideoSceneRanges
from rmbvideo.train.raw_gate import RawGateRecipe, gate_frames

#: A still camera over a still scene: no camera motion, shake or movers.
STILL = VideoSceneRanges(static_probability=1.0, max_objects=0, shake_px=0.0)
#: (kind, pixel reset) of the still captures: spikezoo's display-referred convention, then a camera's two pixels.
KINDS = ((VideoHeldout("still-display", STILL, "spikezoo"), "zero"), (VideoHeldout("still", STILL), "zero"),
         (VideoHeldout("still", STILL), "subtract"))
EVAL_FIRST = EVAL_SEED_START + 2_100_000  # apart from the texture pans' seeds (+2,000,000 on)
TRAIN_FIRST = 780_000  # apart from the recipe's and the REDS-like captures' training seeds
PER_KIND = 3


def _still(first: int, training: bool):  # noqa: ANN202
    for k, (kind, reset) in enumerate(KINDS):
        for j in range(PER_KIND):
            seq = simulate_video_sequence(first + 100 * k + j, kind, replace(FULL, reset=reset), training=training)
            yield seq, f"{kind.name}-{reset}-{seq.name.rsplit('-', 1)[-1]}"


def cache(folder: str, pans: str) -> None:
    """The still captures of evaluation seeds (``still-*.npz``) and of training seeds (``candidate-still-*.npz``: not
    ``train-*``, which ``frame_features.py fit`` reads), and the texture pans' reference frames (``pan-*.npz``, as
    ``frame_features.cache`` stores the real streams')."""
    from rmbvideo.evaluate.real_video import binned_reference, find_streams

    out, model = Path(folder), default_model_path("binned")
    for first, training, prefix in ((EVAL_FIRST, False, "still"), (TRAIN_FIRST, True, "candidate-still")):
        for seq, name in _still(first, training):
            ff._save(out / f"{prefix}-{name}.npz", seq, gate_frames(seq, model, ff.WINDOWS))
            print(f"cached {prefix}-{name}", flush=True)
    for stream in find_streams(Path(pans)):
        binned, tfi, previous, long_tfi, convention = ff.reference_frame_inputs(stream, model)
        np.savez(out / f"pan-{stream.name}.npz", binned=binned, tfi=tfi, previous=previous, long=long_tfi,
                 convention=convention, reference=binned_reference(stream))


def _gated(gate: RawGate, path: Path) -> tuple[dict, list[np.ndarray]]:
    d = dict(np.load(path))
    return d, ff._mixed(gate, d)


def score(folder: str, gate: RawGate | str, quiet: bool = False) -> dict[str, float]:
    """The still captures (mu-law PSNR of frames 3-16, as the evaluation scores) and the texture pans (linear PSNR
    after a least-squares gain), binned and gated; the mean gain of each."""
    gate = load_raw_gate(gate)[0] if isinstance(gate, str) else gate
    gate.eval()
    say = (lambda *a: None) if quiet else print  # noqa: E731
    say("| capture | default (binned) | TFI-4 | TFI-16 | gated | gain |\n|---|---:|---:|---:|---:|---:|")
    gains: dict[str, list[float]] = {"still": [], "pan": []}
    for path in sorted(Path(folder).glob("still-*.npz")):
        d, mixed = _gated(gate, path)
        frames = range(3, len(mixed) - 2)
        row = [np.mean([mu_law_psnr(x[i], d["truth"][i]) for i in frames]) for x in (d["binned"], d["tfi"],
                                                                                       d["long"], mixed)]
        gains["still"].append(row[3] - row[0])
        say(f"| {path.stem} | " + " | ".join(f"{v:.2f}" for v in row) + f" | {row[3] - row[0]:+.2f} |")
    for path in sorted(Path(folder).glob("pan-*.npz")):
        d = dict(np.load(path))
        with torch.no_grad():
            mixed = gate(ff._tensor(d["binned"]), ff._tensor(d["tfi"]), ff._tensor(d["previous"]),
                         float(d["convention"]), ff._tensor(d["long"]))[0, 0].numpy()
        row = [scaled_psnr(x, d["reference"]) for x in (d["binned"], d["tfi"], d["long"], mixed)]
        gains["pan"].append(row[3] - row[0])
        say(f"| {path.stem} | " + " | ".join(f"{v:.2f}" for v in row) + f" | {row[3] - row[0]:+.2f} |")
    means = {k: float(np.mean(v)) for k, v in gains.items()}
    say(f"| mean gain | | | | | still {means['still']:+.2f}, pans {means['pan']:+.2f} |")
    return means


def variant(folder: str, seed: int, still: str) -> None:
    """The recipe's gate fitted at ``frame_features.PIXELS`` a frame on the cached recipe captures without its still
    ones, with the candidate still captures whose names contain ``still`` added ("-": all, "none": none, "display":
    the display-referred ones, which are the recipe's own); its development gains, still and texture-pan gains and
    real streams."""
    ff._cached_recipe(Path(folder))
    paths = ([p for p in sorted(Path(folder).glob("train-*.npz")) if "still" not in p.name]
             + [p for p in sorted(Path(folder).glob("candidate-still-*.npz")) if still in p.name])
    recipe_module.training_sequences = lambda recipe: (ff._stand_in(p) for p in paths)
    recipe = RawGateRecipe(pixels=ff.PIXELS, seed=seed, **ff.ONE_FIT)
    gate = recipe_module.fit_gate(recipe_module.gather_samples(recipe, default_model_path("binned")), recipe)[0]
    gate.eval()
    torch.save(gate.state_dict(), Path(folder) / f"gate-still{still}-{seed}.pt")
    still = "none" if still == "none" else f"{sum('still' in p.name for p in paths)} ({still})"
    print(f"| still captures: {still}, seed {seed} | {scores_row(folder, gate)} |", flush=True)


def scores_row(folder: str, gate: RawGate) -> str:
    """A variant's table cells: development gains (both pixels), still-capture and texture-pan gains, the real
    streams and their mean."""
    dev, real = ff.score(folder, gate, "development", quiet=True), ff.score(folder, gate, "real", quiet=True)
    stills = score(folder, gate, quiet=True)
    streams = " / ".join(f"{v:.2f}" for k, v in real.items() if k != "mean")
    return (f"{dev['zero']:+.2f} / {dev['subtract']:+.2f} | {stills['still']:+.2f} | {stills['pan']:+.2f} | "
            f"{streams} | {real['mean']:.2f}")


if __name__ == "__main__":
    torch.set_num_threads(1)
    command, args = sys.argv[1], sys.argv[2:]
    if command == "cache":
        cache(*args)
    elif command == "score":
        score(*args)
    else:
        variant(args[0], int(args[1]), args[2])
