"""The aligned window means of a stream, computed beside the network when cores are free for them.

The aligned means (optical flow and warps in OpenCV and numpy, ``rmbvideo.recon.aligned_box``) do not
depend on the network, so on a machine with a spare core they can run in a second thread while the
network makes the previous frames: OpenCV and numpy release the GIL for their work. With one worker every
call goes through it in the order it was made, so the results are the same bit for bit whether it runs
beside the network or inline (``workers=0``, the thread policy's choice on a busy or 2-core machine, where
a second thread would only wait for the first). With more (a GPU runs the network faster than one core
makes the means), a pool makes each pair of neighbours' flows as soon as both frames are in and each mean
once its flows are: the same numbers again, since every flow and mean is a function of the frames alone.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np

from rmbvideo.recon.aligned_box import AlignedBox, AlignedBoxConfig


class Ready:
    """A result already made (a call made inline, or one kept for later), with a Future's ``result``."""

    def __init__(self, value: Any) -> None:
        self._value = value

    def result(self) -> Any:
        return self._value


class BusyClock:
    """Seconds of work summed over the threads that did it (a lock per addition: pools add concurrently)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.seconds = 0.0

    def add(self, seconds: float) -> None:
        with self._lock:
            self.seconds += seconds

    def timed(self, func: Callable, *args: Any) -> Any:
        """``func(*args)``, its wall time added."""
        began = time.perf_counter()
        try:
            return func(*args)
        finally:
            self.add(time.perf_counter() - began)


class AlignedWorker:
    """An :class:`AlignedBox` driven inline (``workers=0``), in call order by one background thread (1), or by a
    pool of threads (2 or more).

    ``add`` and ``evict`` return at once (an eviction in a pool first waits for the means queued before it);
    ``mean`` returns a handle whose ``result()`` waits for that frame's mean. ``busy_seconds`` is the time spent
    computing, wherever it ran (summed over a pool's threads); ``waited_seconds`` the time the caller spent
    waiting for results (all of it when inline).
    """

    def __init__(self, config: AlignedBoxConfig, workers: int) -> None:
        if workers < 0:
            raise ValueError(f"workers must be >= 0, got {workers}")
        self._box = AlignedBox(config)
        self.workers = workers
        self._executor = (ThreadPoolExecutor(max_workers=workers, thread_name_prefix="aligned-mean")
                          if workers else None)
        # a pool's threads are its parallelism: each OpenCV call in them gets one thread (the count is process-wide,
        # so it holds until close(); seen on a 16-core GPU host: 15 workers each starting OpenCV's 16 threads spent
        # 8x the time per frame of one worker)
        self._cv_threads = cv2.getNumThreads() if workers >= 2 else None
        if self._cv_threads is not None:
            cv2.setNumThreads(1)
        self._pending: list[Future] = []  # adds and evictions not yet known to have succeeded
        self._added: dict[int, Future] = {}  # a pool's frames and flows to their predecessors, by frame
        self._flowed: dict[int, Future] = {}
        self._means: list[Future] = []  # a pool's queued means
        self._busy = BusyClock()
        self.waited_seconds = 0.0

    @property
    def concurrent(self) -> bool:
        return self._executor is not None

    @property
    def pooled(self) -> bool:
        return self.workers >= 2

    @property
    def busy_seconds(self) -> float:
        return self._busy.seconds

    def _timed(self, func: Callable, *args: Any) -> Any:
        return self._busy.timed(func, *args)

    def _submit(self, func: Callable, *args: Any) -> Future | Ready:
        if self._executor is None:
            began = time.perf_counter()
            try:
                return Ready(self._timed(func, *args))
            finally:
                self.waited_seconds += time.perf_counter() - began
        return self._executor.submit(self._timed, func, *args)

    def _after(self, needs: Sequence[Future], func: Callable, *args: Any) -> Future:
        """Queue ``func`` in the pool to run once ``needs`` are done. Each need was queued earlier, so (the queue
        being first in, first out) it is running or done by the time a thread waits for it here: no deadlock."""

        def task() -> Any:
            for need in needs:
                need.result()
            return self._timed(func, *args)

        return self._executor.submit(task)  # type: ignore[union-attr]

    def add(self, index: int, rate: np.ndarray, sharp: np.ndarray | None = None) -> None:
        """Queue frame ``index``'s rate (and sharp) image (``AlignedBox.add``); a pool also queues the flows
        between it and frame ``index - 1``."""
        if self.pooled:
            handle = self._after([], self._box.add, index, rate, sharp)
            self._added[index] = handle
            if index - 1 in self._added:
                self._flowed[index] = self._after([self._added[index - 1], handle], self._box.flows_between, index)
            return
        handle = self._submit(self._box.add, index, rate, sharp)
        if isinstance(handle, Future):
            self._pending.append(handle)

    def evict(self, oldest_needed: int) -> None:
        """Queue forgetting frames older than ``oldest_needed`` (``AlignedBox.evict``)."""
        if self.pooled:  # first the work that may read those frames: the means queued before and the flows
            began = time.perf_counter()  # between frames up to ``oldest_needed`` (their errors stay theirs)
            for queued in self._means:
                queued.exception()
            self._means.clear()
            for store, last in ((self._added, oldest_needed - 1), (self._flowed, oldest_needed)):
                for key in [k for k in store if k <= last]:
                    store.pop(key).exception()
            self.waited_seconds += time.perf_counter() - began
            self._timed(self._box.evict, oldest_needed)
            return
        handle = self._submit(self._box.evict, oldest_needed)
        if isinstance(handle, Future):
            self._pending.append(handle)

    def mean(self, i: int, neighbours: Sequence[int], statistics: bool = False) -> "AlignedMean":
        """Queue frame ``i``'s aligned mean over ``neighbours`` (``AlignedBox.mean``, with its ``statistics``)."""
        if not self.pooled:
            return AlignedMean(self, self._submit(self._box.mean, i, neighbours, statistics))
        frames = sorted({i, *neighbours})
        needs = [self._added[j] for j in frames if j in self._added]
        needs += [self._flowed[j] for j in range(frames[0] + 1, frames[-1] + 1) if j in self._flowed]
        handle = self._after(needs, self._box.mean, i, neighbours, statistics)
        self._means.append(handle)
        return AlignedMean(self, handle)

    def _wait(self, handle: Future | Ready) -> Any:
        began = time.perf_counter()
        try:
            if not self.pooled:  # an add or eviction that failed fails here, in the caller (a pool's mean
                for earlier in self._pending:  # fails with them, as it waited for them)
                    earlier.result()
                self._pending.clear()
            return handle.result()
        finally:
            self.waited_seconds += time.perf_counter() - began

    def close(self) -> None:
        """Let the background threads end (queued work still finishes)."""
        if self._executor is not None:
            self._executor.shutdown(wait=False)
        if self._cv_threads is not None:
            cv2.setNumThreads(self._cv_threads)
            self._cv_threads = None


class AlignedMean:
    """One frame's aligned mean (with its statistics, as a pair, when asked for), queued: ``result()`` waits for it."""

    def __init__(self, worker: AlignedWorker, handle: Future | Ready) -> None:
        self._worker, self._handle = worker, handle

    def result(self) -> Any:
        return self._worker._wait(self._handle)
