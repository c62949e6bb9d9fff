"""How GC20 and MG20 read light, on the development sequences only (never the held-out ones). Run from the repository
root (each a few minutes on one core):

    python models/experiments/baseline-response/measure.py physical  # reset-to-zero pixel: GC20's Poisson jots against
                                                                     # the firing-rate MLE read through the emission
                                                                     # model's response, as TFW's rows are read
    python models/experiments/baseline-response/measure.py leads     # both pixels: every method on the default's input
                                                                     # (GC20/MG20 told the convention) and the default's
                                                                     # lead over the best of them
    python models/experiments/baseline-response/measure.py inverse   # instant: GC20's Poisson inverse -ln(1 - r) of the
                                                                     # binned rate r of rmbvideo's camera (its tabulated
                                                                     # response) and of the rate convention, over light
"""

import sys

import numpy as np
import torch

from rmbvideo.evaluate.harness import BASELINE_SPECS, MethodSpec, run_frames, run_method, score_frames
from rmbvideo.evaluate.heldout import default_cache_dir, load_development
from rmbvideo.net.blend import reset_to_zero_intensity
from rmbvideo.net.weights import default_model_path, model_readout

READOUT = model_readout(default_model_path("binned"))


def physical() -> None:
    print("| sequence | GC20, Poisson | GC20, rate + response | MG20, Poisson | MG20, rate + response |")
    print("|---|---:|---:|---:|---:|")
    for seq in load_development(default_cache_dir()):
        if "spikezoo" in seq.name:
            continue  # the rate convention: no reset-to-zero response to read
        cells = []
        for method in ("gc20", "mg20"):
            for response in ("poisson", "rate"):
                frames, _, _ = run_frames(MethodSpec(method, method, {"response": response}, READOUT), seq)
                images = {f.index: f.image for f in frames if f.index in seq.scored_frames}
                if response == "rate":
                    images = {i: reset_to_zero_intensity(torch.from_numpy(np.ascontiguousarray(image))).numpy()
                              for i, image in images.items()}
                cells.append(f"{score_frames(images, seq)[0]:.2f}")
        print(f"| {seq.name} | {' | '.join(cells)} |", flush=True)


def leads() -> None:
    specs = [MethodSpec(s.name, s.method, s.options, READOUT) for s in BASELINE_SPECS if s.name != "TFI"]
    default = MethodSpec("RMB-Net", "rmbnet", {"threads": 1}, READOUT)
    print(f"| pixel | sequence | {' | '.join(s.name for s in specs)} | RMB-Net | lead over the best |")
    print("|---|---|" + "---:|" * (len(specs) + 2))
    for reset in ("zero", "subtract"):
        for seq in load_development(default_cache_dir(), reset=reset):
            scores = {s.name: run_method(s, seq).psnr for s in (*specs, default)}
            best = max((name for name in scores if name != default.name), key=scores.get)
            cells = " | ".join(f"{scores[s.name]:.2f}" for s in (*specs, default))
            print(f"| {reset} | {seq.name} | {cells} | {scores[default.name] - scores[best]:+.2f} ({best}) |", flush=True)


def inverse() -> None:
    """The light the Poisson model reads from each pixel's binned rate, over the true light (1 = exact)."""
    from rmbvideo.net.blend import RESET_TO_ZERO_RATES, RESET_TO_ZERO_STEP, rate_convention_rate

    print("| light (threshold per plane) | rmbvideo's camera (reset to zero) | rate convention |")
    print("|---:|---:|---:|")
    for k in range(2, 45, 2):
        light = k * RESET_TO_ZERO_STEP
        rate_convention = float(rate_convention_rate(torch.tensor(min(light, 1.0), dtype=torch.float64)))
        cells = [-np.log1p(-rate) / light for rate in (RESET_TO_ZERO_RATES[k], rate_convention)]
        print(f"| {light:.2f} | {cells[0]:.3f} | {cells[1]:.3f} |")


if __name__ == "__main__":
    {"physical": physical, "leads": leads, "inverse": inverse}[sys.argv[1]]()
