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
    fig, ax = plt.subplots(figsize=(10, 6), dpi=100)
    labels = []
    for ms, psnr, name, front in points:
        ax.scatter(ms, psnr, color="tab:red" if front else "tab:blue", zorder=3)
        labels.append(ax.annotate(name, (ms, psnr), fontsize=7, xytext=(4, 2), textcoords="offset points",
                                  arrowprops={"arrowstyle": "-", "color": "0.6", "lw": 0.5}))
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
    if points:  # room on the right for the slowest rows' names
        ax.set_xlim(min(p[0] for p in points) / 1.5, max(p[0] for p in points) * 8)
    _separate(labels, fig)
    return write_figure(fig, path)


def _separate(labels: list, fig) -> None:
    """Place each point's label, from the highest point down, at the first of a few spots beside it (right, then left;
    level, then a line up or down, then further) inside the axes where it overlaps no other point and no label placed
    before: rows of equal accuracy and near-equal time otherwise print their names over each other or over another's
    point. A line joins a moved label to its point."""
    from matplotlib.transforms import Bbox

    renderer = fig.canvas.get_renderer()
    axes = fig.axes[0]
    inside = axes.get_window_extent(renderer)
    line = 7 * 1.25  # the labels' font size and line spacing, in points
    spots = [(side, k * line) for k in (0, 1, -1, 2, -2, 3, -3, 4, -4) for side in (1, -1)]
    marker = 5  # half a point marker's size, in pixels
    dots = {id(label): Bbox.from_extents(*(axes.transData.transform(label.xy) - marker),
                                         *(axes.transData.transform(label.xy) + marker)) for label in labels}
    placed = []
    for label in sorted(labels, key=lambda a: (-a.xy[1], a.xy[0])):
        others = [*placed, *(dot for key, dot in dots.items() if key != id(label))]
        for side, dy in spots:
            label.set_horizontalalignment("left" if side > 0 else "right")
            box = _text_box(label, (4 * side, 2 + dy), renderer)
            if inside.x0 <= box.x0 and box.x1 <= inside.x1 and not any(box.overlaps(other) for other in others):
                break
        else:
            label.set_horizontalalignment("left")
            box = _text_box(label, (4, 2), renderer)
        placed.append(box)


def _text_box(label, offset: tuple[float, float], renderer):
    """The label moved to ``offset`` (points from its point): the extent of its text alone, not its line to the point."""
    from matplotlib.text import Text

    label.xyann = offset
    label.update_positions(renderer)
    return Text.get_window_extent(label, renderer)


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
