"""The detail stage's forward on one 400x250 frame: the convolution stack on channels-last features (the shipped
forward) against the default layout (the forward before the stop of 2026-11-29), alternated 15 times in one process,
one thread; medians of ms. ``engine``: the stage as the full-resolution engine holds it (``detail_inference_copy``:
weights channels-last), where the two read the same. Run from the repository root:

    python models/experiments/avx2-profile/detail_ab.py [loaded|engine]
"""

import statistics
import sys
import time

import torch

import rmbvideo.net.weights as weights
from rmbvideo.net.detail import block_mean, to_block_levels, upsample
from rmbvideo.recon.full_resolution import detail_inference_copy

torch.set_num_threads(1)
model = weights.load_detail_model(weights.default_detail_path())[0].eval()
if len(sys.argv) > 1 and sys.argv[1] == "engine":
    model = detail_inference_copy(model, "fp32", "cpu")
generator = torch.Generator().manual_seed(0)
binned = torch.rand(1, 1, 125, 200, generator=generator)
rates = torch.rand(1, model.config.rate_channels, 250, 400, generator=generator) * 0.5


def before() -> torch.Tensor:
    """The forward before: the features in the default layout."""
    b, r = binned.clamp(min=0.0), rates.clamp(0.0, 1.0)
    up = upsample(b)
    d = model.body(model.features(up, r)).float()
    d = d - block_mean(d)
    return to_block_levels(up * (1.0 + d).clamp(min=0.0), b)


def after() -> torch.Tensor:
    return model(binned, rates)


with torch.no_grad():
    difference = (before() - after()).abs().max().item()
    times = {"default layout": [], "channels-last": []}
    for _ in range(15):
        for name, forward in (("default layout", before), ("channels-last", after)):
            start = time.perf_counter()
            forward()
            times[name].append(time.perf_counter() - start)
print(f"max |difference| {difference:.2e}")
for name, values in times.items():
    print(f"{name}: {statistics.median(values) * 1e3:.1f} ms (min {min(values) * 1e3:.1f})")
print(f"ratio {statistics.median(times['default layout']) / statistics.median(times['channels-last']):.2f}")
