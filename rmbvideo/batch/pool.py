"""Run many captures: worker processes or a Dask cluster, one batch per folder at a time."""

from __future__ import annotations

import logging
import os
import signal
import sys
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from datetime import datetime, timezone
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from rmbvideo.allocator import keep_freed_memory
from rmbvideo.batch.jobs import (
    LOCK_NAME,
    THREAD_ENV,
    CaptureJob,
    CaptureResult,
    SchedulerError,
)
from rmbvideo.batch.report import write_report
from rmbvideo.batch.runner import finished_result, run_capture_job
from rmbvideo.errors import OutputError
from rmbvideo.io.atomic import make_dir, refuse_file_name_for_folder, signals_deferred
from rmbvideo.threads import available_cores

log = logging.getLogger(__name__)
#: A Dask batch polls its tasks this often, and fails what is left after this long with no live worker.
DASK_POLL_S, DASK_NO_WORKER_S = 2.0, 60.0
#: The warning filter of the resource tracker a process batch starts (``start_quiet_resource_tracker``).
TRACKER_WARNING_FILTER = "ignore:resource_tracker:UserWarning"
#: After a stop, the captures in flight have this long to remove their partial output before their workers are killed.
WORKER_CLEANUP_S = 30.0
#: How often the batch looks up from waiting on its workers: a signal the kernel hands to one of its other threads
#: (the pool's) runs its handler only once the main thread is back in Python, so an untimed wait heard a Ctrl-C only
#: when a capture finished, and never while the workers were stuck.
WAKE_S = 0.2


def default_workers() -> int:
    """One worker process per core available to this process."""
    return available_cores()


