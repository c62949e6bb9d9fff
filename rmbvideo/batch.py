"""Batch conversion: find captures, name their outputs, run each in isolation, resume, report.

Layout of a batch folder ``OUTDIR``::

    <name>/                    a finished capture: the outputs of ``run_reconstruction`` + .complete.json
    .<name>.partial-<token>/   work in progress, renamed to <name> as the very last step
    batch-report.json          the report of the latest run (written atomically)
    .batch.lock                held while a batch runs, so two runs never share a folder

Completion: a capture is done when ``<name>/.complete.json`` exists, its digest of everything that
changes the output (method, format, window and every other option except the chunk size; the
effective geometry and rate; the input's size and mtime; options naming files; the code version)
matches this run, and every file it lists is present with its recorded size. Outputs are written
into the partial folder, the marker is written there after every output is committed, and the
folder is renamed into place last, so an interrupted run (Ctrl-C, kill -9, crash) leaves at most a
partial folder, which the next run removes and redoes; a complete capture is skipped untouched.
"""

from __future__ import annotations

import glob
import hashlib
import json
import logging
import os
import re
import secrets
import shutil
import sys
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from multiprocessing import get_context
from pathlib import Path, PurePath
from typing import Any, Literal

from rmbvideo import __version__
from rmbvideo.errors import InputError, OutputError, RmbvideoError
from rmbvideo.io.atomic import atomic_write_text

log = logging.getLogger(__name__)

MARKER_NAME = ".complete.json"
REPORT_NAME = "batch-report.json"
LOCK_NAME = ".batch.lock"
MARKER_FORMAT = "rmbvideo-batch-complete"
REPORT_FORMAT = "rmbvideo-batch-report"
# run_reconstruction keywords that do not change the output files (the output does not depend on them)
NON_OUTPUT_OPTIONS = frozenset({"chunk_planes", "progress"})
_CAPTURE_SUFFIX = ".dat"
_UNSAFE_NAME_CHARS = re.compile(r"[^A-Za-z0-9._+-]")
_HASH_CHARS = 8
_THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS")

Status = Literal["ok", "failed", "skipped"]


class SchedulerError(RmbvideoError):
    """The Dask cluster cannot be used: Dask is not installed or the scheduler cannot be reached."""


@dataclass(frozen=True)
class FoundCapture:
    """A capture found on the command line; ``relative`` (to the argument that found it) names its output."""

    path: Path
    relative: PurePath


@dataclass(frozen=True)
class CaptureJob:
    """One capture to convert: its input, the batch folder, its output name, ``run_reconstruction`` keywords."""

    input_path: Path
    batch_dir: Path
    name: str
    options: dict[str, Any] = field(default_factory=dict)

    @property
    def output_dir(self) -> Path:
        """Where the finished outputs of this capture live."""
        return self.batch_dir / self.name


@dataclass
class CaptureResult:
    """What happened to one capture (one entry of ``batch-report.json``)."""

    input: str
    output: str
    status: Status
    error: str | None = None
    frames: int | None = None
    seconds: float = 0.0


# ----------------------------------------------------------------------------------------------
# Discovery and naming


def discover_captures(inputs: Sequence[str | os.PathLike[str]]) -> list[FoundCapture]:
    """Expand files, folders (searched recursively for ``.dat``) and globs, in order, without duplicates.

    Globs are expanded here, so quoted patterns work (``**`` is recursive). A literal path that does
    not exist is kept, so that it is reported as a failed capture; a glob that matches nothing is
    logged. Raises ``InputError`` when nothing at all was found.
    """
    found: list[FoundCapture] = []
    seen: set[Path] = set()

    def add(path: Path, relative: PurePath) -> None:
        key = path.resolve()
        if key not in seen:
            seen.add(key)
            found.append(FoundCapture(path, relative))

    for item in inputs:
        text = os.fspath(item)
        path = Path(text)
        if glob.has_magic(text):
            root = _glob_root(text)
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                log.warning("%s: no file matches this pattern", text)
            for match in map(Path, matches):
                if match.is_dir():
                    for capture in _captures_in(match):
                        add(capture, capture.relative_to(root))
                else:
                    add(match, match.relative_to(root))
        elif path.is_dir():
            captures = _captures_in(path)
            if not captures:
                log.warning("%s: folder holds no %s files", path, _CAPTURE_SUFFIX)
            for capture in captures:
                add(capture, capture.relative_to(path))
        else:
            add(path, PurePath(path.name))
    if not found:
        raise InputError(f"{', '.join(map(os.fspath, inputs)) or '(no inputs)'}: no {_CAPTURE_SUFFIX} captures found")
    return found


