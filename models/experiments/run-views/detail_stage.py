"""The detail stage's inference copy against the stage as it was at a commit (``REV``; by default cc349c6~1, the
stage before its inputs were written once into the convolutions' layout): one 400x250 frame, one thread, the two
alternated in one process (ABBA), the median of the per-round ratios, and the largest difference of their outputs. The
old ``rmbvideo/net/detail.py`` is read from the repository's own history. Run from the repository root:

    python models/experiments/run-views/detail_stage.py [auto|fp32] [ROUNDS] [REV]
"""
import statistics
import subprocess
import sys
import time

import torch

from rmbvideo.net.weights import default_detail_path, load_detail_model
from rmbvideo.recon.full_resolution import detail_inference_copy

torch.set_num_threads(1)
rev = sys.argv[3] if len(sys.argv) > 3 else "cc349c6~1"
old_src = subprocess.run(["git", "show", f"{rev}:rmbvideo/net/detail.py"], capture_output=True, text=True, check=True).stdout
ns = {}
exec(compile(old_src, "old_detail", "exec"), ns)
det = load_detail_model(default_detail_path())[0]
prec = sys.argv[1]
new = detail_inference_copy(det, prec, "cpu")
old_net = ns["DetailNet"](det.config)
old_net.load_state_dict(det.state_dict())
old = old_net.eval().to(memory_format=torch.channels_last)
if new.body[0].weight.dtype == torch.bfloat16:
    for layer in old.body:
        if isinstance(layer, torch.nn.Conv2d):
            layer.to(torch.bfloat16)
bf16 = new.body[0].weight.dtype == torch.bfloat16
K = det.config.rate_channels
g = torch.Generator().manual_seed(0)
binned = torch.rand(1, 1, 125, 200, generator=g)
rates = torch.rand(1, K, 250, 400, generator=g) * 0.5
T = {"old": [], "new": []}
outs = {}
with torch.inference_mode(), torch.autocast("cpu", torch.bfloat16, enabled=bf16):
    for r in range(int(sys.argv[2])):
        for name, net in ((("old", old), ("new", new)) if r % 2 else (("new", new), ("old", old))):
            t = time.perf_counter()
            outs[name] = net(binned, rates)
            T[name].append(time.perf_counter() - t)
print(prec, {k: round(1e3 * statistics.median(v), 2) for k, v in T.items()}, "ratio old/new",
      round(statistics.median([a / b for a, b in zip(T["old"], T["new"])]), 3),
      "max rel diff", ((outs["old"] - outs["new"]).abs().max() / outs["old"].abs().max()).item())
