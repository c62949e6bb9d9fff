"""The detail stage's four convolutions chained on one 400x250 frame (channels-last, one thread), under glibc's
allocator thresholds as they are and as ``rmbvideo.allocator`` may set them: medians of 15 passes.
Run from the repository root, each setting in a fresh process:

    for mode in none trim mmap32 trim+mmap32; do python models/experiments/avx2-profile/allocator.py $mode; done
"""

import ctypes
import statistics
import sys
import time

mode = sys.argv[1] if len(sys.argv) > 1 else "none"
libc = ctypes.CDLL(None)
if "trim" in mode:
    libc.mallopt(-1, 1 << 30)  # M_TRIM_THRESHOLD
if "mmap32" in mode:
    libc.mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD

import torch  # noqa: E402  (after the allocator is set, as the CLI does)

import rmbvideo.net.weights as weights  # noqa: E402

torch.set_num_threads(1)
model = weights.load_detail_model(weights.default_detail_path())
model = (model[0] if isinstance(model, tuple) else model).eval()
features = torch.randn(1, 11, 250, 400).contiguous(memory_format=torch.channels_last)
with torch.no_grad():
    model.body(features)
    times = []
    for _ in range(15):
        start = time.perf_counter()
        model.body(features)
        times.append(time.perf_counter() - start)
print(f"{mode}: the chained convolutions {statistics.median(times) * 1e3:.1f} ms a pass")
