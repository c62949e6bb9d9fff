"""Output arrays reused once nothing else holds them.

A fresh array costs its page faults every time: glibc gives freed arrays back to the system between chunks, so a
method making 51 frames of 400x250 a chunk faults in 20 MB a chunk, and binning a 1,024-plane chunk 25.6 MB. At
TFP's and the binning's rates that was a large part of their time on this project's hosts (README, "Where the time
goes on an AVX2-only host").
"""

from __future__ import annotations

import sys

import numpy as np
from numpy.typing import DTypeLike


def _references(images: list[np.ndarray], i: int) -> int:
    """``sys.getrefcount`` of ``images[i]``, counted the same way for every list, so that the count of an image only
    a list holds (which interpreters may differ in) can be measured on a probe rather than assumed."""
    image = images[i]
    return sys.getrefcount(image)


class ImagePool:
    """Arrays of one shape and type: ``take`` returns one that no frame, view or sink references any more, else a new one.

    An image handed out is not written again while anything outside the pool refers to it or to a view of it, so
    frames a caller keeps stay as they were. Images are released in about the order they were taken, so the search
    starts after the last one taken. The pool grows only while every image in it is held, so it never holds more
    than were alive at once, and at most ``max_bytes`` of them; beyond that ``take`` allocates. A request for another
    shape or type starts the pool afresh.
    """

    def __init__(self, max_bytes: int = 128 << 20) -> None:
        self.max_bytes = max_bytes
        self.shape: tuple[int, ...] | None = None
        self.dtype: np.dtype | None = None
        self._images: list[np.ndarray] = []
        self._next = 0  # where the search for a released image starts
        self._probe = [np.empty(0, np.float32)]  # an array only the pool holds: its count means "released"

    def take(self, shape: tuple[int, ...], dtype: DTypeLike = np.float32) -> np.ndarray:
        """An array of ``shape`` and ``dtype`` (contents undefined) for the caller to overwrite completely."""
        shape, dtype = tuple(shape), np.dtype(dtype)
        if shape != self.shape or dtype != self.dtype:
            self.shape, self.dtype, self._images, self._next = shape, dtype, [], 0
        n = len(self._images)
        released = _references(self._probe, 0)
        for k in range(n):
            i = (self._next + k) % n
            if _references(self._images, i) == released:
                self._next = i + 1
                return self._images[i]
        image = np.empty(shape, dtype)
        if (n + 1) * image.nbytes <= self.max_bytes:
            self._images.append(image)
            self._next = 0
        return image
