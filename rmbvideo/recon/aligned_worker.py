"""The aligned window means of a stream, computed beside the network when a core is free for them.

The aligned means (optical flow and warps in OpenCV and numpy, ``rmbvideo.recon.aligned_box``) do not
depend on the network, so on a machine with a spare core they can run in a second thread while the
network makes the previous frames: OpenCV and numpy release the GIL for their work. Every call goes
through one worker in the order it was made, so the results are the same bit for bit whether it runs
beside the network or inline (``concurrent=False``, the thread policy's choice on a busy or 2-core
machine, where a second thread would only wait for the first).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from rmbvideo.recon.aligned_box import AlignedBox, AlignedBoxConfig


class _Done:
    """The result of a call made inline, with a Future's ``result``."""

    def __init__(self, value: Any) -> None:
        self._value = value

    def result(self) -> Any:
        return self._value


class AlignedWorker:
    """An :class:`AlignedBox` driven in call order, inline or in one background thread.

    ``add`` and ``evict`` return at once; ``mean`` returns a handle whose ``result()`` waits for that
    frame's mean. ``busy_seconds`` is the time spent computing, wherever it ran; ``waited_seconds`` the
    time the caller spent waiting for results (all of it when inline).
    """

    def __init__(self, config: AlignedBoxConfig, concurrent: bool) -> None:
        self._box = AlignedBox(config)
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="aligned-mean") if concurrent else None
        self._pending: list[Future] = []  # adds and evictions not yet known to have succeeded
        self.busy_seconds = 0.0
        self.waited_seconds = 0.0

    @property
    def concurrent(self) -> bool:
        return self._executor is not None

    def _timed(self, func: Callable, *args: Any) -> Any:
        began = time.perf_counter()
        try:
            return func(*args)
        finally:
            self.busy_seconds += time.perf_counter() - began

    def _submit(self, func: Callable, *args: Any) -> Future | _Done:
        if self._executor is None:
            began = time.perf_counter()
            try:
                return _Done(self._timed(func, *args))
            finally:
                self.waited_seconds += time.perf_counter() - began
        return self._executor.submit(self._timed, func, *args)

    def add(self, index: int, rate: np.ndarray, sharp: np.ndarray | None = None) -> None:
        """Queue frame ``index``'s rate (and sharp) image (``AlignedBox.add``)."""
        handle = self._submit(self._box.add, index, rate, sharp)
        if isinstance(handle, Future):
            self._pending.append(handle)

    def evict(self, oldest_needed: int) -> None:
        """Queue forgetting frames older than ``oldest_needed`` (``AlignedBox.evict``)."""
        handle = self._submit(self._box.evict, oldest_needed)
        if isinstance(handle, Future):
            self._pending.append(handle)

    def mean(self, i: int, neighbours: Sequence[int]) -> "AlignedMean":
        """Queue frame ``i``'s aligned mean over ``neighbours`` (``AlignedBox.mean``)."""
        return AlignedMean(self, self._submit(self._box.mean, i, neighbours))

    def _wait(self, handle: Future | _Done) -> np.ndarray:
        began = time.perf_counter()
        try:
            for earlier in self._pending:  # an add or eviction that failed fails here, in the caller
                earlier.result()
            self._pending.clear()
            return handle.result()
        finally:
            self.waited_seconds += time.perf_counter() - began

    def close(self) -> None:
        """Let the background thread end (queued work still finishes)."""
        if self._executor is not None:
            self._executor.shutdown(wait=False)


class AlignedMean:
    """One frame's aligned mean, queued: ``result()`` waits for it."""

    def __init__(self, worker: AlignedWorker, handle: Future | _Done) -> None:
        self._worker, self._handle = worker, handle

    def result(self) -> np.ndarray:
        return self._worker._wait(self._handle)
