"""Batch conversion: find captures, name their outputs, run each in isolation, resume, report.

Layout of a batch folder ``OUTDIR``::

    <name>/                    a finished capture: the outputs of ``run_reconstruction`` + .complete.json
    .<name>.partial-<token>/   work in progress, renamed to <name> as the very last step
    ..<name>.partial-<token>.partial-<token>/   its reconstruction's staging, renamed into the one above
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

from rmbvideo.batch.discovery import discover_captures, output_names, plan_jobs
from rmbvideo.batch.jobs import (
           MARKER_NAME,
           REPORT_NAME,
           CaptureJob,
           CaptureResult,
           FoundCapture,
           SchedulerError,
)
from rmbvideo.batch.markers import read_marker
from rmbvideo.batch.pool import batch_lock, default_workers, limit_threads, run_batch
from rmbvideo.batch.report import summary_table, write_report
from rmbvideo.batch.runner import run_capture_job

__all__ = ["MARKER_NAME", "REPORT_NAME", "CaptureJob", "CaptureResult", "FoundCapture", "SchedulerError",
           "batch_lock", "default_workers", "discover_captures", "limit_threads", "output_names", "plan_jobs",
           "read_marker", "run_batch", "run_capture_job", "summary_table", "write_report"]
