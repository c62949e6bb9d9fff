"""The default job (RMB-Net, raw-interval gate, detail stage: full resolution) with each chunk's raw rates, gate and
detail stage inline after the network or in a thread of their own a chunk behind it (``finish_beside``), the thread
policy otherwise (on 2 idle cores: the network one thread, the aligned means beside it). Each run is a fresh process,
the two alternated; ms a frame and each stage's, and whether the frames agree bit for bit.
Run from the folder holding fm5.dat (``rmbvideo simulate fast-motion -o fm.dat`` written five times into one file with
``cat``: 500 frames at 400x250): python finish_beside.py [ROUNDS] [--threads N]
"""

import json
import statistics
import subprocess
import sys

ROUNDS = int(sys.argv[1]) if len(sys.argv) > 1 else 3
THREADS = sys.argv[sys.argv.index("--threads") + 1] if "--threads" in sys.argv else "None"

ONE_RUN = """
import hashlib, json, time
from pathlib import Path
import rmbvideo.recon.full_resolution as full
from rmbvideo.allocator import keep_freed_memory
from rmbvideo.recon.pipeline import StreamStats, iter_frames
from rmbvideo.recon.run import prepare_run

keep_freed_memory()  # as every command does
full.finish_beside_by_default = lambda device, threads: {beside}
run = prepare_run(Path("fm5.dat"), extra_options={{"threads": {threads}}} if {threads} else None)
stats, digest, frames = StreamStats(), hashlib.sha256(), 0
began = time.perf_counter()
for frame in iter_frames(run.reader, run.method, start=run.start, stop=run.stop, readout=run.readout, stats=stats):
    digest.update(frame.image.tobytes())
    frames += 1
seconds = time.perf_counter() - began
print(json.dumps(dict(ms=1e3 * seconds / frames, stages={{k: 1e3 * v / frames for k, v in stats.stages.items()}},
                      digest=digest.hexdigest(), frames=frames)))
"""

results: dict[str, list[dict]] = {"inline": [], "beside": []}
for _ in range(ROUNDS):
    for kind in results:
        code = ONE_RUN.format(beside=kind == "beside", threads=THREADS)
        out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
        results[kind].append(json.loads(out.strip().splitlines()[-1]))
        print(kind, f"{results[kind][-1]['ms']:.1f} ms a frame", flush=True)
for kind, runs in results.items():
    stages = {k: statistics.median(r["stages"][k] for r in runs) for k in runs[0]["stages"]}
    print(f"{kind}: median {statistics.median(r['ms'] for r in runs):.1f} ms a frame ({runs[0]['frames']} frames); "
          + ", ".join(f"{k} {v:.1f}" for k, v in stages.items() if v >= 0.05))
inline, beside = (statistics.median(r["ms"] for r in results[k]) for k in ("inline", "beside"))
digests = {r["digest"] for runs in results.values() for r in runs}
print(f"beside / inline: {beside / inline:.3f} ({inline / beside:.2f}x the frames a second); "
      f"frames {'bit for bit the same' if len(digests) == 1 else 'DIFFER'} in every run")
