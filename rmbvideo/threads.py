"""One thread policy for every command: how many threads the math libraries use in this process.

On a machine whose cores are shared (other processes running, or CI), threads of one operation wait
for each other at every step and two threads run a network about half as fast as one (measured on
this project's 2-core machine: 6.2 s against 3.1 s for ``reconstruct`` with the default model);
with idle cores they help. So: the cores this process may use, minus the load the rest of the
machine puts on them (1-minute load average), at least 1 and at most ``MAX_THREADS``; on 2 cores
or fewer, 1. ``--threads`` overrides it wherever a command offers it.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

MAX_THREADS = 8


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def default_threads() -> int:
    """Threads for one process's compute under the policy above."""
    cores = available_cores()
    if cores <= 2:
        return 1
    try:
        busy = os.getloadavg()[0]
    except OSError:
        busy = 0.0
    return int(max(1, min(MAX_THREADS, cores - round(busy))))


@contextmanager
def compute_threads(count: int | None = None, cv_count: int | None = None) -> Iterator[None]:
    """torch's intra-op threads set to ``count`` (None: ``default_threads()``) and OpenCV's (optical flow,
    warps) to ``cv_count`` (None: the same) inside the block, the previous counts restored after it."""
    import cv2
    import torch

    previous, previous_cv = torch.get_num_threads(), cv2.getNumThreads()
    wanted = default_threads() if count is None else count
    wanted_cv = wanted if cv_count is None else cv_count
    if wanted != previous:
        torch.set_num_threads(wanted)
    if wanted_cv != previous_cv:
        cv2.setNumThreads(wanted_cv)
    try:
        yield
    finally:
        if torch.get_num_threads() != previous:
            torch.set_num_threads(previous)
        if cv2.getNumThreads() != previous_cv:
            cv2.setNumThreads(previous_cv)
