"""Fixed-size records of a capture file, read by position into fresh buffers.

Positional reads rather than a memory map: a file that is truncated while it is being read (a capture
still being copied, a full disk on the writer's side) gives a short read and an ``InputError`` naming
it, where a mapping would kill the process with SIGBUS; resident memory is the chunk being read and
nothing more. Pipes and devices are refused up front: a capture is read by position, and a FIFO would
block forever waiting for a writer.
"""

from __future__ import annotations

import stat
from pathlib import Path

import numpy as np

from rmbvideo.errors import InputError


def regular_file_size(path: Path) -> int:
    """Size of ``path`` in bytes; ``InputError`` if it is missing, a folder, a pipe or a device."""
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if stat.S_ISDIR(info.st_mode):
        raise InputError(f"{path}: is a directory, not a capture file")
    if not stat.S_ISREG(info.st_mode):
        raise InputError(f"{path}: not a regular file (a pipe or device); save the stream to a file first")
    return info.st_size


class RecordFile:
    """``count`` records of ``record_bytes`` each, starting ``offset`` bytes into ``path``."""

    def __init__(self, path: Path, record_bytes: int, count: int, offset: int = 0) -> None:
        self.path = path
        self.record_bytes = record_bytes
        self.count = count
        self.offset = offset
        self._scratch: np.ndarray | None = None
        try:
            self._file = open(path, "rb", buffering=0)
        except OSError as exc:
            raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None

    def read(self, start: int, stop: int, scratch: bool = False) -> np.ndarray:
        """Records ``start..stop`` as a read-only (stop - start, record_bytes) uint8 array.

        ``scratch``: read into a buffer reused by the next scratch read (no fresh pages to fault in per
        chunk); only for callers done with the data before they read again."""
        count = stop - start
        if scratch:
            if self._scratch is None or len(self._scratch) < count:
                self._scratch = np.empty((count, self.record_bytes), dtype=np.uint8)
            out = self._scratch[:count]
            out.flags.writeable = True
        else:
            out = np.empty((count, self.record_bytes), dtype=np.uint8)
        view = memoryview(out).cast("B")
        done = 0
        try:
            self._file.seek(self.offset + start * self.record_bytes)
            while done < len(view):
                got = self._file.readinto(view[done:])
                if not got:
                    raise InputError(f"{self.path}: the file shrank while being read (records {start}..{stop} "
                                     f"of {self.count} are gone); was it still being written?")
                done += got
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read: {exc.strerror or exc}") from None
        out.flags.writeable = False
        return out

    def take(self, indices: np.ndarray) -> np.ndarray:
        """The records at ``indices`` (a few, e.g. for sampling), stacked."""
        return np.concatenate([self.read(int(i), int(i) + 1) for i in indices]) if len(indices) else \
            np.empty((0, self.record_bytes), np.uint8)

    def close(self) -> None:
        self._file.close()
