"""Convert one capture in isolation: into a partial folder, marker last, renamed into place."""

from __future__ import annotations

import errno
import glob
import logging
import os
import secrets
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from rmbvideo.batch.jobs import MARKER_NAME, CaptureJob, CaptureResult
from rmbvideo.batch.markers import (
    fingerprint_digest,
    output_fingerprint,
    read_marker,
    write_marker,
)
from rmbvideo.errors import OutputError, RmbvideoError
from rmbvideo.io.atomic import check_replaceable, make_dir, signals_deferred
from rmbvideo.io.sinks import is_sink_output

log = logging.getLogger(__name__)
_OUTPUT_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS}

def run_capture_job(job: CaptureJob) -> CaptureResult:
    """Convert one capture, or skip it when its output is already complete; never raises for bad input.

    Errors of the input or environment (and unexpected errors, logged with their traceback) become
    a ``failed`` result; the previous outputs of this capture, if any, are left as they were. What the
    conversion warned of is kept in the result (the report stays with the outputs; a terminal scrolls away).
    """
    warned: list[str] = []
    with warnings_kept(warned):
        result = _convert_capture(job)
    result.warnings = warned
    if result.status == "failed":
        log.warning("%s", result.error)
    return result


def _convert_capture(job: CaptureJob) -> CaptureResult:
    """``run_capture_job`` but for its warnings."""
    from rmbvideo.io.capture import open_capture
    from rmbvideo.recon.run import run_reconstruction

    began = time.perf_counter()
    result = CaptureResult(input=str(job.input_path), output=str(job.output_dir), status="failed")
    work: Path | None = None
    try:
        capture = dict(job.options.get("capture") or {})
        reader = open_capture(job.input_path, **{k: capture.get(k) for k in
                                                 ("width", "height", "flip", "header_cols", "rate_hz")})
        fingerprint = output_fingerprint(job, reader)
        _remove_leftovers(job)
        marker = read_marker(job.output_dir, fingerprint_digest(fingerprint))
        if marker is not None:
            log.info("%s: complete in %s, skipped", job.input_path, job.output_dir)
            result.status, result.frames = "skipped", marker.get("frames")
            return result
        check_replaceable(job.output_dir, _is_capture_output, overwrite=True)
        work = resumable_work(job) if job.options.get("resume") else (
            job.batch_dir / f".{job.name}.partial-{os.getpid()}-{secrets.token_hex(4)}")
        try:
            summary = run_reconstruction(job.input_path, work, **{**job.options, "progress": False})
            make_dir(work)
            write_marker(work, job, fingerprint, summary.frames + summary.kept, summary.planes, summary.seconds)
            _install(work, job.output_dir)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        result.status, result.frames = "ok", summary.frames + summary.kept
    except RmbvideoError as exc:
        result.error = _as_output(str(exc), work, job.output_dir)
    except OSError as exc:  # a write failure (full disk, quota, read-only) is the output's, not the input's
        blamed = exc.filename or (job.output_dir if exc.errno in _OUTPUT_ERRNOS else job.input_path)
        result.error = _as_output(f"{blamed}: {exc.strerror or exc}", work, job.output_dir)
    except Exception as exc:  # a bug in one capture must not stop the batch; keep its traceback in the log
        log.exception("%s: unexpected error", job.input_path)
        result.error = f"{job.input_path}: unexpected error: {type(exc).__name__}: {exc}"
    finally:
        result.seconds = time.perf_counter() - began
    return result


class _WarningsKept(logging.Handler):
    """Keeps the text of each warning (not error) logged through it."""

    def __init__(self, kept: list[str]) -> None:
        super().__init__(logging.WARNING)
        self.kept = kept

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno == logging.WARNING:
            self.kept.append(record.getMessage())


@contextmanager
def warnings_kept(kept: list[str]) -> Iterator[None]:
    """Append to ``kept`` what this package warns of inside the block."""
    handler = _WarningsKept(kept)
    package = logging.getLogger("rmbvideo")
    package.addHandler(handler)
    try:
        yield
    finally:
        package.removeHandler(handler)


def _as_output(message: str, work: Path | None, output_dir: Path) -> str:
    """``message`` naming the output folder where it names the hidden folder the capture was written into (removed
    by now): the user knows the one, never sees the other."""
    return message.replace(str(work), str(output_dir)) if work is not None else message


def finished_result(job: CaptureJob) -> CaptureResult | None:
    """An ``ok`` result if ``job``'s output is complete on disk (its marker matches), else None.

    Used when a batch is interrupted: a capture that a worker finished before the parent heard of it
    is reported as done, not as interrupted."""
    from rmbvideo.io.capture import open_capture

    try:
        capture = dict(job.options.get("capture") or {})
        reader = open_capture(job.input_path, **{k: capture.get(k) for k in
                                                 ("width", "height", "flip", "header_cols", "rate_hz")})
        marker = read_marker(job.output_dir, fingerprint_digest(output_fingerprint(job, reader)))
    except (RmbvideoError, OSError, ValueError):
        return None
    if marker is None:
        return None
    return CaptureResult(input=str(job.input_path), output=str(job.output_dir), status="ok",
                         frames=marker.get("frames"))


def resumable_work(job: CaptureJob) -> Path:
    """The hidden folder a ``--resume`` job is reconstructed into: the same for every run of the job, so that the
    frames an interrupted run kept beside it (``..NAME.resumable.partial-*``, ``rmbvideo.recon.resume``) are taken up
    by the next run with the same options."""
    return job.batch_dir / f".{job.name}.resumable"


def _remove_leftovers(job: CaptureJob) -> None:
    """Remove partial or replaced folders of ``job`` left by an interrupted run (the batch lock is held), and the
    folder its reconstruction was staged in beside them (``..NAME.partial-*``): a ``--resume`` job's kept frames
    stay for it to take up, and are removed by a job without ``--resume``."""
    leftovers = [p for p in job.batch_dir.glob(f".{glob.escape(job.name)}.*-*")
                 if p.name.startswith((f".{job.name}.partial-", f".{job.name}.old-"))]
    leftovers += job.batch_dir.glob(f"..{glob.escape(job.name)}.partial-*")
    work = resumable_work(job)
    leftovers += [work] if work.exists() else []  # killed between its run's end and the install
    if not job.options.get("resume"):
        leftovers += work.parent.glob(f".{glob.escape(work.name)}.partial-*")
    for leftover in leftovers:
        log.info("removing %s left by an interrupted run", leftover)
        shutil.rmtree(leftover, ignore_errors=True)


def _is_capture_output(name: str) -> bool:
    """A file an earlier run of a capture left in its folder: the sinks' outputs and the completion marker."""
    return is_sink_output(name) or name == MARKER_NAME


def _install(work: Path, final: Path) -> None:
    """Rename the finished ``work`` folder onto ``final``, moving an older ``final`` aside first (with the
    command's signals held back, so a Ctrl-C cannot leave the older output aside)."""
    try:
        with signals_deferred():
            _swap(work, final)
    except OSError as exc:
        raise OutputError(f"{final}: cannot move the finished output into place: {exc.strerror or exc}") from exc


def _swap(work: Path, final: Path) -> None:
    """``work`` becomes ``final``; an older ``final`` is moved aside, then removed."""
    if final.exists() or final.is_symlink():
        old = final.with_name(f".{final.name}.old-{os.getpid()}-{secrets.token_hex(4)}")
        os.replace(final, old)
        os.replace(work, final)
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)
    else:
        os.replace(work, final)
