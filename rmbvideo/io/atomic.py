"""Atomic file outputs: write to a hidden temporary name in the target folder, rename when done.

A reader (or a resumed batch run) therefore never sees a half-written file under its final name,
and a failed write leaves nothing behind. Errors of the environment (full disk, no permission,
missing folder) become :class:`~rmbvideo.errors.OutputError` naming the final path.
"""

from __future__ import annotations

import errno
import fnmatch
import os
import secrets
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
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


def _process_umask() -> int:
    """The process's file-creation mask (set back at once: read this way at import, before any thread writes)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: The mode a file opened for writing gets here: what every atomic output is given, whatever made it (safetensors
#: creates its files readable by their owner only, so a model trained for a group would be closed to it).
FILE_MODE = 0o666 & ~_process_umask()


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


@dataclass
class _HeldGroup:
    """One ``outputs_together`` block: the folder and name patterns it holds, and the (temporary, final) pairs held."""

    folder: Path
    names: tuple[str, ...]
    held: list[tuple[Path, Path]] = field(default_factory=list)

    def takes(self, final: Path) -> bool:
        return final.parent.resolve() == self.folder and any(fnmatch.fnmatchcase(final.name, n) for n in self.names)


#: The ``outputs_together`` blocks running, innermost last
_groups: list[_HeldGroup] = []


@contextmanager
def outputs_together(folder: Path, names: tuple[str, ...]) -> Iterator[None]:
    """Hold every atomic output written in the block into ``folder`` under a name matching one of ``names`` (glob
    patterns) at its temporary name, and rename them all onto their names when the block succeeds (signals held
    meanwhile); on any failure or stop none is, and the temporaries go. A command's reports are so all of one run: a
    full disk or a Ctrl-C at its last file leaves an earlier run's set whole, never half of each. Other files (caches
    the run reads back) are written as usual; an inner block's files go to that block alone."""
    group = _HeldGroup(Path(folder).resolve(), names)
    _groups.append(group)
    done = False
    try:
        yield
        done = True
    finally:
        _groups.remove(group)
        if not done:
            for temp, _ in group.held:
                remove_quietly(temp)
    with signals_deferred():
        for index, (temp, final) in enumerate(group.held):
            try:
                _commit_or_hold(temp, final)
            except OutputError:
                for later, _ in group.held[index + 1:]:
                    remove_quietly(later)
                raise


def _commit_or_hold(temp: Path, final: Path) -> None:
    """Rename ``temp`` onto ``final``, or hold it for the innermost ``outputs_together`` block that takes it."""
    group = next((g for g in reversed(_groups) if g.takes(final)), None)
    if group is None:
        commit(temp, final)
    else:
        group.held.append((temp, final))


