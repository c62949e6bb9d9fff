"""TFI's block scan (the last spike at or before each plane, the first at or after it, per pixel): the compiled kernel
(``scan_block`` in ``rmbvideo/sensor/_packed.c``, the third stop of 2026-11-29) against its numpy form. First a 64-plane
block of 400x250 planes timed alone, 9 alternated rounds; then ``reconstruct --method tfi --format null`` on 500 frames
of ``fast-motion`` in fresh processes, alternated, with the kernel and with it turned off. Medians; the frames'
digests must agree. Run from the folder holding fm5.dat (``rmbvideo simulate fast-motion -o fm.dat`` written five
times into one file with ``cat``): python tfi_scan.py [ROUNDS]
"""

import statistics
import subprocess
import sys
import time

import numpy as np

from rmbvideo.allocator import keep_freed_memory
from rmbvideo.recon.classical import block_scan

ROUNDS = int(sys.argv[1]) if len(sys.argv) > 1 else 3
keep_freed_memory()
planes = (np.random.default_rng(0).random((64, 250, 400)) < 0.05).astype(np.uint8)
assert all(np.array_equal(a, b) for a, b in zip(block_scan(planes), block_scan(planes, compiled=False)))
alone: dict[bool, list[float]] = {True: [], False: []}
for _ in range(9):
    for compiled in alone:
        began = time.perf_counter()
        block_scan(planes, compiled=compiled)
        alone[compiled].append(time.perf_counter() - began)
kernel, numpy_form = (statistics.median(alone[c]) * 1e3 for c in (True, False))
print(f"a 64-plane block: kernel {kernel:.2f} ms, numpy {numpy_form:.2f} ms ({numpy_form / kernel:.1f}x)")

ONE_RUN = """
import hashlib, time
from pathlib import Path
import rmbvideo.recon.classical as classical
from rmbvideo.allocator import keep_freed_memory
from rmbvideo.recon.pipeline import iter_frames
from rmbvideo.recon.run import prepare_run

keep_freed_memory()  # as every command does
if not {compiled}:
    classical.KERNELS = None
run = prepare_run(Path("fm5.dat"), method="tfi")
digest, began = hashlib.sha256(), time.perf_counter()
for frame in iter_frames(run.reader, run.method, start=run.start, stop=run.stop, readout=run.readout):
    digest.update(frame.image.tobytes())
print(time.perf_counter() - began, digest.hexdigest())
"""
runs: dict[bool, list[float]] = {True: [], False: []}
digests = set()
for _ in range(ROUNDS):
    for compiled in runs:
        out = subprocess.run([sys.executable, "-c", ONE_RUN.format(compiled=compiled)], check=True,
                             capture_output=True, text=True).stdout.split()
        runs[compiled].append(float(out[-2]))
        digests.add(out[-1])
with_kernel, without = (statistics.median(runs[c]) for c in (True, False))
print(f"reconstruct --method tfi, 500 frames: {with_kernel:.2f} s with the kernel, {without:.2f} s without "
      f"({without / with_kernel:.2f}x); rounds {[round(t, 2) for t in runs[True]]} / {[round(t, 2) for t in runs[False]]}; "
      f"frames {'bit for bit the same' if len(digests) == 1 else 'DIFFER'}")
