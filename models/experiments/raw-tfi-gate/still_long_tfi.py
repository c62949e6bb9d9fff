"""Would a longer TFI candidate help the gate on still scenes? (the stop of 2026-11-29, fifth; tried, not built)

On the development texture pans' still clips the gate lowers RMB-Net's frame (c16-v00 47.72 -> 44.92 dB) while TFI
over 64 or 128 central planes reads them at 53-58 dB (noise-free, display-referred spikes: a longer span only
shrinks the one-spike quantisation). Here the same question on still captures of evaluation seeds (``still_scenes.py``'s
kinds: spikezoo's convention, a camera's two pixels), two of each: mean mu-law PSNR of the frames away from the
clip's edges for RMB-Net's binned frame, the shipped gate, and TFI-16/64/128 on the raw capture (2x2-averaged).
Run from the repository root, one thread (about 8 minutes): python models/experiments/raw-tfi-gate/still_long_tfi.py
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from still_scenes import EVAL_FIRST, KINDS  # noqa: E402

from rmbvideo.evaluate.harness import SATURATION, MethodSpec, run_frames  # noqa: E402
from rmbvideo.evaluate.heldout import FULL, simulate_video_sequence  # noqa: E402
from rmbvideo.evaluate.metrics import mu_law_psnr  # noqa: E402
from rmbvideo.net.weights import default_model_path, default_raw_gate_path, load_raw_gate  # noqa: E402
from rmbvideo.train.raw_gate import gate_frames  # noqa: E402

WINDOWS = (16, 64, 128)
EDGE = 8  # frames left out at each end


def main() -> None:
    torch.set_num_threads(1)
    gate = load_raw_gate(default_raw_gate_path())[0]
    model = default_model_path("binned")
    tensor = lambda x: torch.from_numpy(np.ascontiguousarray(x, np.float32))[None, None]  # noqa: E731
    print("| capture | RMB-Net (binned) | shipped gate | " + " | ".join(f"TFI-{w}" for w in WINDOWS) + " |")
    print("|---|" + "---:|" * (2 + len(WINDOWS)))
    for k, (kind, reset) in enumerate(KINDS):
        for j in range(2):
            seq = simulate_video_sequence(EVAL_FIRST + 100 * k + j, kind, replace(FULL, reset=reset), training=False)
            frames = gate_frames(seq, model, gate.config)
            tfi = {w: {f.index: f.image for f in run_frames(MethodSpec(f"TFI-{w}", "tfi", {
                "step": 20, "max_reach": gate.config.tfi_reach, "window": w}, raw=True), seq)[0]} for w in WINDOWS}
            code = float(kind.convention != "physical")
            scores: dict[str, list[float]] = {"binned": [], "gate": [], **{str(w): [] for w in WINDOWS}}
            for i in range(EDGE, len(frames) - EDGE):
                frame, truth = frames[i], np.minimum(seq.gt[i], SATURATION)
                with torch.no_grad():
                    mixed = gate(tensor(frame.binned), tensor(frame.tfi), tensor(frames[i - 1].binned), code,
                                 *(tensor(x) for x in frame.candidates[1:]))[0, 0].numpy()
                scores["binned"].append(mu_law_psnr(frame.binned, truth))
                scores["gate"].append(mu_law_psnr(mixed, truth))
                for w in WINDOWS:
                    scores[str(w)].append(mu_law_psnr(tfi[w][i], truth))
            print(f"| {kind.name} ({reset}) {seq.name} | " + " | ".join(f"{np.mean(v):.2f}" for v in scores.values())
                  + " |", flush=True)


if __name__ == "__main__":
    main()
