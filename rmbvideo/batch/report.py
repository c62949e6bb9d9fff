"""The batch report (batch-report.json) and the summary table."""

from __future__ import annotations

import json
import logging
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path

from rmbvideo import __version__
from rmbvideo.batch.jobs import REPORT_FORMAT, REPORT_NAME, CaptureResult
from rmbvideo.io.atomic import atomic_write_text

log = logging.getLogger(__name__)

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
    warned = sum(1 for r in results if r.warnings)
    if warned:
        lines.append(f"{warned} of them warned of something (a geometry that fits better, say): the warnings of each "
                     f"are in {REPORT_NAME}")
    return "\n".join(lines)