@contextmanager
def atomic_path(final: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``final``; rename it onto ``final`` if the block succeeds.

    On any exception the temporary file is removed and ``final`` is left as it was. Disk-full and
    permission errors raised in the block are re-raised as ``OutputError(f"{final}: ...")``. Inside
    ``outputs_together`` the rename waits for the end of that block.
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
    try:
        os.chmod(temp, FILE_MODE)
    except OSError as exc:
        remove_quietly(temp)
        raise output_error(final, exc) from exc
    _commit_or_hold(temp, final)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as temp:
        with open(temp, "wb") as handle:
            handle.write(data)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_staging(final: Path, adopt: Callable[[Path], bool] | None = None) -> Path | None:
    """Remove what killed runs left beside ``final``: ``.name.partial-<pid>-*`` and ``.name.old-<pid>-*``
    folders whose process is gone (a live run's folders are left alone). With ``adopt``, the newest stale partial
    folder it accepts is kept and returned instead (an interrupted run to continue)."""
    import shutil

    final = Path(final)
    stale: dict[str, list[Path]] = {"partial": [], "old": []}
    for kind in stale:
        for path in final.parent.glob(f".{final.name}.{kind}-*"):
            try:
                pid = int(path.name.rsplit(f".{kind}-", 1)[1].split("-")[0])
            except ValueError:
                continue
            if not _pid_alive(pid):
                stale[kind].append(path)
    kept = None
    if adopt is not None:
        candidates = sorted((p for p in stale["partial"] if p.is_dir() and adopt(p)), key=lambda p: p.stat().st_mtime)
        kept = candidates[-1] if candidates else None
    for path in stale["partial"] + stale["old"]:
        if path != kept:
            shutil.rmtree(path, ignore_errors=True)
    return kept


_deferred: list[BaseException] | None = None  # exceptions of signals held back by signals_deferred


@contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold the exceptions of the command's signal handlers (``raise_or_defer``) back until the block is
    done, then raise the first: a step that swaps outputs is never cut in half."""
    global _deferred
    outer, _deferred = _deferred, []
    try:
        yield
    finally:
        held, _deferred = _deferred, outer
        if held:
            raise held[0]


def raise_or_defer(exc: BaseException) -> None:
    """For signal handlers: raise ``exc`` now, or at the end of the ``signals_deferred`` block running."""
    if _deferred is not None:
        _deferred.append(exc)
        return
    raise exc


def make_dir(path: Path) -> None:
    """Create folder ``path`` and its parents if missing; ``OutputError`` naming it if that fails."""
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{path}: cannot create folder: {exc.strerror or exc}") from exc


@contextmanager
def output_folder(path: Path) -> Iterator[Path]:
    """Create folder ``path`` and its missing parents (``make_dir``) for the outputs of the block; when the block fails
    or is stopped, the folders it created are removed again while empty, so a failed run leaves nothing behind."""
    path = Path(path)
    missing = [folder for folder in (path, *path.parents) if not folder.exists()]  # deepest first
    make_dir(path)
    try:
        yield path
    except BaseException:
        for folder in missing:
            try:
                folder.rmdir()
            except OSError:
                break
        raise


def check_folder_creatable(path: Path) -> None:
    """``OutputError`` up front, before a long run, when folder ``path`` could not be made or written into: its
    nearest existing ancestor is not a writable folder (``output_folder`` makes it when the outputs are ready)."""
    path = Path(path)
    existing = next(folder for folder in (path, *path.parents) if folder.exists() or folder == folder.parent)
    if not existing.is_dir():
        raise OutputError(f"{path}: cannot create folder: {existing} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: cannot create folder: {existing} is not writable")


def check_file_writable(path: Path, overwrite: bool, suffixes: tuple[str, ...] = (), example: str = "output") -> None:
    """``OutputError`` up front, before any long work, when ``path`` cannot be the one file a command writes: a
    folder, a missing folder, a name not ending in one of ``suffixes`` (any case), or an existing file when
    ``overwrite`` is not given (a capture named by mistake is never replaced by a picture or a report);
    ``example`` names the file suggested in the folder's message."""
    path = Path(path)
    if path.is_dir():
        name = example + (suffixes[0] if suffixes else "")
        raise OutputError(f"{path}: is a folder; name the file to write (e.g. {path / name})")
    if suffixes and not path.name.lower().endswith(tuple(suffix.lower() for suffix in suffixes)):
        raise OutputError(f"{path}: this command writes {' or '.join(suffixes)}; name the file so")
    if not path.parent.is_dir():
        raise OutputError(f"{path}: cannot write: folder {path.parent} does not exist")
    if path.exists() and not overwrite:
        raise OutputError(f"{path}: exists; use --overwrite to replace it")


#: Names of videos and pictures: a file's, never an output folder's (``-o video.mp4`` made a folder of that name)
MEDIA_SUFFIXES = frozenset({".mp4", ".mov", ".mkv", ".webm", ".avi", ".png", ".jpg", ".jpeg", ".gif", ".tif", ".tiff",
                            ".exr", ".hdr"})


def refuse_file_name_for_folder(folder: Path, contents: str) -> None:
    """Refuse a new output folder named like a video or picture (``-o video.mp4``): the user meant a file."""
    folder = Path(folder)
    if not folder.exists() and folder.suffix.lower() in MEDIA_SUFFIXES:
        raise OutputError(f"{folder}: names a {folder.suffix.lower()} file, but the output is a folder ({contents}): "
                          f"give e.g. -o {folder.with_suffix('')}")


def check_replaceable(final: Path, is_output: Callable[[str], bool], overwrite: bool) -> None:
    """Refuse to replace ``final`` as a whole unless it is absent, empty, or (with ``overwrite``) holds
    nothing but files ``is_output`` recognises by name: a user's own files, or the capture itself, are
    never removed with it. The current folder is refused too (it would be renamed under the shell)."""
    final = Path(final)
    if final.exists() and not final.is_dir():
        raise OutputError(f"{final}: exists and is not a folder")
    refuse_file_name_for_folder(final, "frames.mp4 or the frames, and frames.csv, go into it")
    if final.resolve() == Path.cwd().resolve():
        raise OutputError(f"{final}: is the current folder; the outputs go into a folder of their own, replaced "
                          "as a whole: name a new one")
    if not final.is_dir():
        return
    names = sorted(entry.name for entry in final.iterdir())
    if not names:
        return
    foreign = [name for name in names if not is_output(name)]
    if foreign:
        shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        raise OutputError(f"{final}: holds files this command does not write ({shown}); the folder is replaced "
                          "as a whole, so give a new or empty one")
    if not overwrite:
        raise OutputError(f"{final}: holds earlier outputs; use --overwrite to replace them")


@contextmanager
def staged_folder(final: Path, is_output: Callable[[str], bool], overwrite: bool = False, *,
                  adopt: Callable[[Path], bool] | None = None,
                  keep: Callable[[Path], bool] | None = None) -> Iterator[Path]:
    """A fresh hidden folder beside ``final`` to write a whole output into; when the block ends
    without error it replaces ``final`` (its previous content is removed only once the new one is in
    place), otherwise it is deleted. At any moment ``final`` is absent, the previous complete output,
    or the new complete output. ``final`` must pass ``check_replaceable`` (``is_output`` names the files
    an earlier output may hold). Stale staging folders of killed runs are removed first, but for the newest that
    ``adopt`` accepts, which becomes this run's folder (a resumed run); a failed run's folder is kept where
    ``keep`` says so (for a run that can be resumed)."""
    import shutil

    shown = Path(final)
    check_replaceable(shown, is_output, overwrite)
    final = Path(os.path.abspath(shown))  # ".." and "a/." have no name to stage beside
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        adopted = remove_stale_staging(final, adopt)
        token = f"{os.getpid()}-{secrets.token_hex(4)}"
        staging = final.with_name(f".{final.name}.partial-{token}")
        if adopted is not None:  # renamed to this process's name, so no other run takes it for stale
            os.rename(adopted, staging)
        else:
            staging.mkdir()
    except OSError as exc:
        raise output_error(shown, exc) from exc
    try:
        yield staging
        old = final.with_name(f".{final.name}.old-{token}")
        with signals_deferred():  # a signal now would leave the old output aside, or half removed
            if not overwrite:
                _rename_unless_filled(staging, final, shown)
                return
            if final.exists():
                os.rename(final, old)
            os.rename(staging, final)
            shutil.rmtree(old, ignore_errors=True)
    except BaseException as exc:
        if keep is None or not keep(staging):
            shutil.rmtree(staging, ignore_errors=True)
        if isinstance(exc, OSError) and is_environment_error(exc):
            raise output_error(shown, exc) from exc
        if isinstance(exc, OutputError) and str(staging) in str(exc):  # name the folder the user gave
            raise OutputError(str(exc).replace(str(staging), str(shown))) from exc
        raise


def _rename_unless_filled(staging: Path, final: Path, shown: Path) -> None:
    """Rename ``staging`` onto ``final`` only while ``final`` is absent or empty: the rename itself refuses a
    folder another run has filled since this one started (two runs racing into one new folder), so without
    ``--overwrite`` no complete output is ever replaced."""
    try:
        os.rename(staging, final)
    except OSError as exc:
        if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
            raise
        raise OutputError(f"{shown}: was filled by another run while this one wrote its outputs; that run's "
                          "outputs are kept (use --overwrite to replace them)") from None
