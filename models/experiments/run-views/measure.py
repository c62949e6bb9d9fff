"""A batched pass's windows as views of one encode call's features, against copies (``RmbNet.step_run``'s
``_consecutive_view`` turned off): the encoders and a pass at 200x125, one thread, the two alternated in one process
(ABBA order, each with its own carried state), the median of the per-round ratios. Run from the repository root:

    python models/experiments/run-views/measure.py [fp32|bf16] [ROUNDS] [FRAMES]
"""

import statistics
import sys
import time

import torch

from rmbvideo.bench.network import _inputs
from rmbvideo.net import model as net_model
from rmbvideo.net.weights import default_model_path, load_model
from rmbvideo.recon.rmbnet import inference_copy


def main(precision: str = "bf16", rounds: int = 10, count: int = 64) -> None:
    torch.set_num_threads(1)
    model = load_model(default_model_path())[0].eval()
    i_s, i_m, i_c, aligned = _inputs(model, 200, 125, count, torch.device("cpu"))
    frames = range(count + 2 * model.config.w)
    bf16 = precision == "bf16"
    net = inference_copy(model, bf16=bf16)
    views = net_model._consecutive_view
    states: dict = {"views": None, "copies": None}
    passes: dict = {"views": [], "copies": []}
    totals: dict = {"views": [], "copies": []}
    outputs = {}
    for r in range(rounds):
        for variant in (("views", "copies") if r % 2 else ("copies", "views")):
            net_model._consecutive_view = views if variant == "views" else (lambda tensors: None)
            with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                began = time.perf_counter()
                encoded = net.encode(i_s, i_m, frames, i_c)
                middle = time.perf_counter()
                outputs[variant], states[variant] = net.step_run(encoded, states[variant], aligned=aligned)
                ended = time.perf_counter()
            passes[variant].append(ended - middle)
            totals[variant].append(ended - began)
    net_model._consecutive_view = views
    for name, times in (("pass", passes), ("encoders + pass", totals)):
        ratio = statistics.median(c / v for c, v in zip(times["copies"], times["views"]))
        print(f"{precision} {name}: copies {1e3 * statistics.median(times['copies']) / count:.2f} ms a frame, "
              f"views {1e3 * statistics.median(times['views']) / count:.2f}, median ratio {ratio:.3f}")
    print("outputs bit for bit equal:", torch.equal(outputs["views"], outputs["copies"]))


if __name__ == "__main__":
    main(*(f(a) for f, a in zip((str, int, int), sys.argv[1:])))
