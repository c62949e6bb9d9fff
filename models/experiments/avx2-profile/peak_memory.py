"""Peak anonymous memory of the default job at full resolution by capture length, as the memory test measures it
(``rmbvideo.bench.memory.reconstruct_peak_rss``: a fresh process, the memory test's tiny model, random 400x250
captures), for each ``--threads`` given. Run from the repository root:

    python models/experiments/avx2-profile/peak_memory.py [--policy] [--chunk N] [--planes A,B,...] THREADS...

``--policy``: with the allocator policy in force (``rmbvideo.allocator``), which fixed glibc thresholds in the
environment would leave alone; without it the mmap threshold is fixed, as in the test.
"""

import argparse
import os
import tempfile
from pathlib import Path

import torch

import rmbvideo.bench.memory as memory
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import ModelCard, save_model

parser = argparse.ArgumentParser()
parser.add_argument("threads", nargs="+")
parser.add_argument("--policy", action="store_true")
parser.add_argument("--chunk", default="128")
parser.add_argument("--planes", default="640,3200,6400")
args = parser.parse_args()
if args.policy:
    memory.FIXED_MMAP_THRESHOLD = {}
base = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
folder = Path(tempfile.mkdtemp(prefix="peak-memory-"))
torch.manual_seed(0)
model = save_model(folder / "tiny", RmbNet(RmbNetConfig(w=1, width=0.25)), ModelCard(name="tiny"))
for threads in args.threads:
    for count in (int(p) for p in args.planes.split(",")):
        path = memory.write_random_capture(folder / f"c{count}.dat", count, 400, 250, seed=count)
        peak = memory.reconstruct_peak_rss([str(path), "-o", str(folder / "out"), "--format", "null", "-q",
                                            "--width", "400", "--height", "250", "--method", "rmbnet", "--model",
                                            str(model), "--device", "cpu", "--chunk-planes", args.chunk,
                                            "--threads", threads], env={"OMP_NUM_THREADS": "1"}, base_env=base)
        print(f"--threads {threads}, {count} planes: {peak.anonymous >> 20} MB", flush=True)
