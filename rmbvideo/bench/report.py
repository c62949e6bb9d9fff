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


#: where a point's label may go, tried in turn: (side: 1 right of the point, -1 left; lines up (+) or down (-))
LABEL_SPOTS = [(side, k) for k in (0, 1, -1, 2, -2, 3, -3, 4, -4) for side in (1, -1)]

Box = tuple[float, float, float, float]  # x0, y0, x1, y1


def _overlap(a: Box, b: Box) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _free_spot(box_at, taken: list[Box], left: float, right: float) -> tuple[int, int]:
    """The first of ``LABEL_SPOTS`` whose box (``box_at(spot)``) lies between ``left`` and ``right`` and overlaps none
    of ``taken`` (the first spot where every one does): rows of equal accuracy and near-equal time otherwise print
    their names over each other or over another's point."""
    for spot in LABEL_SPOTS:
        box = box_at(spot)
        if left <= box[0] and box[2] <= right and not any(_overlap(box, other) for other in taken):
            return spot
    return LABEL_SPOTS[0]


def _separate(labels: list, fig) -> None:
    """Place the matplotlib labels from the highest point down (``_free_spot``), clear of the points and of the labels
    placed before; a line joins a moved label to its point."""
    renderer = fig.canvas.get_renderer()
    axes = fig.axes[0]
    inside = axes.get_window_extent(renderer)
    line, marker = 7 * 1.25, 5  # the labels' line spacing in points; half a marker in pixels
    dots = {id(label): (*(axes.transData.transform(label.xy) - marker), *(axes.transData.transform(label.xy) + marker))
            for label in labels}
    placed: list[Box] = []

    def box_at(label, spot: tuple[int, int]) -> Box:
        side, k = spot
        label.set_horizontalalignment("left" if side > 0 else "right")
        return tuple(_text_box(label, (4 * side, 2 + k * line), renderer).extents)

    for label in sorted(labels, key=lambda a: (-a.xy[1], a.xy[0])):
        others = [*placed, *(dot for key, dot in dots.items() if key != id(label))]
        spot = _free_spot(lambda s: box_at(label, s), others, inside.x0, inside.x1)
        placed.append(box_at(label, spot))


def _text_box(label, offset: tuple[float, float], renderer):
    """The label moved to ``offset`` (points from its point): the extent of its text alone, not its line to the point."""
    from matplotlib.text import Text

    label.xyann = offset
    label.update_positions(renderer)
    return Text.get_window_extent(label, renderer)


def _write_plot_opencv(points: list[tuple[float, float, str, bool]], path: Path) -> Path:
    """The same plot drawn with OpenCV (no axes library needed): axes with their ticks, names placed as matplotlib's."""
    import cv2

    width, height, left, right, top, bottom = 1000, 600, 70, 20, 40, 60
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.35
    canvas = np.full((height, width, 3), 255, np.uint8)
    cv2.rectangle(canvas, (left, top), (width - right, height - bottom), (0, 0, 0), 1)
    cv2.putText(canvas, "rmbvideo bench: accuracy against time (red: Pareto front)", (left + 230, top - 14), font, 0.5,
                (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, "milliseconds per output frame, end to end (log)", (left + 250, height - 15), font, 0.45,
                (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, "mu-law PSNR (dB)", (5, top - 14), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    if not points:
        return write_png(path, canvas)
    xs = np.log10([p[0] for p in points])
    ys = np.array([p[1] for p in points])
    x0, x1 = xs.min() - 0.1, xs.max() + 0.9  # room on the right for the slowest rows' names
    y0, y1 = ys.min() - 1.0, ys.max() + 1.0

    def pixel(x: float, y: float) -> tuple[int, int]:
        return (int(left + (x - x0) / (x1 - x0) * (width - left - right)),
                int(height - bottom - (y - y0) / (y1 - y0) * (height - top - bottom)))

    grey = (200, 200, 200)
    for decade in range(math.ceil(x0), math.floor(x1) + 1):
        px, _ = pixel(decade, y0)
        cv2.line(canvas, (px, top), (px, height - bottom), grey, 1)
        cv2.putText(canvas, f"{10.0 ** decade:g}", (px - 10, height - bottom + 16), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    tick = 2.5 if y1 - y0 < 25 else 5.0
    for value in np.arange(math.ceil(y0 / tick) * tick, y1, tick):
        _, py = pixel(x0, value)
        cv2.line(canvas, (left, py), (width - right, py), grey, 1)
        cv2.putText(canvas, f"{value:.1f}", (left - 40, py + 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    front = sorted((x, y) for x, (_, y, _, f) in zip(xs, points) if f)
    for a, b in zip(front, front[1:]):
        cv2.line(canvas, pixel(*a), pixel(b[0], a[1]), (0, 0, 200), 1)
        cv2.line(canvas, pixel(b[0], a[1]), pixel(*b), (0, 0, 200), 1)
    centres = [pixel(x, y) for x, (_, y, _, _) in zip(xs, points)]
    dots = [(cx - 5, cy - 5, cx + 5, cy + 5) for cx, cy in centres]
    placed: list[Box] = []
    line = 12  # pixels between label lines
    for i in sorted(range(len(points)), key=lambda i: (-points[i][1], xs[i])):
        name, (cx, cy) = points[i][2], centres[i]
        (w, h), _ = cv2.getTextSize(name, font, scale, 1)

        def box_at(spot: tuple[int, int]) -> Box:
            side, k = spot
            bx = cx + 6 if side > 0 else cx - 6 - w
            by = cy - 3 - k * line  # the text's baseline
            return bx, by - h, bx + w, by

        others = [*placed, *(dot for j, dot in enumerate(dots) if j != i)]
        box = box_at(_free_spot(box_at, others, left, width - right))
        placed.append(box)
        if abs(box[3] - (cy - 3)) > 1:  # moved off its point's line: a line joins them
            cv2.line(canvas, (cx, cy), (int(box[0] if box[0] > cx else box[2]), int(box[3] - h / 2)), grey, 1)
        cv2.putText(canvas, name, (int(box[0]), int(box[3])), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    for (cx, cy), (_, _, _, f) in zip(centres, points):
        cv2.circle(canvas, (cx, cy), 4, (0, 0, 200) if f else (200, 0, 0), -1)
    return write_png(path, canvas)
