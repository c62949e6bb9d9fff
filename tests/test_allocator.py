"""The allocator policy of every command: on glibc, a freed few-MB block is reused, not faulted in again."""

from __future__ import annotations

import platform
import resource

import numpy as np
import pytest

from rmbvideo.allocator import keep_freed_memory

GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


@pytest.mark.skipif(not GLIBC, reason="the policy sets glibc's thresholds; elsewhere it changes nothing")
def test_a_freed_block_is_reused_without_page_faults() -> None:
    """Ten cycles of a 6 MB array made, written and freed fault in almost nothing after the first (glibc's defaults:
    about 500 pages with transparent huge pages, 15,000 without)."""
    assert keep_freed_memory() and keep_freed_memory()  # in force, and applying it again changes nothing

    def cycle() -> None:
        block = np.empty(6 << 20, np.uint8)
        block.fill(1)
        del block

    cycle()
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt  # this thread's: other threads' faults not counted
    for _ in range(10):
        cycle()
    assert resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before < 100


@pytest.mark.skipif(not GLIBC, reason="the policy sets glibc's thresholds; elsewhere it changes nothing")
def test_thresholds_set_in_the_environment_are_left_alone() -> None:
    """Whoever set glibc's thresholds in the environment chose them (the memory tests fix the mmap threshold so that a
    peak measures what the program holds): the policy then leaves them."""
    import os
    import subprocess
    import sys

    code = "from rmbvideo.allocator import keep_freed_memory; print(keep_freed_memory())"
    for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_"):
        env = {key: value for key, value in os.environ.items() if not key.startswith("MALLOC_")}
        result = subprocess.run([sys.executable, "-c", code], env={**env, name: "65536"}, capture_output=True,
                                text=True, check=True)
        assert result.stdout.strip() == "False", name
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "True"


@pytest.mark.skipif(not GLIBC, reason="the policy sets glibc's thresholds; elsewhere it changes nothing")
def test_a_block_one_thread_freed_is_reused_by_another() -> None:
    """The process keeps one arena: a 6 MB block the main thread made and freed is reused by a thread started later,
    which faults in almost nothing (with an arena a thread it faults in the whole block: about 500 pages with
    transparent huge pages, 1,500 without).
    In a fresh process, so that no thread of an earlier test holds an arena."""
    import os
    import subprocess
    import sys

    code = """
import resource, threading
import numpy as np
from rmbvideo.allocator import keep_freed_memory
assert keep_freed_memory()
def cycle():
    block = np.empty(6 << 20, np.uint8)
    block.fill(1)
    del block
cycle()
faults = []
def worker():
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    cycle()
    faults.append(resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before)
thread = threading.Thread(target=worker)
thread.start()
thread.join()
print(faults[0])
"""
    env = {key: value for key, value in os.environ.items() if not key.startswith("MALLOC_")}
    faults = [int(subprocess.run([sys.executable, "-c", code], env={**env, **extra}, capture_output=True, text=True,
                                 check=True).stdout) for extra in ({}, {"MALLOC_ARENA_MAX": "8"})]
    assert faults[0] < 100 < faults[1]
