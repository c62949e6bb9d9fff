"""Does the gate gain from seeing its neighbourhood? A gate of 3x3 convolutions against the shipped per-pixel one.

The shipped gate (``rmbvideo.net.raw_gate``) reads each pixel's features alone (its 1x1 network; the features carry
some 3x3 roughness) and mixes RMB-Net's binned frame with raw TFI-4 and TFI-16. A gate whose first two layers are
3x3 convolutions sees a 5x5 neighbourhood of the features: whether an edge is near, whether TFI's disagreement is a
lone pixel (noise) or a region (motion or real detail). Both are trained here the same way, on random crops of the
recipe's 47 cached training captures (``frame_features.py cache``: the 44 ``train-*`` and the three still
display-referred ``candidate-still-still-display-zero-*``), to the recipe's loss (mu-law MSE after dividing by each
frame's robust truth scale), and scored on the cached development set (mean gain over the binned frame, both pixels),
the texture pans and the real streams' reference frames, beside the shipped gate. Run from the repository root, one
thread:

    python models/experiments/raw-tfi-gate/spatial_gate.py train DIR OUT.safetensors [kernel] [minutes] [seed]
    python models/experiments/raw-tfi-gate/spatial_gate.py score DIR OUT.safetensors|GATE.safetensors [development|heldout]
        [BEFORE.safetensors]

DIR is made by ``frame_features.py cache DIR ../shared/data/spikezoo-base`` (the recipe's captures, the development
and held-out sets, the real streams; about 25 minutes) and ``still_scenes.py cache DIR PANS`` (the texture pans'
reference frames, ``pan-*``; PANS is ``texture_pans.texture_pan_folder``'s folder, written by ``rmbvideo evaluate
--texture-pans``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import torch
from safetensors import safe_open
from safetensors.torch import save_file
from torch import nn

sys.path.insert(0, str(Path(__file__).parent))
import frame_features as ff  # noqa: E402

from rmbvideo.evaluate.metrics import mu_law_psnr, robust_scale  # noqa: E402
from rmbvideo.evaluate.real_video import scaled_psnr  # noqa: E402
from rmbvideo.mulaw import mu_law  # noqa: E402
from rmbvideo.net.raw_gate import INITIAL_LOGIT, RawGate, gate_features  # noqa: E402
from rmbvideo.net.weights import default_raw_gate_path, load_raw_gate  # noqa: E402
from rmbvideo.train.raw_gate import LOSS_MU  # noqa: E402

CROP = 48
BATCH = 16


class ConvGate(nn.Module):
    """A gate of ``kernel`` x ``kernel`` convolutions (two, then a 1x1 to the candidates' logits) on standardised
    ``gate_features``; the mixing is the shipped gate's (a softmax beside RMB-Net's fixed 0)."""

    def __init__(self, count: int, kernel: int, hidden: int = 16) -> None:
        super().__init__()
        pad = kernel // 2
        self.register_buffer("mean", torch.zeros(count))
        self.register_buffer("std", torch.ones(count))
        self.body = nn.Sequential(nn.Conv2d(count, hidden, kernel, padding=pad, padding_mode="replicate"), nn.ReLU(),
                                  nn.Conv2d(hidden, hidden, kernel, padding=pad, padding_mode="replicate"), nn.ReLU(),
                                  nn.Conv2d(hidden, 2, 1))
        with torch.no_grad():
            self.body[-1].bias.fill_(INITIAL_LOGIT)
        self.kernel = kernel

    def mix(self, features: torch.Tensor, binned: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
        logits = self.body((features - self.mean.reshape(1, -1, 1, 1)) / self.std.reshape(1, -1, 1, 1))
        share = torch.softmax(torch.cat([torch.zeros_like(logits[:, :1]), logits], dim=1), dim=1)[:, 1:]
        return (1.0 - share.sum(1, keepdim=True)) * binned + (share * candidates).sum(1, keepdim=True)


def _t(x: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(x, np.float32))


def frame_inputs(binned, tfi, long, previous, convention: float) -> torch.Tensor:  # noqa: ANN001
    """(1, F, H, W) features as the shipped gate computes them (frame features included)."""
    return gate_features(_t(binned)[None, None], _t(tfi)[None, None], _t(previous)[None, None], convention,
                         _t(long)[None, None], frame=True)


def training_paths(folder: Path) -> list[Path]:
    """The recipe's 47 cached captures: ``train-*`` (the three still display-referred ones among them in a cache made
    since the recipe had them, else ``still_scenes.py``'s ``candidate-still-still-display-zero-*``)."""
    paths = sorted(folder.glob("train-*.npz"))
    if not any("still-display" in p.name for p in paths):
        paths += sorted(folder.glob("candidate-still-still-display-zero-*.npz"))
    return paths