def _captures_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.suffix.lower() == _CAPTURE_SUFFIX and p.is_file())


def _glob_root(pattern: str) -> Path:
    """The folder made of the pattern's leading parts without wildcards."""
    parts: list[str] = []
    for part in PurePath(pattern).parts:
        if glob.has_magic(part):
            break
        parts.append(part)
    return Path(*parts) if parts else Path(".")


def output_names(captures: Sequence[FoundCapture]) -> list[str]:
    """A folder name per capture: its relative path with separators as ``__``, suffix dropped.

    Deterministic: unsafe characters become ``_`` and names that collide (ignoring case, as some
    file systems do) or clash with the batch's own files all get ``-<hash of the full path>``.
    """
    base = [_safe_name(c.relative) for c in captures]
    counts = Counter(name.casefold() for name in base)
    reserved = {REPORT_NAME.casefold(), LOCK_NAME.casefold()}
    names = []
    for capture, name in zip(captures, base):
        if counts[name.casefold()] > 1 or name.casefold() in reserved:
            digest = hashlib.sha1(str(capture.path.resolve()).encode("utf-8")).hexdigest()[:_HASH_CHARS]
            name = f"{name}-{digest}"
        names.append(name)
    return names


def _safe_name(relative: PurePath) -> str:
    parts = [p for p in relative.parts if p not in ("", ".", "..", "/")]
    if parts and parts[-1].lower().endswith(_CAPTURE_SUFFIX):
        parts[-1] = parts[-1][: -len(_CAPTURE_SUFFIX)]
    name = "__".join(_UNSAFE_NAME_CHARS.sub("_", p) for p in parts if p)
    if name.startswith("."):
        name = "_" + name[1:]
    return name or "capture"


def plan_jobs(inputs: Sequence[str | os.PathLike[str]], batch_dir: Path, options: dict[str, Any]) -> list[CaptureJob]:
    """Discover the captures of ``inputs`` and make one job per capture writing under ``batch_dir``."""
    captures = discover_captures(inputs)
    return [CaptureJob(c.path, Path(batch_dir), name, dict(options))
            for c, name in zip(captures, output_names(captures))]


# ----------------------------------------------------------------------------------------------
# Completion markers


def output_fingerprint(job: CaptureJob, reader: Any) -> dict[str, Any]:
    """Everything that decides the output of ``job``, as JSON data (``reader``: the opened capture)."""
    options = {k: _describe(v) for k, v in sorted(job.options.items())
               if k not in NON_OUTPUT_OPTIONS and k != "capture"}
    g = reader.geometry
    stat = job.input_path.stat()
    return {
        "code_version": __version__,
        "options": options,
        "capture": {"width": g.width, "height": g.height, "header_cols": g.header_cols, "flip": g.flip,
                    "rate_hz": reader.rate_hz},
        "input": {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns},
    }


