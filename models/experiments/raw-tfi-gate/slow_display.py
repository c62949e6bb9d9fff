"""Would display-referred training captures at the speeds video mostly has teach the raw gate what 200_part3 needs?

The real-video streams move 0.12-0.19 raw px/plane (DIS flow between TFP-40 frames); the simulated display-referred
streams the gate is fitted on move 1.06-1.2 (spikezoo-fast and the fast twin) and 0.35-0.6 (the low-contrast twin):
there RMB-Net's binned window blurs and TFI wins, where on the real streams its window is sharp. This adds captures
of the training scenes' default video ranges (camera speed log-uniform 0.005-1.2 px/plane: mostly slow) in
spikezoo's convention to the samples of ``rmbvideo train-raw-gate --display-videos 2``, fits a gate with each loss
and scores it on the real streams at the binned size (as ``gate.py real``). Answer: no (200_part3 -0.77 dB with the
mu-law loss, -1.25 with the display-linear one, against the shipped gate's -0.48; ``results.md``). Run from the
repository root:

    python models/experiments/raw-tfi-gate/slow_display.py speeds ../shared/data/spikezoo-base   # the speeds above
    python models/experiments/raw-tfi-gate/slow_display.py gather OUT.npz [CAPTURES]   # about 10 minutes, one core
    python models/experiments/raw-tfi-gate/slow_display.py fit OUT.npz mu-law|mu-law+display-linear GATE.safetensors
    python models/experiments/raw-tfi-gate/gate.py real GATE.safetensors ../shared/data/spikezoo-base
"""

import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

from rmbvideo.evaluate.heldout import FULL, simulate_video_sequence
from rmbvideo.net.raw_gate import RawGateConfig
from rmbvideo.net.weights import ModelCard, default_model_path, save_model
from rmbvideo.train.raw_gate import (VIDEO_DISPLAY, GateSamples, RawGateRecipe, display_referred, fit_gate,
                                     gate_frames, gather_samples, _samples)

FIRST_SEED = 740_000
#: The gate these figures were fitted with reads plain TFI (the recipe's default became TFI-4 since).
PLAIN_TFI = RawGateConfig(tfi_window=0)


def flow_speed(planes: np.ndarray, a: int, b: int, window: int = 40) -> float:
    """Median optical-flow speed (raw px per raw plane) between the TFP frames of ``window`` planes centred on a, b."""
    scale = 255 / max(float(planes.mean()) * 2.5, 1e-3)
    frame = lambda c: np.clip(planes[c - window // 2:c + window // 2].mean(0) * scale, 0, 255).astype(np.uint8)  # noqa: E731
    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(frame(a), frame(b), None)
    return float(np.median(np.hypot(flow[..., 0], flow[..., 1]))) / (b - a)


def speeds(folder: str) -> None:
    from rmbvideo.evaluate.heldout import VIDEO_KINDS
    from rmbvideo.evaluate.real_video import find_streams
    from rmbvideo.io.dat import DatReader

    for stream in find_streams(Path(folder)):
        planes = np.concatenate([c.planes for c in DatReader(stream.capture, stream.geometry).chunks(1000)])
        print(f"{stream.name}: {flow_speed(planes, 60, 100):.3f} / {flow_speed(planes, 150, 190):.3f} px/plane")
    for kind in [*(k for k in VIDEO_KINDS if k.name in ("spikezoo-fast", "low-contrast")), VIDEO_DISPLAY]:
        for seed in (FIRST_SEED, FIRST_SEED + 1):
            seq = simulate_video_sequence(seed, replace(kind, convention="spikezoo"), FULL, training=True)
            planes = np.unpackbits(seq.raw_packed, axis=-1, bitorder="little").astype(np.float32)
            print(f"{kind.name} {seed}: {flow_speed(planes, 60, 100):.3f} / {flow_speed(planes, 150, 190):.3f} px/plane")


def gather(out: str, captures: int = 6) -> None:
    """The ``--display-videos 2`` recipe's samples, then ``captures`` of ``VIDEO_DISPLAY`` (its own pixel draws)."""
    torch.set_num_threads(1)
    recipe = RawGateRecipe(gate=PLAIN_TFI, display_videos=2, display_scenes=0, still_scenes=0, pixels=2000, lr=3e-3,
                           restarts=1)  # the recipe these figures were made with
    model = default_model_path("binned")
    base = gather_samples(recipe, model)
    rng = np.random.default_rng(1)
    parts, names = [], []
    for j in range(captures):
        seq = simulate_video_sequence(FIRST_SEED + j, VIDEO_DISPLAY, FULL, training=True)
        assert display_referred(seq)
        parts.append(_samples(seq, gate_frames(seq, model, recipe.gate), recipe, rng))
        names.append(seq.name)
    extra = [np.concatenate(x) for x in zip(*parts)]
    np.savez(out, features=np.concatenate([base.features, extra[0]]), binned=np.concatenate([base.binned, extra[1]]),
             tfi=np.concatenate([base.tfi, extra[2]]), truth=np.concatenate([base.truth, extra[3]]),
             display=np.concatenate([base.display, np.ones(len(extra[1]), bool)]),
             names=np.array([*base.captures, *names]))


def fit(samples_path: str, loss: str, out: str) -> None:
    torch.set_num_threads(1)
    z = np.load(samples_path)
    samples = GateSamples(z["features"], z["binned"], z["tfi"], z["truth"], z["display"],
                          tuple(str(n) for n in z["names"]))
    gate, metrics = fit_gate(samples, RawGateRecipe(gate=PLAIN_TFI, loss=loss, lr=3e-3, restarts=1))
    print(metrics)
    save_model(Path(out), gate, ModelCard(name=Path(out).stem, description="slow_display.py experiment",
                                          training={"loss": loss}, data={"captures": list(samples.captures)},
                                          metrics=metrics))


if __name__ == "__main__":
    {"speeds": lambda: speeds(sys.argv[2]),
     "gather": lambda: gather(sys.argv[2], *(int(a) for a in sys.argv[3:])),
     "fit": lambda: fit(*sys.argv[2:5])}[sys.argv[1]]()
