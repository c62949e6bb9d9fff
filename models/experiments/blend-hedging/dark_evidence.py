"""Two development-set findings of the stop of 2026-11-27 (d), the shipped model at inference, no retraining. Run from
the repository root (a few minutes each on one core; pictures into OUT, default /tmp):

    python models/experiments/blend-hedging/dark_evidence.py mover [OUT]      # fast-dark-207 frame 10, every method
    python models/experiments/blend-hedging/dark_evidence.py gate 1,3 [OUT]   # the robust merge's weight ** p
    python models/experiments/blend-hedging/dark_evidence.py subtract         # random-1000050, both pixels

``mover``: the truth, the default, the aligned mean it reads (gain-scaled to the truth) and the baselines on the same
input at the fast-dark clip's middle frame, its PSNR and the clip's. ``gate``: the development video sequences with
the merge's weight min(1, tau / z^2) raised to each power p (1 is the shipped merge). ``subtract``: the default and
the baselines on a bright development pan from the paper's reset-to-zero pixel and from a pixel reset by subtraction.
"""

import sys
from pathlib import Path

import cv2
import numpy as np

import rmbvideo.recon.aligned_box as aligned_module
from rmbvideo.evaluate.harness import SATURATION, MethodSpec, baseline_specs, run_frames, score_frames
from rmbvideo.evaluate.heldout import load_development
from rmbvideo.evaluate.metrics import robust_scale
from rmbvideo.mulaw import mu_law

DEFAULT = MethodSpec("default", "rmbnet", {"threads": 1, "input_mode": "binned", "precision": "fp32"}, "pure-m")


def frames_of(spec: MethodSpec, seq) -> dict[int, np.ndarray]:
    return {f.index: f.image for f in run_frames(spec, seq)[0]}


def score(images: dict[int, np.ndarray], seq) -> float:
    return score_frames({i: images[i] for i in seq.scored_frames}, seq)[0]


def mover(out: str = "/tmp") -> None:
    kept = {}
    original = aligned_module.AlignedBox.mean

    def keep(self, i, neighbours, statistics=False):
        result = original(self, i, neighbours, statistics)
        kept[i] = result[0] if statistics else result
        return result

    aligned_module.AlignedBox.mean = keep
    seq = next(s for s in load_development() if s.name == "fast-dark-207")
    i = 10
    truth = np.minimum(seq.gt[i], SATURATION)
    scale = robust_scale(truth)
    tiles = [truth]
    for spec in [DEFAULT, *baseline_specs("pure-m")]:
        images = frames_of(spec, seq)
        print(f"{spec.name}: frame {i} {score_frames({i: images[i]}, seq)[0]:.2f} dB, clip {score(images, seq):.2f} dB")
        tiles.append(images[i])
        if spec is DEFAULT:
            mean = kept[i][0] if kept[i].ndim == 3 else kept[i]
            tiles.append(mean * float(np.sum(mean * truth) / max(np.sum(mean * mean), 1e-12)))
    aligned_module.AlignedBox.mean = original
    tone = [(255 * mu_law(np.clip(t / scale, 0, 1))).astype(np.uint8) for t in tiles]
    grid = np.vstack([np.hstack(tone[:4]), np.hstack(tone[4:8])])
    path = Path(out) / "fast-dark-207-frame10.png"
    cv2.imwrite(str(path), cv2.resize(grid, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST))
    print(f"{path}: truth, default, aligned mean x gain, TFW-S, TFW-L, TFI, GC20, MG20")


def gate(powers: str = "1,3") -> None:
    merge = aligned_module._RobustMerge
    power = [1.0]

    def add(self, warped, inside):
        z = aligned_module._arcsine_sqrt(self._local(warped)) - self._angle
        z2 = np.maximum(np.square(z) / self._variance, 1e-12)
        weight = np.minimum(self._tau / z2, 1.0) ** power[0] * inside
        self._weights += weight
        self._total += weight * warped
        if self._squares is not None:
            self._squares += weight * warped * warped

    merge.add = add
    sequences = [s for s in load_development() if s.name in ("random-1000050", "fast-7", "dark-107", "fast-dark-207")]
    for p in map(float, powers.split(",")):
        power[0] = p
        scores = {seq.name: score(frames_of(DEFAULT, seq), seq) for seq in sequences}
        line = ", ".join(f"{k} {v:.2f}" for k, v in scores.items())
        print(f"p = {p:g}: {line}; mean {np.mean(list(scores.values())):.2f}")


def subtract() -> None:
    name = "random-1000050"
    for reset in ("zero", "subtract"):
        seq = next(s for s in load_development(reset=reset) if s.name == name)
        for spec in [DEFAULT, *baseline_specs("pure-m")]:
            print(f"{name} ({reset}) {spec.name}: {score(frames_of(spec, seq), seq):.2f} dB", flush=True)
    truth = next(s for s in load_development() if s.name == name).gt
    print(f"truth: median {np.median(truth):.3f} of full scale")


if __name__ == "__main__":
    {"mover": mover, "gate": gate, "subtract": subtract}[sys.argv[1]](*sys.argv[2:])