def _describe(value: Any) -> Any:
    """JSON form of an option value; a value naming an existing file also records its size and mtime."""
    if isinstance(value, dict):
        return {str(k): _describe(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_describe(v) for v in value]
    if isinstance(value, (str, os.PathLike)):
        text = os.fspath(value)
        if text and os.path.isfile(text):
            stat = os.stat(text)
            return {"file": text, "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}
        return text
    if value is None or isinstance(value, (bool, int, float)):
        return value
    return str(value)


def fingerprint_digest(fingerprint: dict[str, Any]) -> str:
    """A stable hash of a fingerprint."""
    return hashlib.sha256(json.dumps(fingerprint, sort_keys=True).encode("utf-8")).hexdigest()


def read_marker(output_dir: Path, digest: str) -> dict[str, Any] | None:
    """The completion marker of ``output_dir`` if it proves a complete output for ``digest``, else ``None``."""
    try:
        marker = json.loads((output_dir / MARKER_NAME).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(marker, dict) or marker.get("format") != MARKER_FORMAT or marker.get("digest") != digest:
        return None
    files = marker.get("files")
    if not isinstance(files, list):
        return None
    for entry in files:
        try:
            if (output_dir / entry["path"]).stat().st_size != entry["size"]:
                return None
        except (OSError, KeyError, TypeError):
            return None
    return marker


def _write_marker(work: Path, job: CaptureJob, fingerprint: dict[str, Any], frames: int, planes: int,
                  seconds: float) -> None:
    files = sorted(p for p in work.rglob("*") if p.is_file())
    marker = {
        "format": MARKER_FORMAT,
        "version": 1,
        "input": str(job.input_path),
        "digest": fingerprint_digest(fingerprint),
        "fingerprint": fingerprint,
        "files": [{"path": p.relative_to(work).as_posix(), "size": p.stat().st_size} for p in files],
        "frames": frames,
        "planes": planes,
        "seconds": seconds,
        "completed_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    atomic_write_text(work / MARKER_NAME, json.dumps(marker, indent=2) + "\n")


# ----------------------------------------------------------------------------------------------
# Running one capture


def run_capture_job(job: CaptureJob) -> CaptureResult:
    """Convert one capture, or skip it when its output is already complete; never raises for bad input.

    Errors of the input or environment (and unexpected errors, logged with their traceback) become
    a ``failed`` result; the previous outputs of this capture, if any, are left as they were.
    """
    from rmbvideo.io.capture import open_capture
    from rmbvideo.recon.run import run_reconstruction

    began = time.perf_counter()
    result = CaptureResult(input=str(job.input_path), output=str(job.output_dir), status="failed")
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
        work = job.batch_dir / f".{job.name}.partial-{os.getpid()}-{secrets.token_hex(4)}"
        try:
            summary = run_reconstruction(job.input_path, work, **{**job.options, "progress": False})
            _make_dir(work)
            _write_marker(work, job, fingerprint, summary.frames, summary.planes, summary.seconds)
            _install(work, job.output_dir)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        result.status, result.frames = "ok", summary.frames
    except RmbvideoError as exc:
        result.error = str(exc)
    except OSError as exc:
        result.error = f"{exc.filename or job.input_path}: {exc.strerror or exc}"
    except Exception as exc:  # a bug in one capture must not stop the batch; keep its traceback in the log
        log.exception("%s: unexpected error", job.input_path)
        result.error = f"{job.input_path}: unexpected error: {type(exc).__name__}: {exc}"
    finally:
        result.seconds = time.perf_counter() - began
    if result.status == "failed":
        log.warning("%s", result.error)
    return result


def _remove_leftovers(job: CaptureJob) -> None:
    """Remove partial or replaced folders of ``job`` left by an interrupted run (the batch lock is held)."""
    for leftover in job.batch_dir.glob(f".{glob.escape(job.name)}.*-*"):
        if leftover.name.startswith((f".{job.name}.partial-", f".{job.name}.old-")):
            log.info("removing %s left by an interrupted run", leftover)
            shutil.rmtree(leftover, ignore_errors=True)


def _make_dir(path: Path) -> None:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{path}: cannot create folder: {exc.strerror or exc}") from exc


def _install(work: Path, final: Path) -> None:
    """Rename the finished ``work`` folder onto ``final``, moving an older ``final`` aside first."""
    try:
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
    except OSError as exc:
        raise OutputError(f"{final}: cannot move the finished output into place: {exc.strerror or exc}") from exc


# ----------------------------------------------------------------------------------------------
# Running many captures


def default_workers() -> int:
    """One worker process per core available to this process."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def limit_threads(threads: int) -> None:
    """Cap the math libraries' threads in this process (torch, OpenCV, OpenMP/BLAS) at ``threads``."""
    for name in _THREAD_ENV:
        os.environ[name] = str(threads)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)
    import cv2

    cv2.setNumThreads(threads)


@contextmanager
def batch_lock(batch_dir: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``batch_dir`` (released when the process ends, even by kill -9)."""
    import fcntl

    path = batch_dir / LOCK_NAME
    try:
        handle = open(path, "a+")
    except OSError as exc:
        raise OutputError(f"{batch_dir}: cannot write: {exc.strerror or exc}") from exc
    with handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise OutputError(f"{batch_dir}: another batch is running into this folder") from None
        yield


def run_batch(jobs: Sequence[CaptureJob], batch_dir: Path, *, workers: int | None = None,
              scheduler: str | None = None, progress: bool = False) -> list[CaptureResult]:
    """Run ``jobs`` (one process per worker, or on the Dask scheduler at ``scheduler``) and write the report.

    Returns the results in job order. One capture failing does not stop the others. On Ctrl-C the
    report is still written, with the unfinished captures as failed, and ``KeyboardInterrupt`` is
    re-raised.
    """
    from tqdm import tqdm

    batch_dir = Path(batch_dir)
    _make_dir(batch_dir)
    results: list[CaptureResult | None] = [None] * len(jobs)
    workers = min(workers or default_workers(), max(1, len(jobs)))
    started = datetime.now(timezone.utc)
    with batch_lock(batch_dir), tqdm(total=len(jobs), unit="capture", disable=not progress,
                                     dynamic_ncols=True) as bar:
        def record(i: int, result: CaptureResult) -> None:
            results[i] = result
            bar.update(1)
            bar.set_postfix_str(f"{Path(result.input).name}: {result.status}", refresh=False)

        try:
            if scheduler is not None:
                _run_on_dask(jobs, scheduler, record)
            elif workers == 1:
                for i, job in enumerate(jobs):
                    record(i, run_capture_job(job))
            else:
                _run_in_processes(jobs, workers, record)
        except KeyboardInterrupt:
            _fill_unfinished(jobs, results, "interrupted before it finished")
            write_report(batch_dir, results, started)
            raise
    write_report(batch_dir, results, started)
    return results  # type: ignore[return-value]


def _fill_unfinished(jobs: Sequence[CaptureJob], results: list[CaptureResult | None], reason: str) -> None:
    for i, job in enumerate(jobs):
        if results[i] is None:
            results[i] = CaptureResult(str(job.input_path), str(job.output_dir), "failed",
                                       error=f"{job.input_path}: {reason}")


def _run_in_processes(jobs: Sequence[CaptureJob], workers: int,
                      record: Callable[[int, CaptureResult], None]) -> None:
    """Run jobs on ``workers`` spawned processes, each limited to its share of the cores.

    At most ``workers`` jobs are in flight. When a worker dies (killed, out of memory, crash), the
    jobs it took down are retried once, alone, so a capture that kills its worker fails by itself.
    """
    threads = max(1, default_workers() // workers)
    pending = deque(range(len(jobs)))
    crashes: Counter[int] = Counter()

    def worker_died(i: int) -> None:
        crashes[i] += 1
        if crashes[i] > 1:
            record(i, CaptureResult(str(jobs[i].input_path), str(jobs[i].output_dir), "failed",
                                    error=f"{jobs[i].input_path}: worker process died "
                                          "(killed, out of memory or crashed)"))
        else:
            log.warning("%s: a worker process died while this capture ran; retrying it alone",
                        jobs[i].input_path)
            pending.appendleft(i)

    while pending:
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"),
                                 initializer=limit_threads, initargs=(threads,)) as pool:
            running: dict[Future[CaptureResult], int] = {}
            broken = False
            while (pending or running) and not broken:
                while pending and len(running) < workers and not any(crashes[i] for i in running.values()):
                    if crashes[pending[0]] and running:
                        break
                    i = pending.popleft()
                    running[pool.submit(run_capture_job, jobs[i])] = i
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in done:
                    i = running.pop(future)
                    try:
                        record(i, future.result())
                    except BrokenProcessPool:
                        broken = True
                        worker_died(i)
            for i in running.values():  # every job still in a broken pool went down with it
                worker_died(i)


def _run_on_dask(jobs: Sequence[CaptureJob], address: str, record: Callable[[int, CaptureResult], None]) -> None:
    """Run jobs on the Dask distributed cluster whose scheduler is at ``address`` (``rmbvideo[cluster]``).

    Input and output paths must be visible to the workers at the same names (a shared file system).
    Each task limits its math threads to its worker's share of that machine's cores.
    """
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise SchedulerError("--scheduler needs Dask: pip install 'rmbvideo[cluster]'") from None
    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise SchedulerError(f"{address}: cannot reach the Dask scheduler ({exc})") from None
    with client:
        shares = _dask_thread_shares(client)
        futures = {client.submit(run_capture_job_on_dask, job, shares, pure=False): i
                   for i, job in enumerate(jobs)}
        try:
            for future in as_completed(futures):
                i = futures[future]
                try:
                    record(i, future.result())
                except Exception as exc:  # the worker died or the task was lost
                    record(i, CaptureResult(str(jobs[i].input_path), str(jobs[i].output_dir), "failed",
                                            error=f"{jobs[i].input_path}: Dask task failed: {exc}"))
        except KeyboardInterrupt:
            client.cancel(list(futures))
            raise


def _dask_thread_shares(client: Any) -> dict[str, int]:
    """Threads per task for each worker: that machine's cores over the task slots of all its workers."""
    workers = client.scheduler_info().get("workers", {})
    cores = client.run(os.cpu_count)
    slots: Counter[str] = Counter()
    for info in workers.values():
        slots[info.get("host", "")] += max(1, int(info.get("nthreads", 1)))
    return {address: max(1, (cores.get(address) or 1) // max(1, slots[info.get("host", "")]))
            for address, info in workers.items()}


def run_capture_job_on_dask(job: CaptureJob, shares: dict[str, int]) -> CaptureResult:
    """``run_capture_job`` inside a Dask worker, with the math threads limited to the worker's share."""
    from distributed import get_worker

    limit_threads(shares.get(get_worker().address, 1))
    return run_capture_job(job)


# ----------------------------------------------------------------------------------------------
# Report


def write_report(batch_dir: Path, results: Sequence[CaptureResult | None], started: datetime) -> Path:
    """Write ``batch-report.json`` (atomically) and return its path."""
    entries = [asdict(r) for r in results if r is not None]
    totals = Counter(e["status"] for e in entries)
    report = {
        "format": REPORT_FORMAT,
        "version": 1,
        "code_version": __version__,
        "started": started.isoformat(timespec="seconds"),
        "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "totals": {status: totals.get(status, 0) for status in ("ok", "failed", "skipped")},
        "captures": entries,
    }
    path = Path(batch_dir) / REPORT_NAME
    atomic_write_text(path, json.dumps(report, indent=2) + "\n")
    return path


def summary_table(results: Sequence[CaptureResult]) -> str:
    """A plain-text table of the results: one row per capture, then the totals."""
    rows = [("STATUS", "FRAMES", "SECONDS", "INPUT", "ERROR")]
    for r in results:
        rows.append((r.status, "-" if r.frames is None else str(r.frames), f"{r.seconds:.2f}", r.input,
                     r.error or ""))
    widths = [max(len(row[k]) for row in rows) for k in range(4)]
    lines = ["  ".join(cell.ljust(widths[k]) if k < 4 else cell for k, cell in enumerate(row)).rstrip()
             for row in rows]
    totals = Counter(r.status for r in results)
    lines.append(f"{len(results)} captures: {totals['ok']} ok, {totals['skipped']} skipped, "
                 f"{totals['failed']} failed")
    return "\n".join(lines)
