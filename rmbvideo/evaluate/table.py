"""Evaluation outputs: the Table 2 analog as Markdown and CSV, and side-by-side comparison PNGs.

Figures are drawn with OpenCV only (no matplotlib needed). Images are mu-law tone-mapped (mu = 5000)
after dividing by a robust maximum (99.9th percentile) of the reference: the ground truth on the
held-out set, each method's own frame on a real capture (no ground truth there). Zoomed regions are
re-exposed to their own reference patch (and use a milder mu = 64), so detail in a deep shadow shows.

``python -m rmbvideo.evaluate.table --real CAPTURE.dat -o out.png`` writes the real-capture figure.
"""

from __future__ import annotations

import argparse
import csv
import io
import logging
import math
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rmbvideo.errors import InputError
from rmbvideo.evaluate.harness import RowResult, downsample_2x
from rmbvideo.evaluate.metrics import robust_scale
from rmbvideo.io.atomic import atomic_write_text
from rmbvideo.io.png import write_png
from rmbvideo.mulaw import mu_law

log = logging.getLogger(__name__)

MU = 5000.0
LABEL_HEIGHT = 22
PANEL_GAP = 4
ZOOM_SIZE = 160  # displayed side of a zoomed region (px)
ZOOM_MU = 64.0  # milder curve for zooms: a re-exposed patch spans a small range
DARK_COLOUR = (255, 160, 0)  # BGR
BRIGHT_COLOUR = (0, 200, 255)
MOVING_COLOUR = (80, 80, 255)


def _format(value: float, digits: int) -> str:
    return "—" if not math.isfinite(value) else f"{value:.{digits}f}"


def markdown_table(rows: Seq[RowResult], title: str = "") -> str:
    """The rows as a Markdown table (columns: method, mu-PSNR, SSIM, PU21-PSNR, temporal mu-PSNR, fps, status)."""
    lines = [f"{title}\n" if title else "",
             "| Method | μ-PSNR (dB) ↑ | μ-SSIM ↑ | PU21-PSNR (dB) ↑ | temporal μ-PSNR (dB) ↑ | frames/s ↑ "
             "| network frames/s | status |",
             "|---|---:|---:|---:|---:|---:|---:|---|"]
    for row in rows:
        lines.append(f"| {row.name} | {_format(row.psnr, 2)} | {_format(row.ssim, 3)} | {_format(row.pu21, 2)} "
                     f"| {_format(row.temporal, 2)} | {_format(row.fps, 1)} | {_format(row.network_fps, 1)} "
                     f"| {row.status} |")
    return "\n".join(line for line in lines if line) + "\n"