def die_with_parent() -> None:
    """Linux: this process is killed when its parent dies (even by kill -9), so a worker never goes on
    writing after the batch that started it is gone (the next run removes its partial folder); elsewhere
    nothing happens. SIGKILL, not SIGTERM: SIGTERM is how the batch asks a worker to stop and clean up."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


#: Whether this worker process is running a capture now (set by ``run_in_worker``), and whether it was told to stop.
_capture_running = False
_interrupted = False


def _worker_stopped(signum: int, frame: Any) -> None:
    """SIGINT (a terminal's Ctrl-C reaches the whole process group) or SIGTERM (the batch stopping its workers) in a
    worker: a running capture is interrupted, once, and cleans up as in the batch's own process. An idle worker stays
    until the batch shuts the pool down: a worker that left by itself would break the pool, which then kills the
    other workers mid-cleanup."""
    global _interrupted
    if _interrupted:
        return  # a second signal must not cut the first one's cleanup short
    _interrupted = True
    if _capture_running:
        raise KeyboardInterrupt


def start_worker(threads: int, log_level: int) -> None:
    """Initialiser of a batch worker process: dies with the batch, stops as above, uses ``threads`` threads and
    the allocator policy of every command, and logs its warnings to stderr (debug messages too at ``-v``) as the
    batch does: its per-capture information would interleave without naming the capture."""
    die_with_parent()
    logging.basicConfig(level=logging.DEBUG if log_level <= logging.DEBUG else logging.WARNING,
                        format="rmbvideo: %(message)s")
    signal.signal(signal.SIGTERM, _worker_stopped)
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # a batch started with Ctrl-C ignored keeps it so
        signal.signal(signal.SIGINT, _worker_stopped)
    limit_threads(threads)
    keep_freed_memory()


def run_in_worker(job: CaptureJob) -> CaptureResult:
    """``run_capture_job`` in a worker process, marked as running for its SIGINT handler."""
    global _capture_running
    if _interrupted:  # the stop came while this job was on its way to the worker
        raise KeyboardInterrupt
    _capture_running = True
    try:
        return run_capture_job(job)
    finally:
        _capture_running = False


def limit_threads(threads: int) -> None:
    """Cap the math libraries' threads in this process (torch, OpenCV, OpenMP/BLAS) at ``threads``."""
    for name in THREAD_ENV:
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
    refuse_file_name_for_folder(batch_dir, "one output folder per capture and the batch report go into it")
    make_dir(batch_dir)
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
    """Results for the jobs not heard back from: done if their output is complete on disk, else failed."""
    for i, job in enumerate(jobs):
        if results[i] is None:
            results[i] = finished_result(job) or _failed(job, reason)


def start_quiet_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (the pool's queues' semaphores are registered with it) with its
    warning of leaked semaphores off. When a batch is killed (kill -9) the tracker removes them, as it should, then
    warned of "7 leaked semaphore objects" in two lines naming one of its own files. It reads its warning filters
    from the environment it starts with, so they are set for that start only; a tracker already running is kept."""
    from multiprocessing import resource_tracker

    before = os.environ.get("PYTHONWARNINGS")
    os.environ["PYTHONWARNINGS"] = ",".join(filter(None, (before, TRACKER_WARNING_FILTER)))
    try:
        resource_tracker.ensure_running()
    finally:
        if before is None:
            del os.environ["PYTHONWARNINGS"]
        else:
            os.environ["PYTHONWARNINGS"] = before


def _run_in_processes(jobs: Sequence[CaptureJob], workers: int,
                      record: Callable[[int, CaptureResult], None]) -> None:
    """Run jobs on ``workers`` spawned processes, each limited to its share of the cores.

    At most ``workers`` jobs are in flight. When a worker dies (killed, out of memory, crash), the
    jobs it took down are retried once, alone, so a capture that kills its worker fails by itself.
    """
    threads = max(1, default_workers() // workers)
    start_quiet_resource_tracker()
    pending = deque(range(len(jobs)))
    crashes: Counter[int] = Counter()

    def worker_died(i: int) -> None:
        crashes[i] += 1
        if crashes[i] > 1:
            record(i, _failed(jobs[i], "worker process died (killed, out of memory or crashed)"))
        else:
            log.warning("%s: a worker process died while this capture ran; retrying it alone",
                        jobs[i].input_path)
            pending.appendleft(i)

    while pending:
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"),
                                 initializer=start_worker,
                                 initargs=(threads, logging.getLogger().getEffectiveLevel())) as pool:
            running: dict[Future[CaptureResult], int] = {}
            broken = False
            try:
                while (pending or running) and not broken:
                    while pending and len(running) < workers and not any(crashes[i] for i in running.values()):
                        if crashes[pending[0]] and running:
                            break
                        i = pending.popleft()
                        running[pool.submit(run_in_worker, jobs[i])] = i
                    done, _ = wait(running, timeout=WAKE_S, return_when=FIRST_COMPLETED)
                    for future in done:
                        i = running.pop(future)
                        try:
                            record(i, future.result())
                        except BrokenProcessPool:
                            broken = True
                            worker_died(i)
            except KeyboardInterrupt:  # Ctrl-C, SIGTERM or SIGHUP: every capture in flight cleans up first
                with signals_deferred():
                    _stop_workers(pool, {future: jobs[i].input_path for future, i in running.items()})
                raise
            for i in running.values():  # every job still in a broken pool went down with it
                worker_died(i)


def _stop_workers(pool: ProcessPoolExecutor, running: dict[Future[CaptureResult], Path]) -> None:
    """Ask every worker to stop (SIGTERM: a signal to the batch alone reaches none of them), give the captures in
    flight ``WORKER_CLEANUP_S`` to remove their partial output, kill the ones still running, and shut the pool down.
    Run with signals held back: a second Ctrl-C cutting this short would leave partial folders and a pool that
    never exits."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        try:
            os.kill(process.pid, signal.SIGTERM)
        except ProcessLookupError:  # gone already
            pass
    _, late = wait(running, timeout=WORKER_CLEANUP_S)
    if late:
        log.warning("%s: still running %g s after the stop; killed (the next run removes its partial output)",
                    ", ".join(sorted(str(running[future]) for future in late)), WORKER_CLEANUP_S)
        for process in processes:
            process.kill()
    pool.shutdown(wait=True, cancel_futures=True)


def _run_on_dask(jobs: Sequence[CaptureJob], address: str, record: Callable[[int, CaptureResult], None]) -> None:
    """Run jobs on the Dask distributed cluster whose scheduler is at ``address`` (``rmbvideo[cluster]``).

    Input and output paths must be visible to the workers at the same names (a shared file system).
    Each task limits its math threads to its worker's share of that machine's cores.
    """
    try:
        from distributed import Client
        from distributed import wait as dask_wait
    except ImportError:
        raise SchedulerError("--scheduler needs Dask: pip install 'rmbvideo[cluster]'") from None
    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise SchedulerError(f"{address}: cannot reach the Dask scheduler ({exc})") from None
    with client:
        shares = _dask_thread_shares(client)
        pending = {client.submit(run_capture_job_on_dask, job, shares, pure=False): i for i, job in enumerate(jobs)}
        alone_since: float | None = None
        try:
            while pending:
                try:
                    done, _ = dask_wait(list(pending), timeout=DASK_POLL_S, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = set()
                for future in done:
                    i = pending.pop(future)
                    try:
                        record(i, future.result())
                    except Exception as exc:  # the worker died or the task was lost
                        record(i, _failed(jobs[i], f"Dask task failed: {exc}"))
                if done or client.scheduler_info().get("workers"):
                    alone_since = None
                    continue
                alone_since = alone_since or time.monotonic()
                if time.monotonic() - alone_since > DASK_NO_WORKER_S:
                    client.cancel(list(pending))
                    for i in sorted(pending.values()):
                        record(i, _failed(jobs[i], f"no live Dask worker at {address} for "
                                                   f"{DASK_NO_WORKER_S:g} s"))
                    pending.clear()
        except KeyboardInterrupt:
            client.cancel(list(pending))
            raise


def _failed(job: CaptureJob, reason: str) -> CaptureResult:
    return CaptureResult(str(job.input_path), str(job.output_dir), "failed", error=f"{job.input_path}: {reason}")


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
