"""One allocator policy for every command: freed memory kept for reuse, not handed back to the system at every frame.

By default glibc serves each block above its mmap threshold (128 kB, raised only as large blocks are freed) as a
fresh mapping, and gives the heap's free top back to the system once 128 kB is free there. So the few-MB tensors and
arrays a frame makes (a 16-channel 400x250 feature map is 6.4 MB) are faulted in again, page by page, every time.
Measured on this project's AVX2 host, one thread (``models/experiments/avx2-profile/allocator.py``): the detail
stage's four chained convolutions took 31-48 ms a pass as glibc does by default and 20-29 ms with both thresholds
raised (about 35 with either alone), TFI 9-27 % less CPU time (``allocator_jobs.py``). Blocks above ``MMAP_THRESHOLD_BYTES`` (a whole decoded chunk) are still mapped
and handed back when freed. Memory stays bounded: the process keeps its high-water mark, which later frames reuse.
glibc only (Linux); elsewhere nothing changes, and neither where glibc's thresholds are set in the environment
(``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``): whoever set them chose (``rmbvideo.bench.memory`` fixes the
mmap threshold so that a peak measures what the program holds).

With the thresholds raised, the process also keeps one malloc arena (``ARENA_MAX``) unless ``MALLOC_ARENA_MAX`` is set:
glibc gives each new thread an arena of its own, and each arena then kept its own high-water mark of the frames' blocks
that the main, aligned-mean and finishing threads make and free. Measured with the default job on a 1000x1000 camera
(800 planes, two runs each): 3.41-3.53 GB peak and 30.3-30.4 s with an arena a thread, 2.67-2.75 GB and 26.0-26.4 s
with one; at 400x250 the same to the runs' spread (565-572 MB, 12.8-13.5 s; ``car.dat`` x20).
"""

from __future__ import annotations

import ctypes
import logging
import os
import platform

logger = logging.getLogger(__name__)

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8  # mallopt's parameter numbers (malloc.h)
#: free memory at the heap's top handed back to the system only beyond this
TRIM_THRESHOLD_BYTES = 1 << 30
#: blocks up to this size come from the heap (glibc's largest dynamic threshold on 64-bit hosts)
MMAP_THRESHOLD_BYTES = 32 << 20

#: malloc arenas the process keeps: threads share them, and with them the freed blocks
ARENA_MAX = 1

#: the environment variables by which glibc's thresholds are set at start-up
ENVIRONMENT = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")

_in_force = False


def keep_freed_memory() -> bool:
    """Raise glibc's trim and mmap thresholds for this process (once) and keep ``ARENA_MAX`` arenas for the threads it
    starts after this; whether the policy is in force."""
    global _in_force
    if _in_force:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    if any(name in os.environ for name in ENVIRONMENT):
        logger.debug("glibc's thresholds are set in the environment; left as they are")
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # pragma: no cover - a glibc without mallopt
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    _in_force = bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) and mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
    if not _in_force:  # pragma: no cover - glibc refused the values
        logger.debug("glibc refused the allocator thresholds; its defaults stay")
    elif "MALLOC_ARENA_MAX" not in os.environ and not mallopt(_M_ARENA_MAX, ARENA_MAX):  # pragma: no cover
        logger.debug("glibc refused the arena limit; an arena a thread stays")
    return _in_force
