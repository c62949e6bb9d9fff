"""The units of a batch: captures found, jobs to run, their results, and the batch folder's file names."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any, Literal

from rmbvideo.errors import RmbvideoError

MARKER_NAME = ".complete.json"
REPORT_NAME = "batch-report.json"
LOCK_NAME = ".batch.lock"
MARKER_FORMAT = "rmbvideo-batch-complete"
REPORT_FORMAT = "rmbvideo-batch-report"
# run_reconstruction keywords that do not change the output files (the output does not depend on them)
NON_OUTPUT_OPTIONS = frozenset({"chunk_planes", "progress"})
CAPTURE_SUFFIX = ".dat"
UNSAFE_NAME_CHARS = re.compile(r"[^A-Za-z0-9._+-]")
HASH_CHARS = 8
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS")

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
    warnings: list[str] = field(default_factory=list)  # what the conversion warned of (a geometry that fits better)
