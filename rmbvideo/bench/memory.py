"""Peak memory of a fresh subprocess: of a ``reconstruct`` run (so captures of different lengths can be compared) or of
any statement (a benchmark row alone: within one process the resident set keeps every earlier run's high-water mark)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096

# Runs CALL (Python statements; argv[1:] are theirs) in a fresh process and prints its peak RSS and the sampled peak of
# its anonymous RSS (RssAnon: heap and arrays, without file pages of memory maps). The peak RSS is the kernel's
# high-water mark of this process's own memory (VmHWM), not ru_maxrss: Linux carries the parent's high-water mark into
# a child's ru_maxrss across fork and exec (a parent holding 800 MB made a 14 MB child read 827 MB).
_CHILD = """
import json, resource, sys, threading
from rmbvideo.bench.memory import anonymous_rss_bytes, high_water_rss_bytes
peak = [anonymous_rss_bytes()]
stop = threading.Event()
def sample():
    while not stop.wait(0.002):
        peak[0] = max(peak[0], anonymous_rss_bytes())
thread = threading.Thread(target=sample, daemon=True)
thread.start()
try:
    CALL
finally:
    stop.set()
    thread.join()
    peak[0] = max(peak[0], anonymous_rss_bytes())
    rss = high_water_rss_bytes() or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"rss": rss, "anon_peak": peak[0]}))
"""
_RECONSTRUCT = 'from rmbvideo.cli import main; main(sys.argv[1:], prog_name="rmbvideo", standalone_mode=False)'


# glibc raises its mmap threshold each time a large array is freed, after which arrays of that size come
# from the heap and fragment it: anonymous RSS then creeps up by ~10 % over the first tens of thousands of
# planes before it levels off (measured: tfw 180 -> 194 -> 202 -> 202 MB at 2k, 10k, 31k, 92k planes). A
# fixed threshold returns freed arrays to the system, so the figure is what the program holds (tfw: 173 ->
# 174 MB over the same lengths) and a growth with length is a real one.
FIXED_MMAP_THRESHOLD = {"MALLOC_MMAP_THRESHOLD_": "65536"}


@dataclass(frozen=True)
class PeakMemory:
    """Peak memory of a process in bytes: ``rss`` (its high-water mark, including file pages of memory-mapped
    input, which the kernel can drop at will) and ``anonymous`` (sampled peak of RssAnon)."""

    rss: int
    anonymous: int


def _status_bytes(field: str) -> int:
    """A ``kB`` field of /proc/self/status in bytes (0 where /proc is unavailable)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def anonymous_rss_bytes() -> int:
    """RssAnon of this process now, in bytes (0 where /proc is unavailable)."""
    return _status_bytes("RssAnon")


def high_water_rss_bytes() -> int:
    """VmHWM: the peak resident set of this process's memory so far, in bytes (0 where /proc is unavailable)."""
    return _status_bytes("VmHWM")


def current_rss_bytes() -> int:
    """Resident set size of this process now (0 where /proc is unavailable)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * _PAGE
    except OSError:
        return 0


def child_peak_memory(call: str, args: list[str], env: dict[str, str] | None = None, timeout_s: float = 600.0,
                      what: str = "the child") -> PeakMemory:
    """Peak memory of a fresh Python subprocess running the statement ``call`` with ``args`` as its argv[1:], in the
    environment ``env`` (default: this process's). Raises ``RuntimeError`` with the child's stderr if it fails."""
    result = subprocess.run([sys.executable, "-c", _CHILD.replace("CALL", call), *args], capture_output=True,
                            text=True, timeout=timeout_s, env=env)
    last = result.stdout.strip().splitlines()[-1] if result.stdout.strip() else ""
    if result.returncode != 0 or not last.startswith("{"):
        raise RuntimeError(f"{what} failed ({result.returncode}): {result.stderr[-2000:]}")
    result_json = json.loads(last)
    return PeakMemory(rss=int(result_json["rss"]), anonymous=int(result_json["anon_peak"]))


def reconstruct_peak_rss(args: list[str], env: dict[str, str] | None = None,
                         timeout_s: float = 600.0, base_env: dict[str, str] | None = None) -> PeakMemory:
    """Peak memory of ``rmbvideo reconstruct ARGS`` run in a fresh Python subprocess, whose environment is
    ``base_env`` (default: this process's) with glibc's mmap threshold fixed, updated with ``env``.

    Raises ``RuntimeError`` with the child's stderr if it fails.
    """
    child_env = {**(os.environ if base_env is None else base_env), **FIXED_MMAP_THRESHOLD, **(env or {})}
    return child_peak_memory(_RECONSTRUCT, ["reconstruct", *args], child_env, timeout_s,
                             what=f"reconstruct {' '.join(args)}")


def write_random_capture(path: Path, n_planes: int, width: int, height: int, rate: float = 0.3,
                         seed: int = 0) -> Path:
    """A .dat capture of ``n_planes`` Bernoulli(``rate``) planes, written in bounded chunks."""
    import numpy as np

    from rmbvideo.io.dat import DatGeometry, DatWriter

    rng = np.random.default_rng(seed)
    pool = (rng.random((64, height, width)) < rate).astype(np.uint8)
    with DatWriter(path, DatGeometry(width=width, height=height)) as writer:
        for s in range(0, n_planes, len(pool)):
            writer.write(pool[: min(len(pool), n_planes - s)])
    return path


def memory_scaling(method: str, planes: int, factor: int = 5, width: int = 400, height: int = 250,
                   extra: tuple[str, ...] = ()) -> dict:
    """Peak RSS of ``reconstruct --format null`` on a capture of ``planes`` and of ``factor`` x as many."""
    peaks = []
    with tempfile.TemporaryDirectory(prefix="rmbvideo-memory-") as folder:
        for count in (planes, factor * planes):
            path = write_random_capture(Path(folder) / f"c{count}.dat", count, width, height)
            peaks.append(reconstruct_peak_rss([str(path), "-o", str(Path(folder) / "out"), "--format", "null",
                                               "--method", method, "--width", str(width), "--height", str(height),
                                               "-q", *extra]))
            path.unlink()
    return {"method": method, "options": list(extra), "planes": planes, "factor": factor,
            "peak_anon_mib": [p.anonymous / 2**20 for p in peaks], "peak_rss_mib": [p.rss / 2**20 for p in peaks],
            "growth": peaks[1].anonymous / peaks[0].anonymous - 1.0}
