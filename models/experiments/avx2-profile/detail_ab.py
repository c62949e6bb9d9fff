"""The detail stage's forward on one 400x250 frame: the convolution stack on channels-last features (the shipped
forward) against the default layout (the forward before the stop of 2026-11-29), alternated 15 times in one process,
one thread; medians of ms. Run from the repository root: python models/experiments/avx2-profile/detail_ab.py
"""

import statistics
import time

import torch
import torch.nn.functional as F
import rmbvideo.net.weights as W
from rmbvideo.net.detail import block_mean, to_block_levels, upsample
torch.set_num_threads(1)
m = W.load_detail_model(W.default_detail_path())
m = (m[0] if isinstance(m, tuple) else m).eval()
g = torch.Generator().manual_seed(0)
binned = torch.rand(1, 1, 125, 200, generator=g)
rates = torch.rand(1, m.config.rate_channels, 250, 400, generator=g) * 0.5

def before():
    b, r = binned.clamp(min=0.0), rates.clamp(0.0, 1.0)
    up = upsample(b)
    d = m.body(m.features(up, r)).float()
    d = d - block_mean(d)
    return to_block_levels(up * (1.0 + d).clamp(min=0.0), b)

after = lambda: m(binned, rates)
with torch.no_grad():
    diff = (before() - after()).abs().max().item()
    times = {"default layout": [], "channels-last": []}
    for _ in range(15):
        for name, f in (("default layout", before), ("channels-last", after)):
            s = time.perf_counter(); f(); times[name].append(time.perf_counter() - s)
print(f"max |difference| {diff:.2e}")
for name, v in times.items():
    print(f"{name}: {statistics.median(v) * 1e3:.1f} ms (min {min(v) * 1e3:.1f})")
print(f"ratio {statistics.median(times['default layout']) / statistics.median(times['channels-last']):.2f}")
