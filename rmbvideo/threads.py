"""One thread policy for every command: how many threads the math libraries use in this process.

On a machine whose cores are shared (other processes running, or CI), threads of one operation wait
for each other at every step and two threads run a network about half as fast as one (measured on
this project's 2-core machine: 6.2 s against 3.1 s for ``reconstruct`` with the default model);
with idle cores they help. So: the cores this process may use, minus those the rest of the machine
keeps busy, at least 1 and at most ``MAX_THREADS``; on 2 cores or fewer, 1. ``--threads`` overrides it
wherever a command offers it. Busy cores are measured over 0.1 s from ``/proc/stat`` on this
process's cores while it sleeps (the 1-minute load average would count this process's own recent
work, e.g. the previous command of a script), the load average where that file is missing.

Work that never waits for a partner thread is another matter: RMB-Net's aligned window means (OpenCV
and numpy) can run in a thread of their own beside the network whenever a second core is idle, 2-core
machines included (measured on this project's 2-core machine, idle: 40 -> 52 frames/s; with the other
core busy it would only take turns with the network, so then it does not).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

MAX_THREADS = 8
#: seconds over which busy cores are measured, and for which a measurement is reused
SAMPLE_S = 0.1
REUSE_S = 5.0

_measured: tuple[float, float] | None = None  # (monotonic time, busy cores)


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def _cpu_times() -> tuple[float, float] | None:
    """(total, idle) jiffies summed over this process's cores from ``/proc/stat``, or None."""
    try:
        lines = Path("/proc/stat").read_text().splitlines()
        cores = {f"cpu{c}" for c in os.sched_getaffinity(0)}
    except (OSError, AttributeError):
        return None
    total = idle = 0.0
    for line in lines:
        fields = line.split()
        if fields and fields[0] in cores:
            values = [float(v) for v in fields[1:9]]  # user .. steal (guest time is inside user)
            total += sum(values)
            idle += values[3] + values[4]  # idle + iowait
    return (total, idle) if total > 0 else None


def busy_cores() -> float:
    """Cores of this process's that the rest of the machine keeps busy (see the module docstring)."""
    global _measured
    now = time.monotonic()
    if _measured is not None and now - _measured[0] < REUSE_S:
        return _measured[1]
    before = _cpu_times()
    if before is not None:
        time.sleep(SAMPLE_S)
        after = _cpu_times()
        if after is not None and after[0] > before[0]:
            busy = available_cores() * (1.0 - (after[1] - before[1]) / (after[0] - before[0]))
            _measured = (time.monotonic(), busy)
            return busy
    try:
        return os.getloadavg()[0]
    except OSError:
        return 0.0


def idle_cores() -> int:
    """The cores this process may use minus those the rest of the machine keeps busy, at least 1 and at
    most ``MAX_THREADS``."""
    return int(max(1, min(MAX_THREADS, available_cores() - round(busy_cores()))))


def default_threads() -> int:
    """Threads for one process's compute under the policy above."""
    return 1 if available_cores() <= 2 else idle_cores()


def work_beside(threads: int | None) -> bool:
    """Whether independent work (the aligned window means) gets a thread of its own beside the network:
    with an explicit count, when it is 2 or more; under the policy, when a second core is idle."""
    return threads >= 2 if threads is not None else idle_cores() >= 2


@contextmanager
def compute_threads(count: int | None = None, cv_count: int | None = None) -> Iterator[None]:
    """torch's intra-op threads set to ``count`` (None: ``default_threads()``) and OpenCV's (optical flow,
    warps) to ``cv_count`` (None: the same) inside the block, the previous counts restored after it.

    In a thread other than the main one (a stage running beside another) only torch's count is set, and kept: under
    OpenMP it is that thread's own (a new thread starts at every core), and in builds where it is the process's,
    restoring it would undo the main thread's; OpenCV's, process-wide, stays the main thread's to set and restore."""
    import cv2
    import torch

    wanted = default_threads() if count is None else count
    if threading.current_thread() is not threading.main_thread():
        torch.set_num_threads(wanted)
        yield
        return
    previous, previous_cv = torch.get_num_threads(), cv2.getNumThreads()
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
