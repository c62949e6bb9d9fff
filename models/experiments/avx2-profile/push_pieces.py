"""The default job with each 1,024-plane chunk pushed whole or in pieces of ``CPU_PUSH_PLANES`` (256) raw planes, the
thread policy otherwise (on 2 idle cores: the raw rates, gate and detail stage in a thread behind the network), fresh
processes alternated; seconds for the whole capture. Run from the folder holding fm.dat and fm5.dat (``rmbvideo simulate
fast-motion -o fm.dat``: 100 frames at 400x250; fm5.dat: it written five times into one file with ``cat``):

    python push_pieces.py [ROUNDS]
"""

import statistics
import subprocess
import sys

ROUNDS = int(sys.argv[1]) if len(sys.argv) > 1 else 2
ONE_RUN = """
import time
from pathlib import Path
from rmbvideo.allocator import keep_freed_memory
from rmbvideo.recon.pipeline import iter_frames
from rmbvideo.recon.run import prepare_run

keep_freed_memory()  # as every command does
run = prepare_run(Path({capture!r}))
run.method.max_push_planes = {pieces}
began = time.perf_counter()
frames = sum(1 for _ in iter_frames(run.reader, run.method, start=run.start, stop=run.stop, readout=run.readout))
print(time.perf_counter() - began)
"""
for capture in ("fm.dat", "fm5.dat"):
    times: dict[str, list[float]] = {"whole chunks": [], "256-plane pieces": []}
    for _ in range(ROUNDS):
        for kind, pieces in zip(times, (None, 256)):
            out = subprocess.run([sys.executable, "-c", ONE_RUN.format(capture=capture, pieces=pieces)], check=True,
                                 capture_output=True, text=True).stdout
            times[kind].append(float(out.strip().splitlines()[-1]))
    print(capture + ": " + ", ".join(f"{kind} {statistics.median(v):.2f} s ({', '.join(f'{t:.2f}' for t in v)})"
                                     for kind, v in times.items()), flush=True)
