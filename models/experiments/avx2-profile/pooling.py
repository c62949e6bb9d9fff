"""``rmbvideo.net.pooling``'s area means against ``F.avg_pool2d`` on the shapes the default job pools (one thread,
medians of 200 calls, microseconds), with a check that the values are the same bit for bit.
Run from the repository root: python models/experiments/avx2-profile/pooling.py
"""

import statistics
import time

import torch
import torch.nn.functional as F

from rmbvideo.net.pooling import mean_2x2, mean_3x3

torch.set_num_threads(1)


def microseconds(call) -> float:
    call()
    times = []
    for _ in range(200):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e6


generator = torch.Generator().manual_seed(0)
for label, x, ours, theirs in (
        ("2x2 mean, 1x250x400", torch.rand(1, 1, 250, 400, generator=generator), mean_2x2, lambda t: F.avg_pool2d(t, 2)),
        ("2x2 mean, 5x250x400", torch.rand(1, 5, 250, 400, generator=generator), mean_2x2, lambda t: F.avg_pool2d(t, 2)),
        ("3x3 mean, 1x127x202", torch.rand(1, 1, 127, 202, generator=generator), mean_3x3,
         lambda t: F.avg_pool2d(t, 3, stride=1))):
    assert torch.equal(ours(x), theirs(x))
    print(f"{label}: avg_pool2d {microseconds(lambda: theirs(x)):.0f} us, strided sums {microseconds(lambda: ours(x)):.0f} us")
