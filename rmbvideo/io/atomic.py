"""Atomic file outputs: write to a hidden temporary name in the target folder, rename when done.

A reader (or a resumed batch run) therefore never sees a half-written file under its final name,
and a failed write leaves nothing behind. Errors of the environment (full disk, no permission,
missing folder) become :class:`~rmbvideo.errors.OutputError` naming the final path.
"""

from __future__ import annotations

import errno
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from rmbvideo.errors import OutputError

# errno values that mean "the environment cannot take this output", as opposed to a bug.
_ENVIRONMENT_ERRNOS = frozenset(
    {
        errno.ENOSPC,
        errno.EDQUOT,
        errno.EFBIG,
        errno.EACCES,
        errno.EPERM,
        errno.EROFS,
        errno.ENOENT,
        errno.ENOTDIR,
        errno.EISDIR,
        errno.EIO,
        errno.ENAMETOOLONG,
    }
)


def temp_path_for(final: Path) -> Path:
    """A fresh hidden temporary name beside ``final``: ``.name.tmp-<pid>-<random>``."""
    final = Path(final)
    return final.with_name(f".{final.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}")


def output_error(path: Path, exc: OSError) -> OutputError:
    """The user-facing error for an ``OSError`` met while writing ``path``."""
    reason = exc.strerror or str(exc)
    return OutputError(f"{path}: cannot write: {reason}")


def is_environment_error(exc: BaseException) -> bool:
    """Whether ``exc`` is an ``OSError`` caused by the disk or permissions rather than a bug."""
    return isinstance(exc, OSError) and exc.errno in _ENVIRONMENT_ERRNOS


def remove_quietly(path: Path) -> None:
    """Delete ``path`` if it exists; used for cleanup, so failures are ignored."""
    try:
        os.unlink(path)
    except OSError:
        pass


def commit(temp: Path, final: Path) -> None:
    """Rename a completed temporary file onto its final name (atomic within one folder)."""
    try:
        os.replace(temp, final)
    except OSError as exc:
        remove_quietly(temp)
        raise output_error(final, exc) from exc


@contextmanager
def atomic_path(final: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``final``; rename it onto ``final`` if the block succeeds.

    On any exception the temporary file is removed and ``final`` is left as it was. Disk-full and
    permission errors raised in the block are re-raised as ``OutputError(f"{final}: ...")``.
    """
    final = Path(final)
    if not final.parent.is_dir():
        raise OutputError(f"{final}: cannot write: folder {final.parent} does not exist")
    temp = temp_path_for(final)
    try:
        yield temp
    except BaseException as exc:
        remove_quietly(temp)
        if is_environment_error(exc):
            raise output_error(final, exc) from exc
        raise
    if not temp.exists():
        raise OutputError(f"{final}: cannot write: nothing was written to {temp.name}")
    commit(temp, final)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as temp:
        with open(temp, "wb") as handle:
            handle.write(data)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))
