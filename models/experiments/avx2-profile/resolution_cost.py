"""What each output of a 1-bit capture costs: the default job at full resolution, at the binned size with the
raw-interval gate (``--resolution binned``'s default since the third stop of 2026-11-29) and without it (``--raw-gate
off``: the network's frames alone), each run a fresh process under the thread policy, alternated; ms a frame.
Run from the folder holding fm5.dat (``rmbvideo simulate fast-motion -o fm.dat`` written five times into one file with
``cat``: 500 frames at 400x250): python resolution_cost.py [ROUNDS]
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
run = prepare_run(Path("fm5.dat"), resolution={resolution!r}, raw_gate={gate!r})
began, frames = time.perf_counter(), 0
for frame in iter_frames(run.reader, run.method, start=run.start, stop=run.stop, readout=run.readout):
    frames += 1
print(1e3 * (time.perf_counter() - began) / frames)
"""
KINDS = {"full": ("full", "auto"), "binned, gated": ("binned", "auto"), "binned, --raw-gate off": ("binned", "off")}
times: dict[str, list[float]] = {kind: [] for kind in KINDS}
for _ in range(ROUNDS):
    for kind, (resolution, gate) in KINDS.items():
        code = ONE_RUN.format(resolution=resolution, gate=gate)
        out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
        times[kind].append(float(out.strip().splitlines()[-1]))
        print(f"{kind}: {times[kind][-1]:.1f} ms a frame", flush=True)
full = statistics.median(times["full"])
for kind, values in times.items():
    median = statistics.median(values)
    print(f"{kind}: median {median:.1f} ms a frame, {full / median:.2f}x the full job's frames a second")
