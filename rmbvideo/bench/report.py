"""Benchmark outputs: a Markdown table, a CSV and a PNG of accuracy against time with the Pareto
front marked (matplotlib when importable, else OpenCV drawing). Files are written atomically."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rmbvideo.bench.pareto import pareto_front
from rmbvideo.bench.runner import BenchRecord
from rmbvideo.io.atomic import atomic_write_text
from rmbvideo.io.png import write_figure, write_png

NA = "n/a"


def mark_pareto(records: Sequence[BenchRecord]) -> None:
    """Set ``pareto`` on each record: on the front of (seconds per frame, PSNR to the table's 0.01 dB)
    among trained rows."""
    points = [(r.seconds_per_frame, r.psnr if r.trained else None) for r in records]
    for record, on_front in zip(records, pareto_front(points, resolution=0.01)):
        record.pareto = on_front


def _fmt(value: float | None, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return NA
    return f"{value:.{digits}f}"


def markdown_table(records: Sequence[BenchRecord]) -> str:
    """The table of the README: one row per configuration; '*' marks the Pareto front."""
    head = ("| configuration | model | PSNR-μ (dB) | SSIM-μ | frames/s end to end | frames/s network | "
            "real-time factor | peak RSS (MiB) | Pareto |")
    lines = [head, "|" + "---|" * 9]
    for r in records:
        lines.append("| " + " | ".join([
            r.name, r.model if r.trained or r.method != "rmbnet" else f"{r.model} (accuracy n/a)",
            _fmt(r.psnr), _fmt(r.ssim, 4), _fmt(r.fps, 1), _fmt(r.net_fps, 1), _fmt(r.realtime_factor, 4),
            _fmt(r.peak_rss_mib, 0), "*" if r.pareto else "",
        ]) + " |")
    return "\n".join(lines) + "\n"


def write_csv(records: Sequence[BenchRecord], path: Path) -> Path:
    """All record fields, one row per configuration; missing values are empty."""
    buffer = io.StringIO()
    fields = list(records[0].to_dict()) if records else list(BenchRecord.__dataclass_fields__)
    writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for record in records:
        writer.writerow({k: ("" if v is None else v) for k, v in record.to_dict().items()})
    atomic_write_text(path, buffer.getvalue())
    return path


def write_plot(records: Sequence[BenchRecord], path: Path) -> Path:
    """PNG: PSNR against milliseconds per frame (log scale) for trained rows, Pareto front joined."""
    points = [(1e3 * r.seconds_per_frame, r.psnr, r.name, r.pareto) for r in records
              if r.trained and r.psnr is not None and math.isfinite(r.seconds_per_frame)]
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return _write_plot_opencv(points, path)
    fig, ax = plt.subplots(figsize=(8, 5), dpi=100)
    for ms, psnr, name, front in points:
        ax.scatter(ms, psnr, color="tab:red" if front else "tab:blue", zorder=3)
        ax.annotate(name, (ms, psnr), fontsize=7, xytext=(3, 3), textcoords="offset points")
    front = sorted((ms, p) for ms, p, _, f in points if f)
    if front:
        ax.step([f[0] for f in front], [f[1] for f in front], where="post", color="tab:red",
                label="Pareto front")
        ax.legend(loc="lower right")
    if points:
        ax.set_xscale("log")
    ax.set_xlabel("milliseconds per output frame, end to end (log)")
    ax.set_ylabel("μ-law PSNR (dB)")
    ax.set_title("rmbvideo bench: accuracy against time")
    ax.grid(True, which="both", alpha=0.3)
    return write_figure(fig, path)


def _write_plot_opencv(points: list[tuple[float, float, str, bool]], path: Path) -> Path:
    """The same plot drawn with OpenCV (no axes library needed)."""
    import cv2

    width, height, margin = 800, 500, 60
    canvas = np.full((height, width, 3), 255, np.uint8)
    cv2.rectangle(canvas, (margin, margin // 2), (width - margin // 2, height - margin), (0, 0, 0), 1)
    if points:
        xs = np.log10([p[0] for p in points])
        ys = np.array([p[1] for p in points])
        x0, x1 = xs.min() - 0.1, xs.max() + 0.1
        y0, y1 = ys.min() - 1.0, ys.max() + 1.0

        def pixel(x: float, y: float) -> tuple[int, int]:
            px = margin + (x - x0) / (x1 - x0) * (width - 1.5 * margin)
            py = height - margin - (y - y0) / (y1 - y0) * (height - 1.5 * margin)
            return int(px), int(py)

        front = sorted((x, y) for x, (_, y, _, f) in zip(xs, points) if f)
        for a, b in zip(front, front[1:]):
            cv2.line(canvas, pixel(*a), pixel(b[0], a[1]), (0, 0, 200), 1)
            cv2.line(canvas, pixel(b[0], a[1]), pixel(*b), (0, 0, 200), 1)
        for x, (_, y, name, f) in zip(xs, points):
            cv2.circle(canvas, pixel(x, y), 4, (0, 0, 200) if f else (200, 0, 0), -1)
            cv2.putText(canvas, name, pixel(x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.3, (0, 0, 0), 1)
    cv2.putText(canvas, "PSNR (dB) vs log ms/frame; red: Pareto front", (margin, height - 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)

    return write_png(path, canvas)
