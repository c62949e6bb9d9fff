"""Does the gate gain from features of the whole frame? Gate variants fitted on cached frames, so each costs minutes
instead of the recipe's simulation: ``cache`` runs the recipe's training captures, the development sets (both
pixels), the held-out sets and the real-video streams once through ``gate_frames`` (RMB-Net's binned frames, raw
TFI-4 and TFI-16, the truth) and stores them; ``compare`` fits each variant as ``fit_gate`` does (the recipe's loss,
steps and learning rate; ``PIXELS`` drawn per frame) and scores it on the development set and the real streams at
the binned size; ``fit`` runs the recipe's own ``fit_raw_gate`` on the cached training frames (what ``rmbvideo
train-raw-gate`` gives, without simulating again); ``score`` scores a gate file on the cached frames (``gate.py
fitted`` / ``real``'s numbers). Run from the repository root, one thread:

    python models/experiments/raw-tfi-gate/frame_features.py cache DIR ../shared/data/spikezoo-base   # ~25 min
    python models/experiments/raw-tfi-gate/frame_features.py compare DIR [SEED]     # ~10 min a variant
    python models/experiments/raw-tfi-gate/frame_features.py fit DIR OUT.safetensors   # ~50 min (2,000 pixels a frame)
    python models/experiments/raw-tfi-gate/frame_features.py score DIR GATE development|heldout|real
"""

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

import rmbvideo.train.raw_gate as recipe_module
from rmbvideo.evaluate.harness import sequence_convention
from rmbvideo.evaluate.heldout import load_development, load_heldout, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.real_video import scaled_psnr
from rmbvideo.net.raw_gate import RawGate, RawGateConfig
from rmbvideo.net.weights import default_model_path, load_raw_gate
from rmbvideo.train.raw_gate import (GateFrame, GateSamples, RawGateRecipe, display_referred, fit_gate, gate_frames,
                                     training_sequences)

#: Pixels drawn per frame in ``compare`` (the recipe draws 2,000; 500 fits four times faster and, for the gate
#: without frame features, lands within 0.1 dB of the shipped gate on every development mean and real stream).
PIXELS = 500
WINDOWS = RawGateConfig(tfi_window=4, long_window=16)
#: The recipe's fit as every variant table of these scripts was made: one fit, Adam at 3e-3 (the recipe fits from four
#: restarts at 1e-2 since 2026-11-29; ``fit`` uses the recipe as it is).
ONE_FIT = {"lr": 3e-3, "restarts": 1}


def _tensor(x: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(x, np.float32))[None, None]


def _save(path: Path, seq, frames: list[GateFrame]) -> None:
    np.savez(path, binned=np.stack([f.binned for f in frames]), tfi=np.stack([f.tfi for f in frames]),
             long=np.stack([f.long_tfi for f in frames]), truth=np.stack([f.truth for f in frames]),
             convention=float(sequence_convention(seq) != "physical"), display=display_referred(seq))


def _evaluation_sets(which: str) -> dict[str, list]:
    if which == "development":
        return {reset: load_development(reset=reset) for reset in ("zero", "subtract")}
    return {reset: load_heldout(False, reset=reset) + load_video_heldout(False, reset=reset)
            for reset in ("zero", "subtract")}


class _Recorder(RawGate):
    """A gate that keeps what ``FullResolution`` gives it, frame by frame."""

    def forward(self, binned, tfi, previous, convention, long_tfi=None):  # noqa: ANN001, ANN201
        self.calls.append([x.numpy().copy()[0, 0] for x in (binned, tfi, previous, long_tfi)] + [convention])
        return super().forward(binned, tfi, previous, convention, long_tfi)


def cache(folder: str, streams: str) -> None:
    """Every capture's frames as the gate reads them, one .npz each (the real streams: the reference frame's)."""
    from rmbvideo.evaluate.real_video import binned_reference, find_streams

    out, model = Path(folder), default_model_path("binned")
    out.mkdir(parents=True, exist_ok=True)
    for k, seq in enumerate(training_sequences(RawGateRecipe())):
        _save(out / f"train-{k:02d}-{seq.name}.npz", seq, gate_frames(seq, model, WINDOWS))
    for which in ("development", "heldout"):
        for reset, sequences in _evaluation_sets(which).items():
            for seq in sequences:
                _save(out / f"{which}-{reset}-{seq.name}.npz", seq, gate_frames(seq, model, WINDOWS))
    for stream in find_streams(Path(streams)):
        binned, tfi, previous, long_tfi, convention = reference_frame_inputs(stream, model)
        np.savez(out / f"real-{stream.name}.npz", binned=binned, tfi=tfi, previous=previous, long=long_tfi,
                 convention=convention, reference=binned_reference(stream))
        print(f"cached {stream.name}", flush=True)


def reference_frame_inputs(stream, model: Path) -> list:  # noqa: ANN001
    """What the gate reads at a real stream's reference frame in the default job: binned, TFI, previous binned and
    long TFI images (each (H, W)) and the convention."""
    from rmbvideo.evaluate.real_video import CONVENTION, RAW_STEP, open_stream
    from rmbvideo.net.weights import model_readout
    from rmbvideo.recon.full_resolution import FullResolution
    from rmbvideo.recon.methods import make_reconstructor
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

    gate = _Recorder(WINDOWS)
    gate.calls = []
    engine = make_reconstructor("rmbnet", model=str(model), input_mode="binned", threads=1, convention=CONVENTION)
    recon = FullResolution(engine, RmbReadout(mode=ReadoutMode(model_readout(model))), step=RAW_STEP, threads=1,
                           raw_gate=gate)
    sink = FrameCollector()
    reconstruct_stream(open_stream(stream), recon, sink)
    return gate.calls[sorted(sink.frames).index(stream.frame)]


