"""A batched pass's windows as views of one encode call's features, against copies (``RmbNet.step_run``'s
``_consecutive_view`` turned off): the encoders and a pass at 200x125, one thread, the two alternated in one process
(ABBA order, each with its own carried state), the median of the per-round ratios. ``step``: the engine's CPU path,
frame by frame (``bench network``'s ``_frame_by_frame``), against a pass with views, the same way. Run from the
repository root:

    python models/experiments/run-views/measure.py [fp32|bf16] [ROUNDS] [FRAMES] [step]
"""

import statistics
import sys
import time

import torch

from rmbvideo.bench.network import _frame_by_frame, _inputs
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


def frame_by_frame(precision: str = "bf16", rounds: int = 8, count: int = 32) -> None:
    """The engine's CPU path (encoders in its batches, then ``step`` with the pair cache) against a pass with views."""
    torch.set_num_threads(1)
    model = load_model(default_model_path())[0].eval()
    inputs = _inputs(model, 200, 125, count, torch.device("cpu"))
    bf16 = precision == "bf16"
    net = inference_copy(model, bf16=bf16)
    times: dict = {"frame by frame": [], "pass": []}
    for r in range(rounds):
        for variant in (("frame by frame", "pass") if r % 2 else ("pass", "frame by frame")):
            with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                began = time.perf_counter()
                if variant == "pass":
                    i_s, i_m, i_c, aligned = inputs
                    net.step_run(net.encode(i_s, i_m, range(count + 2 * model.config.w), i_c), None, aligned=aligned)
                else:
                    _frame_by_frame(net, inputs, count)
                times[variant].append(time.perf_counter() - began)
    ratio = statistics.median(p / f for p, f in zip(times["pass"], times["frame by frame"]))
    print(f"{precision}: frame by frame {1e3 * statistics.median(times['frame by frame']) / count:.2f} ms a frame, "
          f"pass {1e3 * statistics.median(times['pass']) / count:.2f}, median ratio pass / frame by frame {ratio:.3f}")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "step"]
    run = frame_by_frame if "step" in sys.argv[1:] else main
    run(*(f(a) for f, a in zip((str, int, int), args)))
