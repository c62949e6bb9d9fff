"""One job in-process on 500 frames of ``fast-motion`` (fm5.dat: ``rmbvideo simulate fast-motion -o fm.dat`` written
five times into one file with ``cat``; RMB-Net: 60 frames of it), with the allocator policy off or on: CPU seconds,
wall seconds, page faults.
Run from the folder holding fm5.dat, alternating: python allocator_jobs.py off|on tfp|tfi|rmbnet
"""

import resource
import sys
import time

if sys.argv[1] == "on":
    from rmbvideo.allocator import keep_freed_memory
    assert keep_freed_memory()
from pathlib import Path  # noqa: E402

from rmbvideo.recon.run import run_reconstruction  # noqa: E402


def cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


method = sys.argv[2]
# RMB-Net: the default job, 60 frames after 5 of warm-up, one thread; the classical methods: the whole capture
options = dict(duration_s=0.06, extra_options={"threads": 1}) if method == "rmbnet" else {}
if method == "rmbnet":
    run_reconstruction(Path("fm5.dat"), Path("/tmp/alloc-" + sys.argv[1]), fmt="null", duration_s=0.005, overwrite=True,
                       extra_options={"threads": 1})
c0, w0, f0 = cpu(), time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt
run_reconstruction(Path("fm5.dat"), Path("/tmp/alloc-" + sys.argv[1]), method=method, fmt="null", overwrite=True, **options)
print(sys.argv[1], method, f"cpu {cpu() - c0:.2f} s wall {time.perf_counter() - w0:.2f} s "
      f"faults {resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0}")
