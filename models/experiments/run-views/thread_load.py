"""Where the default full-resolution job's threads spend a 2-core CPU: each thread's CPU time per frame (read from
Linux's /proc/self/task), the wall time per frame and the share of the cores in use, under the default thread policy;
then the same job on one thread (``threads=1``: everything inline), whose CPU a frame is what the stages need alone.
The capture: the bundled demo scene simulated at the camera's 400x250 for 0.2 s (written once to a temporary folder);
one warm-up run first. Run from the repository root (about a minute):

    python models/experiments/run-views/thread_load.py
"""

import os
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import rmbvideo
from rmbvideo.allocator import keep_freed_memory
from rmbvideo.recon.run import reconstruct_frames

TICK = os.sysconf("SC_CLK_TCK")


def thread_cpu() -> dict[int, float]:
    """CPU seconds (user + system) of every thread of this process, by native id."""
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            fields = open(f"/proc/self/task/{tid}/stat").read().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended
            continue
        out[int(tid)] = (int(fields[11]) + int(fields[12])) / TICK
    return out


def main() -> None:
    keep_freed_memory()  # the allocator policy every command sets
    with tempfile.TemporaryDirectory() as folder:
        capture = Path(folder) / "demo400.dat"
        rmbvideo.simulate_capture(replace(rmbvideo.load_scene("demo"), width=400, height=250, duration_s=0.2), capture)
        list(reconstruct_frames(capture, "rmbnet"))  # warm-up: models loaded, caches filled
        seen: dict[int, float] = {}
        names: dict[int, str] = {}
        done = threading.Event()

        def sample() -> None:  # the executors' threads end with the run: read them while they live
            while not done.is_set():
                seen.update(thread_cpu())
                names.update((t.native_id, t.name) for t in threading.enumerate() if t.native_id is not None)
                time.sleep(0.1)

        before = thread_cpu()
        sampler = threading.Thread(target=sample, name="sampler", daemon=True)
        sampler.start()
        began = time.perf_counter()
        count = len(list(reconstruct_frames(capture, "rmbnet")))
        wall = time.perf_counter() - began
        seen.update(thread_cpu())
        done.set()
        sampler.join()
        began = time.perf_counter()
        alone = len(list(reconstruct_frames(capture, "rmbnet", threads=1)))
        one_thread = (time.perf_counter() - began) / alone
    used = {tid: cpu - before.get(tid, 0.0) for tid, cpu in seen.items() if names.get(tid) != "sampler"}
    total = sum(used.values())
    print(f"{count} frames, {1e3 * wall / count:.1f} ms a frame, {100 * total / wall:.0f} % of a core in use on "
          f"average ({os.cpu_count()} cores)")
    for tid, cpu in sorted(used.items(), key=lambda kv: -kv[1]):
        if cpu >= 0.01:
            print(f"  {names.get(tid, str(tid)):16s} {1e3 * cpu / count:5.1f} ms of CPU a frame")
    print(f"  together {1e3 * total / count:.1f} ms of CPU a frame; on one thread, everything inline: "
          f"{1e3 * one_thread:.1f} ms a frame")


if __name__ == "__main__":
    main()