def load_training(folder: Path) -> tuple[torch.Tensor, ...]:
    """Every cached training frame: features (N, F, H, W), binned, candidates (N, 2, H, W) and truth, the images
    divided by their frame's robust truth scale."""
    feats, binned, cands, truth = [], [], [], []
    for path in training_paths(folder):
        d = dict(np.load(path))
        previous = d["binned"][0]
        for i in range(len(d["binned"])):
            scale = robust_scale(d["truth"][i])
            feats.append(frame_inputs(d["binned"][i], d["tfi"][i], d["long"][i], previous, float(d["convention"]))[0])
            binned.append(_t(d["binned"][i] / scale)[None])
            cands.append(_t(np.stack([d["tfi"][i], d["long"][i]]) / scale))
            truth.append(_t(d["truth"][i] / scale)[None])
            previous = d["binned"][i]
    return torch.stack(feats), torch.stack(binned), torch.stack(cands), torch.stack(truth)


def loss_of(mixed: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    tone = lambda v: mu_law(v.clamp(0.0, 1.0), LOSS_MU)  # noqa: E731
    return ((tone(mixed) - tone(truth)) ** 2).mean()


def train(folder: str, out: str, kernel: str = "3", minutes: str = "20", seed: str = "0") -> None:
    torch.manual_seed(int(seed))
    rng = np.random.default_rng(int(seed))
    feats, binned, cands, truth = load_training(Path(folder))
    n, count, height, width = feats.shape
    gate = ConvGate(count, int(kernel))
    with torch.no_grad():
        gate.mean.copy_(feats.mean(dim=(0, 2, 3)))
        gate.std.copy_(feats.std(dim=(0, 2, 3)).clamp(min=1e-6))
    optimiser = torch.optim.Adam(gate.body.parameters(), lr=3e-3)
    budget, began, step, running = float(minutes) * 60, time.monotonic(), 0, []
    print(f"{n} frames, {count} features; kernel {kernel}", flush=True)
    while time.monotonic() - began < budget:
        frac = (time.monotonic() - began) / budget
        for group in optimiser.param_groups:
            group["lr"] = 3e-4 + 0.5 * (3e-3 - 3e-4) * (1 + np.cos(np.pi * frac))
        k = rng.integers(0, n, BATCH)
        y = rng.integers(0, height - CROP + 1, BATCH)
        x = rng.integers(0, width - CROP + 1, BATCH)
        def crop(a: torch.Tensor) -> torch.Tensor:
            return torch.stack([a[k[j], :, y[j]:y[j] + CROP, x[j]:x[j] + CROP] for j in range(BATCH)])
        loss = loss_of(gate.mix(crop(feats), crop(binned), crop(cands)), crop(truth))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        running.append(float(loss.detach()))
        step += 1
        if step % 500 == 0:
            print(f"step {step} {time.monotonic() - began:.0f}s loss {np.mean(running[-500:]):.6f}", flush=True)
    with torch.no_grad():  # the whole training set's loss, frame by frame
        full = np.mean([float(loss_of(gate.mix(feats[i:i + 1], binned[i:i + 1], cands[i:i + 1]), truth[i:i + 1]))
                        for i in range(n)])
    print(f"done: {step} steps, training loss {full:.6f}", flush=True)
    save_file(gate.state_dict(), out, metadata={"kernel": kernel, "count": str(count)})


def load_gate(path: str) -> ConvGate:
    """A gate this script wrote (safetensors: tensors only, its shape in the metadata)."""
    with safe_open(path, framework="pt") as handle:
        meta = handle.metadata()
        state = {key: handle.get_tensor(key) for key in handle.keys()}
    gate = ConvGate(int(meta["count"]), int(meta["kernel"]))
    gate.load_state_dict(state)
    return gate.eval()


@torch.no_grad()
def mixed_frame(gate: ConvGate | RawGate, binned, tfi, long, previous, convention: float) -> np.ndarray:  # noqa: ANN001
    if isinstance(gate, RawGate):
        t = lambda a: _t(a)[None, None]  # noqa: E731
        return gate(t(binned), t(tfi), t(previous), convention, t(long))[0, 0].numpy()
    feats = frame_inputs(binned, tfi, long, previous, convention)
    return gate.mix(feats, _t(binned)[None, None], _t(np.stack([tfi, long]))[None])[0, 0].numpy()


def score(folder: str, path: str, which: str = "development", before: str | None = None) -> None:
    """The gate at ``path`` (this script's, or a gate weight file with its card) beside ``before`` (default: the shipped
    gate) on the cached ``which`` set, the texture pans and the real streams."""
    other = load_raw_gate(before or default_raw_gate_path())[0].eval()
    gates = {"before": other, Path(path).stem: load_gate(path) if not Path(path).with_suffix(".json").is_file() else
             load_raw_gate(path)[0].eval()}
    names = list(gates)
    print(f"| sequence | binned | {' | '.join(names)} |\n|---|---:|" + "---:|" * len(names))
    for reset, sequences in ff._evaluation_sets(which).items():
        rows = []
        for seq in sequences:
            d = dict(np.load(Path(folder) / f"{which}-{reset}-{seq.name}.npz"))
            row = [np.mean([mu_law_psnr(d["binned"][i], d["truth"][i]) for i in seq.scored_frames])]
            for gate in gates.values():
                frames = [mixed_frame(gate, d["binned"][i], d["tfi"][i], d["long"][i], d["binned"][max(i - 1, 0)],
                                      float(d["convention"])) for i in range(len(d["binned"]))]
                row.append(np.mean([mu_law_psnr(frames[i], d["truth"][i]) for i in seq.scored_frames]))
            rows.append(row)
            print(f"| {seq.name} ({reset}) | " + " | ".join(f"{v:.2f}" for v in row) + " |", flush=True)
        m = np.mean(rows, axis=0)
        print(f"| **mean ({reset})** | {m[0]:.2f} | " + " | ".join(f"{v:.2f} ({v - m[0]:+.2f})" for v in m[1:]) + " |")
    for prefix in ("pan", "real"):
        rows = []
        for p in sorted(Path(folder).glob(f"{prefix}-*.npz")):
            d = dict(np.load(p))
            row = [scaled_psnr(d["binned"], d["reference"])]
            row += [scaled_psnr(mixed_frame(g, d["binned"], d["tfi"], d["long"], d["previous"], float(d["convention"])),
                                d["reference"]) for g in gates.values()]
            rows.append(row)
            print(f"| {p.stem} | " + " | ".join(f"{v:.2f}" for v in row) + " |", flush=True)
        m = np.mean(rows, axis=0)
        print(f"| **mean ({prefix})** | " + " | ".join(f"{v:.2f}" for v in m) + " |")


if __name__ == "__main__":
    torch.set_num_threads(1)
    command, args = sys.argv[1], sys.argv[2:]
    {"train": train, "score": score}[command](*args)