def _frames(path: Path) -> tuple[dict, list[GateFrame]]:
    d = dict(np.load(path))
    return d, [GateFrame(d["binned"][i], d["tfi"][i], d["truth"][i], d["long"][i]) for i in range(len(d["binned"]))]


def _stand_in(path: Path) -> SimpleNamespace:
    """What ``_samples`` reads of a sequence: its name and the description that says its convention and reset."""
    d = np.load(path)
    description = {} if not float(d["convention"]) else {"convention": "spikezoo"}
    if float(d["convention"]) and not bool(d["display"]):
        description["reset"] = "subtract"
    return SimpleNamespace(name=path.stem.split("-", 2)[2], description=json.dumps(description), path=path)


def _cached_recipe(folder: Path) -> None:
    """Make the recipe module read the cached training frames instead of simulating them."""
    paths = sorted(folder.glob("train-*.npz"))
    recipe_module.training_sequences = lambda recipe: (_stand_in(p) for p in paths)
    recipe_module.gate_frames = lambda seq, model, gate, precision="auto": _frames(seq.path)[1]


def _mixed(gate: RawGate, d: dict) -> list[np.ndarray]:
    """The gate's frames of a cached sequence, each with the binned frame before it."""
    out, previous = [], d["binned"][0]
    with torch.no_grad():
        for i in range(len(d["binned"])):
            out.append(gate(_tensor(d["binned"][i]), _tensor(d["tfi"][i]), _tensor(previous), float(d["convention"]),
                            _tensor(d["long"][i]))[0, 0].numpy())
            previous = d["binned"][i]
    return out


def score(folder: str, gate: RawGate | str, which: str, quiet: bool = False) -> dict[str, float]:
    """Mean gain per pixel kind on the development or held-out set (mu-law PSNR of the scored frames), or the real
    streams' linear PSNR after a least-squares gain; rows printed unless ``quiet``."""
    gate = load_raw_gate(gate)[0] if isinstance(gate, str) else gate
    gate.eval()
    say = (lambda *a: None) if quiet else print  # noqa: E731
    if which == "real":
        scores = {}
        say("| stream | default (binned) | gated |\n|---|---:|---:|")
        for path in sorted(Path(folder).glob("real-*.npz")):
            d = dict(np.load(path))
            with torch.no_grad():
                mixed = gate(_tensor(d["binned"]), _tensor(d["tfi"]), _tensor(d["previous"]), float(d["convention"]),
                             _tensor(d["long"]))[0, 0].numpy()
            scores[path.stem[5:]] = scaled_psnr(mixed, d["reference"])
            say(f"| {path.stem[5:]} | {scaled_psnr(d['binned'], d['reference']):.2f} | {scores[path.stem[5:]]:.2f} |")
        scores["mean"] = float(np.mean(list(scores.values())))
        return scores
    say("| sequence | default | TFI-4 (raw) | gated | gain |\n|---|---:|---:|---:|---:|")
    gains = {}
    for reset, sequences in _evaluation_sets(which).items():
        rows = []
        for seq in sequences:
            d = dict(np.load(Path(folder) / f"{which}-{reset}-{seq.name}.npz"))
            images = (d["binned"], d["tfi"], _mixed(gate, d))
            row = [np.mean([mu_law_psnr(x[i], d["truth"][i]) for i in seq.scored_frames]) for x in images]
            rows.append(row)
            say(f"| {seq.name} ({reset}) | {row[0]:.2f} | {row[1]:.2f} | {row[2]:.2f} | {row[2] - row[0]:+.2f} |")
        m = np.mean(rows, axis=0)
        say(f"| mean ({reset}) | {m[0]:.2f} | {m[1]:.2f} | {m[2]:.2f} | {m[2] - m[0]:+.2f} |")
        gains[reset] = float(m[2] - m[0])
    return gains


def compare(folder: str, seed: int = 0) -> None:
    """The gate without and with the frame features, fitted on the cached training frames (``PIXELS`` a frame, seed
    ``seed``), scored on the development set and the real streams."""
    _cached_recipe(Path(folder))
    print("| gate (seed) | development: mean gain, paper's pixel / reset by subtraction | real streams | real mean |")
    print("|---|---:|---:|---:|")
    for frame in (False, True):
        recipe = RawGateRecipe(gate=RawGateConfig(tfi_window=4, long_window=16, frame_features=frame), pixels=PIXELS, **ONE_FIT,
                               seed=seed)
        samples: GateSamples = recipe_module.gather_samples(recipe, default_model_path("binned"))
        gate = fit_gate(samples, recipe)[0]
        dev, real = score(folder, gate, "development", quiet=True), score(folder, gate, "real", quiet=True)
        streams = " / ".join(f"{v:.2f}" for k, v in real.items() if k != "mean")
        print(f"| {'with' if frame else 'without'} frame features ({seed}) | {dev['zero']:+.2f} / "
              f"{dev['subtract']:+.2f} | {streams} | {real['mean']:.2f} |", flush=True)


def fit(folder: str, out: str) -> None:
    """The recipe's gate (``rmbvideo train-raw-gate`` with no options), fitted on the cached training frames."""
    _cached_recipe(Path(folder))
    print(recipe_module.fit_raw_gate(RawGateRecipe(), Path(out)))


if __name__ == "__main__":
    torch.set_num_threads(1)
    command, args = sys.argv[1], sys.argv[2:]
    if command == "cache":
        cache(*args)
    elif command == "compare":
        compare(args[0], int(args[1]) if len(args) > 1 else 0)
    elif command == "fit":
        fit(*args)
    else:
        score(*args)