def csv_table(rows: Seq[RowResult]) -> str:
    """The rows as CSV (empty cells for rows without numbers)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["method", "mu_psnr_db", "mu_ssim", "pu21_psnr_db", "temporal_mu_psnr_db", "fps", "network_fps",
                     "status"])
    for row in rows:
        values = [row.psnr, row.ssim, row.pu21, row.temporal, row.fps, row.network_fps]
        writer.writerow([row.name, *("" if not math.isfinite(v) else f"{v:.6g}" for v in values), row.status])
    return buffer.getvalue()


def write_tables(rows: Seq[RowResult], out_dir: Path, notes: str = "") -> tuple[Path, Path]:
    """Write ``evaluation.md`` (table plus ``notes``) and ``evaluation.csv`` into ``out_dir``."""
    out_dir = Path(out_dir)
    md, table = out_dir / "evaluation.md", out_dir / "evaluation.csv"
    atomic_write_text(md, markdown_table(rows, "# Evaluation on the held-out synthetic set") + "\n"
                      + per_sequence_table(rows, "## μ-PSNR (dB) per sequence") + "\n" + notes)
    atomic_write_text(table, csv_table(rows))
    return md, table


def per_sequence_table(rows: Seq[RowResult], title: str = "") -> str:
    """mu-law PSNR (dB) of every row with numbers on every sequence, as a Markdown table."""
    ok = [row for row in rows if row.per_sequence]
    if not ok:
        return ""
    names = list(ok[0].per_sequence)
    lines = [f"{title}\n" if title else "", "| Method | " + " | ".join(names) + " |",
             "|---|" + "---:|" * len(names)]
    for row in ok:
        lines.append(f"| {row.name} | " + " | ".join(_format(row.per_sequence[n], 2) for n in names) + " |")
    return "\n".join(line for line in lines if line) + "\n"


def to_display(image: np.ndarray, scale: float, mu: float = MU) -> np.ndarray:
    """Linear image -> uint8 grey: divide by ``scale``, clip to [0, 1], mu-law."""
    normalised = np.clip(np.nan_to_num(image / max(scale, 1e-12), nan=0.0, posinf=1.0), 0.0, 1.0)
    return np.round(mu_law(normalised.astype(np.float32), mu) * 255).astype(np.uint8)


@dataclass(frozen=True)
class Region:
    """A square patch: top-left ``(y, x)`` and side ``size`` in image pixels."""

    y: int
    x: int
    size: int

    def crop(self, image: np.ndarray) -> np.ndarray:
        return image[self.y:self.y + self.size, self.x:self.x + self.size]


def pick_regions(gt: np.ndarray) -> tuple[Region, Region]:
    """The darkest and the brightest textured square patches of ``gt`` (side ~ a quarter of the height).

    Texture is the standard deviation of the tone-mapped patch; candidates are the patches at least as
    textured as the median patch, ranked by their mean linear value (the two picks differ).
    """
    height, width = gt.shape
    size = max(4, min(height, width) // 4)
    stride = max(1, size // 2)
    display = mu_law(np.clip(gt / robust_scale(gt), 0.0, 1.0), MU)
    candidates = []
    for y in range(0, height - size + 1, stride):
        for x in range(0, width - size + 1, stride):
            region = Region(y, x, size)
            candidates.append((float(region.crop(display).std()), float(region.crop(gt).mean()), region))
    texture_floor = float(np.median([c[0] for c in candidates]))
    textured = sorted((c for c in candidates if c[0] >= texture_floor), key=lambda c: c[1])
    dark, bright = textured[0][2], textured[-1][2]
    return dark, bright


def pick_moving_region(before: np.ndarray, after: np.ndarray) -> Region:
    """The square patch (the size ``pick_regions`` uses) where the tone-mapped frames ``before`` and ``after`` of one
    method differ most on average: the moving edges, where a window's frames disagree and ghosts or blur show."""
    height, width = after.shape
    size = max(4, min(height, width) // 4)
    stride = max(1, size // 4)
    scale = robust_scale(after)
    change = np.abs(to_display(after, scale).astype(np.float32) - to_display(before, scale).astype(np.float32))
    candidates = [(float(Region(y, x, size).crop(change).mean()), y, x)
                  for y in range(0, height - size + 1, stride) for x in range(0, width - size + 1, stride)]
    _, y, x = max(candidates)
    return Region(y, x, size)


def _label(panel: np.ndarray, text: str) -> np.ndarray:
    """``panel`` (grey or BGR) in BGR with a label bar above it."""
    bgr = cv2.cvtColor(panel, cv2.COLOR_GRAY2BGR) if panel.ndim == 2 else panel
    bar = np.full((LABEL_HEIGHT, bgr.shape[1], 3), 32, np.uint8)
    scale = 0.45
    while scale > 0.25 and cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > bgr.shape[1] - 4:
        scale -= 0.05
    cv2.putText(bar, text, (3, LABEL_HEIGHT - 7), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return np.vstack([bar, bgr])


def _zoom(image: np.ndarray, region: Region, reference: np.ndarray) -> np.ndarray:
    patch = to_display(region.crop(image), robust_scale(region.crop(reference)), ZOOM_MU)
    return cv2.resize(patch, (ZOOM_SIZE, ZOOM_SIZE), interpolation=cv2.INTER_NEAREST)


def _column(title: str, image: np.ndarray, reference: np.ndarray, regions: Seq[tuple[Region, tuple]]) -> np.ndarray:
    """One method: the full frame (regions outlined) above its zoomed regions, labelled."""
    factor = max(1, -(-ZOOM_SIZE // image.shape[1]))  # small frames are enlarged to the zooms' width
    grey = to_display(image, robust_scale(reference))
    full = cv2.cvtColor(cv2.resize(grey, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST),
                        cv2.COLOR_GRAY2BGR)
    for region, colour in regions:
        top_left = (region.x * factor, region.y * factor)
        bottom_right = ((region.x + region.size) * factor - 1, (region.y + region.size) * factor - 1)
        cv2.rectangle(full, top_left, bottom_right, colour, 1)
    width = max(full.shape[1], ZOOM_SIZE)
    parts = [_pad_width(_label(full, title), width)]
    for region, colour in regions:
        zoom = cv2.cvtColor(_zoom(image, region, reference), cv2.COLOR_GRAY2BGR)
        cv2.rectangle(zoom, (0, 0), (ZOOM_SIZE - 1, ZOOM_SIZE - 1), colour, 2)
        parts.append(np.full((PANEL_GAP, width, 3), 255, np.uint8))
        parts.append(_pad_width(zoom, width))
    return np.vstack(parts)


def _pad_width(panel: np.ndarray, width: int) -> np.ndarray:
    pad = width - panel.shape[1]
    return np.pad(panel, ((0, 0), (0, pad), (0, 0)), constant_values=255) if pad > 0 else panel


def side_by_side(images: dict[str, np.ndarray], reference: np.ndarray, regions: Seq[Region]) -> np.ndarray:
    """A BGR figure: one labelled column per entry of ``images`` (first the reference, if included),
    all tone-mapped against ``reference``; the dark, bright (and moving) ``regions`` outlined and zoomed below."""
    coloured = list(zip(regions, (DARK_COLOUR, BRIGHT_COLOUR, MOVING_COLOUR)))
    columns = [_column(name, image, reference, coloured) for name, image in images.items()]
    height = max(c.shape[0] for c in columns)
    columns = [np.pad(c, ((0, height - c.shape[0]), (0, 0), (0, 0)), constant_values=255) for c in columns]
    gap = np.full((height, PANEL_GAP, 3), 255, np.uint8)
    return np.hstack([part for column in columns for part in (column, gap)][:-1])


def write_comparison_png(rows: Seq[RowResult], gt: np.ndarray, frame_index: int, path: Path,
                         title: str = "GT") -> Path:
    """The held-out figure: GT and every row with frames, at ``frame_index``; regions picked from the GT."""
    dark, bright = pick_regions(gt)
    images = {title: gt}
    images.update({row.name: row.figure_frames[frame_index] for row in rows if frame_index in row.figure_frames})
    return write_png(path, side_by_side(images, gt, (dark, bright)))


def real_capture_comparison(path: Path, out_png: Path, model: Path | None = None, device: str = "auto",
                            frame: int | str = "middle", precision: str = "auto") -> Path:
    """Side-by-side of a real capture: RMB-Net (shipped binned model, or ``model``) vs TFP vs TFI.

    The capture's geometry comes from its sidecar, else the 400x250 defaults; RMB-Net reads it in the convention
    and response ``reconstruct`` would (``--convention auto``, ``--response auto``). RMB-Net runs on the
    2x2x2-binned stream through the readout its model was trained on; TFP (41 planes) and TFI run on the raw planes, and their
    frames are 2x2 area-averaged to RMB-Net's size. ``frame``: a frame index, or ``"first"``, ``"middle"`` or
    ``"last"`` of the frames all three produce (a clip's edges are where a window is cut short). The dark and bright
    regions are picked on the TFP frame, the moving one where TFP's frames before and after it differ most; each
    column is tone-mapped to its own robust maximum (there is no ground truth, and the methods' linear units agree
    only roughly).
    """
    from rmbvideo.io.capture import open_capture
    from rmbvideo.recon.methods import make_reconstructor
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.io.sidecar import simulated_camera
    from rmbvideo.recon.run import auto_convention, trained_readout
    from rmbvideo.sensor.conventions import response_for
    from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

    reader = open_capture(Path(path), width=None, height=None, flip=None, header_cols=None, rate_hz=None)
    camera = simulated_camera(Path(path))  # read as `reconstruct` reads it: its convention and response
    rmbnet = make_reconstructor("rmbnet", model=model, device=device, precision=precision, input_mode="binned",
                                convention=auto_convention(reader, Path(path)),
                                response=response_for(None if camera is None else camera.effects))
    runs = {
        "RMB-Net": (rmbnet, RmbReadout(mode=ReadoutMode(trained_readout(rmbnet)))),
        "TFP": (make_reconstructor("tfp", window=41, step=20), None),
        "TFI": (make_reconstructor("tfi", step=20), None),
    }
    frames: dict[str, dict[int, np.ndarray]] = {}
    for name, (recon, readout) in runs.items():
        sink = FrameCollector()
        reconstruct_stream(reader, recon, sink, readout=readout)
        frames[name] = sink.images
    common = sorted(set.intersection(*(set(images) for images in frames.values())))
    if len(common) < 2:
        raise InputError(f"{path}: too short for a comparison (fewer than 2 frames produced by every method)")
    named = {"first": common[0], "middle": common[len(common) // 2], "last": common[-1]}
    if frame not in named and frame not in common:
        raise InputError(f"{path}: no frame {frame} made by every method (frames {common[0]}..{common[-1]})")
    index = named.get(frame, frame)
    shape = frames["RMB-Net"][index].shape

    def binned(image: np.ndarray) -> np.ndarray:
        return image if image.shape == shape else downsample_2x(image, shape)

    images = {name: binned(images[index]) for name, images in frames.items()}
    neighbour = common[common.index(index) + (1 if index == common[0] else -1)]
    regions = (*pick_regions(images["TFP"]), pick_moving_region(binned(frames["TFP"][neighbour]), images["TFP"]))
    columns = [side_by_side({f"{name}, frame {index}": image}, image, regions) for name, image in images.items()]
    gap = np.full((columns[0].shape[0], PANEL_GAP, 3), 255, np.uint8)
    log.info("%s: comparison of frame %d written to %s", path, index, out_png)
    return write_png(Path(out_png), np.hstack([part for column in columns for part in (column, gap)][:-1]))


def main(argv: list[str] | None = None) -> None:
    """``python -m rmbvideo.evaluate.table --real CAPTURE.dat [-o PNG] [--model M] [--device D] [--frame F]``."""
    parser = argparse.ArgumentParser(description="Comparison figure of a real capture: RMB-Net vs TFP vs TFI.")
    parser.add_argument("--real", type=Path, required=True, help="a 400x250 .dat capture")
    parser.add_argument("-o", "--output", type=Path, default=Path("real_comparison.png"))
    parser.add_argument("--model", type=Path, default=None, help="RMB-Net weights (default: shipped binned model)")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--frame", default="middle",
                        help="a frame index, or first, middle or last of the frames every method makes")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="rmbvideo: %(message)s")
    frame = int(args.frame) if args.frame.lstrip("-").isdigit() else args.frame
    real_capture_comparison(args.real, args.output, args.model, args.device, frame)


if __name__ == "__main__":
    main()


def write_sequence_png(rows: Seq[RowResult], name: str, gt: np.ndarray, path: Path,
                       columns: Seq[str] | None = None) -> Path:
    """The figure of sequence ``name``'s middle scored frame (``RowResult.middle_frames``): its ground
    truth ``gt`` and the rows named in ``columns`` (default: every row with the frame); regions
    picked from the GT."""
    dark, bright = pick_regions(gt)
    images = {"GT": gt}
    images.update({row.name: row.middle_frames[name] for row in rows
                   if name in row.middle_frames and (columns is None or row.name in columns)})
    return write_png(path, side_by_side(images, gt, (dark, bright)))
