"""What a slimmer RMB-Net would run at: the network alone, frame by frame at 200x125 binned, one thread, fp32 (the
speed issue's CPU target, 50 frames/s, on the host at hand), for the shipped default's architecture and for slimmer
variants of it. The weights are random: a network's time does not depend on them, and none of the variants is trained,
so this says which architecture could meet the target, not what it would score. Each round times every variant once,
in turn (so a busy moment hits them alike); medians over the rounds, and each variant's ratio to the shipped one.

    python models/experiments/slim-speed/measure.py [ROUNDS]   # default 5; about 20 s a round on an AVX2 core
"""

import dataclasses
import statistics
import sys

import torch

from rmbvideo.bench.network import _frame_by_frame, _inputs
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import default_model_path, load_model
from rmbvideo.recon.rmbnet import inference_copy

#: (name, changes to the shipped config): channels are the encoder blocks' (the shipped 0.5 x 24/32/48 = 12/16/24)
VARIANTS = (
    ("shipped (12/16/24, 5x5 encoders)", {}),
    ("3x3 encoders", {"encoder_kernel": 3}),
    ("8/16/24", {"width": 1.0, "base_channels": (8, 16, 24)}),
    ("8/16/24, 3x3 encoders", {"width": 1.0, "base_channels": (8, 16, 24), "encoder_kernel": 3}),
    ("8/8/16, 3x3 encoders", {"width": 1.0, "base_channels": (8, 8, 16), "encoder_kernel": 3}),
    ("8/16/16, 3x3 encoders, half attention", {"width": 1.0, "base_channels": (8, 16, 16), "encoder_kernel": 3,
                                              "attention_hidden": 0.5}),
)
WIDTH, HEIGHT, FRAMES = 200, 125, 48


def main(rounds: int) -> None:
    torch.set_num_threads(1)
    shipped = load_model(default_model_path())[0].config
    nets = []
    for name, changes in VARIANTS:
        model = RmbNet(dataclasses.replace(shipped, **changes)).eval()
        params = sum(p.numel() for p in model.parameters())
        nets.append((name, inference_copy(model), _inputs(model, WIDTH, HEIGHT, FRAMES, torch.device("cpu")), params))
    times: dict[str, list[float]] = {name: [] for name, *_ in nets}
    with torch.inference_mode():
        for name, net, inputs, _ in nets:  # warm-up
            _frame_by_frame(net, inputs, FRAMES)
        for _ in range(rounds):
            for name, net, inputs, _ in nets:
                encode, steps = _frame_by_frame(net, inputs, FRAMES)
                times[name].append(1e3 * (encode + steps) / FRAMES)
    reference = statistics.median(times[nets[0][0]])
    print(f"| variant | parameters | ms a frame | frames/s | x shipped |\n|---|---:|---:|---:|---:|")
    for name, _, _, params in nets:
        ms = statistics.median(times[name])
        print(f"| {name} | {params / 1e6:.3f} M | {ms:.1f} | {1e3 / ms:.1f} | {reference / ms:.2f} |")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
