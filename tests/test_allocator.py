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
