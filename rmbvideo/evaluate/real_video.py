"""Real-video evaluation: spike streams that come with an 8-bit reference image of one plane.

This is the format of spikezoo's REDS streams (``NAME.dat`` + ``NAME.png``; ``key_id151`` in the name
counts the reference plane from 1, otherwise the middle plane is the reference); a capture is as large as its
reference (any size, each pair its own; rows stored upside down as spikezoo's and the camera's). The reference is in
unknown units, so every reconstruction is scaled by least squares onto it (``scaled_psnr``) and scored
by linear PSNR (peak 1) and SSIM.

Every row is scored at the binned resolution (half the camera's): the methods on the RMB stream
(TFW, GC20, MG20, RMB-Net: the 2x2x2-binned stream through the RMB readout) give it directly; the
methods on the raw 1-bit capture (TFP at windows 20/41/80/140, TFI) are 2x2 area-averaged, and the
reference is area-averaged to the same size. "best classical on the raw capture" is, per stream,
the best of those raw rows (an oracle choice of window: the strongest bar there is).

The frame scored is made at the reference's moment: a ``key_idK`` reference shows the light at time K in planes
(plane k spans [k, k + 1), so the end of plane K - 1; on spikezoo's REDS streams TFP slid plane by plane matches the
reference best there, at 150.8-151.7 for K = 151: ``models/experiments/raw-tfi-gate/real_gap.py moment``). Frame i
is centred at raw plane 20 i + 10, so the capture is read from plane ``skip`` on, numbered from 0
(``open_stream``), to put a frame's centre on that moment.
"""

from __future__ import annotations

import logging
import math
import re
import struct
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from rmbvideo.chunks import RmbChunk, SpikeChunk
from rmbvideo.errors import InputError
from rmbvideo.evaluate.harness import GATED_ROW, RMB_ROW, TFI_WINDOWS, rate_as_light
from rmbvideo.evaluate.metrics import ssim
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.io.records import regular_file_size
from rmbvideo.recon.full_resolution import FullResolution, raw_gate_stage
from rmbvideo.recon.methods import make_reconstructor
from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
from rmbvideo.sensor.binning import bin_2x2x2, binned_rmb_chunk
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

log = logging.getLogger(__name__)

RAW_STEP = 20  # raw planes per output frame (N = 10 binned readouts)
TFP_WINDOWS = (20, 41, 80, 140)
BEST_RAW = "best classical on the raw capture"
#: The spikezoo format's streams are simulated in its rate convention (``rmbvideo.sensor.conventions``).
CONVENTION = "spikezoo"
#: Below this SSIM for every row, no method's frame looks like the reference: the stream is not what its PNG shows
#: (the spikes of a 400x250 stream read as a 100x100 PNG says score 0.04-0.14; the real streams 0.9-0.98).
UNLIKE_SSIM = 0.3
_KEY = re.compile(r"key_id(\d+)")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class RealStream:
    """A spike stream and its reference image: ``plane`` is the 0-based raw plane the PNG shows."""

    name: str
    capture: Path
    reference: Path
    plane: int
    geometry: DatGeometry = DatGeometry(400, 250)

    @property
    def moment(self) -> int:
        """The time the reference shows, in planes: the end of its plane."""
        return self.plane + 1

    @property
    def skip(self) -> int:
        """Planes left unread at the start so that a frame is centred at ``moment`` (0 if it is too early)."""
        return (self.moment - RAW_STEP // 2) % RAW_STEP if self.moment >= RAW_STEP // 2 else 0

    @property
    def frame(self) -> int:
        """Index of the output frame made at the reference's moment, counted from plane ``skip``."""
        return max(self.moment - self.skip - RAW_STEP // 2, 0) // RAW_STEP


@dataclass(frozen=True)
class RealRow:
    """A table row: ``method`` with ``options``; ``raw`` rows run on the raw capture (then 2x2-averaged),
    the others on the binned stream through ``readout`` (the RMB design unless an ablation says otherwise)."""

    name: str
    method: str
    options: dict[str, Any] = field(default_factory=dict)
    raw: bool = False
    readout: str = "rmb"
    gated: bool = False  # RMB-Net on the raw capture as the default job runs it: its frames and the raw gate


@dataclass
class RealScore:
    """One row on one stream: the gain-scaled frame at the binned size, its PSNR and SSIM."""

    image: np.ndarray
    psnr: float
    ssim: float


def reference_plane(path: Path, planes: int) -> int:
    """The plane a reference PNG shows: ``key_idK`` in its name (K counts from 1), else the middle."""
    match = _KEY.search(path.stem)
    plane = int(match.group(1)) - 1 if match else (planes - 1) // 2
    if not 0 <= plane < planes:
        raise InputError(f"{path}: reference plane {plane} is outside the capture's {planes} planes")
    return plane


def png_geometry(path: Path) -> DatGeometry:
    """The layout of a capture whose reference is the PNG ``path``: the image's width and height (read from its
    header), no header columns, rows stored upside down as spikezoo's streams and the camera store them."""
    try:
        with open(path, "rb") as file:
            head = file.read(24)
    except OSError as error:
        raise InputError(f"{path}: cannot read ({error.strerror})") from None
    if len(head) < 24 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise InputError(f"{path}: not a PNG image")
    width, height = struct.unpack(">II", head[16:24])
    if width % 2 or height % 2:
        raise InputError(f"{path}: a reference must have even sides to be scored at the binned size, "
                         f"found {width}x{height}")
    try:
        return DatGeometry(width, height)
    except InputError as error:
        raise InputError(f"{path}: {width}x{height} is not a capture's size ({error})") from None


def find_streams(folder: Path, geometry: DatGeometry | None = None) -> list[RealStream]:
    """Every ``NAME.dat`` in ``folder`` with a ``NAME.png`` beside it (either suffix in either case), sorted by name, a
    capture without one named in a warning; each capture laid out as
    ``geometry``, or when none is given, as its reference's size says (``png_geometry``: any size, one per pair)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder of .dat + .png pairs")
    streams, unpaired = [], []
    captures = sorted(path for path in folder.iterdir() if path.suffix.lower() == ".dat" and path.is_file())
    for capture in captures:
        reference = _reference_of(capture)
        if reference is None:
            unpaired.append(capture.name)
        else:
            layout = geometry if geometry is not None else png_geometry(reference)
            if geometry is None and regular_file_size(capture) % layout.plane_bytes:
                raise InputError(f"{capture}: not a whole number of {layout.width}x{layout.height} planes, the size of "
                                 f"its reference {reference.name}")
            planes = DatReader(capture, layout).n_planes
            streams.append(RealStream(capture.stem, capture, reference, reference_plane(reference, planes), layout))
    if not streams:
        raise InputError(f"{folder}: no .dat file with a .png reference beside it")
    if unpaired:  # a user's folder of twenty pairs with two PNGs missing must not quietly score eighteen
        log.warning("%s: left out, no PNG of the same name beside %s: %s", folder,
                    "it" if len(unpaired) == 1 else f"these {len(unpaired)} captures", ", ".join(unpaired))
    return streams


def _reference_of(capture: Path) -> Path | None:
    """The PNG named as ``capture`` (``.png`` or ``.PNG``: cameras and exports write either), or None."""
    for suffix in (".png", ".PNG"):
        reference = capture.with_suffix(suffix)
        if reference.is_file():
            return reference
    return None


class PlanesFrom:
    """A capture read from raw plane ``skip`` on, its planes numbered from 0: every method's frames are then made
    ``skip`` planes later in the capture. Binned reading bins the raw planes (any ``skip``, odd too)."""

    def __init__(self, reader: DatReader, skip: int) -> None:
        self._reader = reader
        self._skip = skip

    @property
    def n_planes(self) -> int:
        return max(self._reader.n_planes - self._skip, 0)

    def chunks(self, chunk_planes: int = 1024, start: int = 0, stop: int | None = None) -> Iterator[SpikeChunk]:
        """The reader's chunks of planes ``skip + start .. skip + stop``, numbered from ``start``."""
        stop = self.n_planes if stop is None else stop
        for chunk in self._reader.chunks(chunk_planes, start + self._skip, stop + self._skip):
            yield SpikeChunk(chunk.planes, chunk.start - self._skip, chunk.rate_hz)

    def binned_chunks(self, chunk_planes: int = 1024, start: int = 0, stop: int | None = None) -> Iterator[RmbChunk]:
        """``chunks`` (an even number of planes each) 2x2x2-binned into pure-M chunks."""
        stop = self.n_planes if stop is None else stop
        for chunk in self.chunks(chunk_planes, start, stop - (stop - start) % 2):
            yield binned_rmb_chunk(*bin_2x2x2(chunk.planes), chunk.start, chunk.rate_hz)


def open_stream(stream: RealStream) -> DatReader | PlanesFrom:
    """The stream's capture, read so that frame ``stream.frame`` is made at the reference's moment."""
    reader = DatReader(stream.capture, stream.geometry)
    return PlanesFrom(reader, stream.skip) if stream.skip else reader


def binned_reference(stream: RealStream) -> np.ndarray:
    """The reference image in [0, 1], area-averaged to the binned size (H/2, W/2)."""
    image = cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE)
    height, width = stream.geometry.height, stream.geometry.image_width
    if image is None or image.shape != (height, width):
        found = "unreadable" if image is None else f"{image.shape[1]}x{image.shape[0]}"
        raise InputError(f"{stream.reference}: expected an 8-bit {width}x{height} image, found {found}")
    return cv2.resize(image.astype(np.float32) / 255.0, (width // 2, height // 2), interpolation=cv2.INTER_AREA)


def least_squares_gain(prediction: np.ndarray, reference: np.ndarray) -> float:
    """The gain g minimising |g prediction - reference|^2 (0 for an all-zero prediction)."""
    pred = prediction.astype(np.float64)
    return float((pred * reference).sum() / max(float((pred * pred).sum()), 1e-12))


def scaled_psnr(prediction: np.ndarray, reference: np.ndarray) -> float:
    """PSNR (peak 1) of ``prediction`` scaled by least squares onto ``reference`` (both linear)."""
    mse = float(((least_squares_gain(prediction, reference) * prediction - reference) ** 2).mean())
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


def reconstruct_frame(stream: RealStream, row: RealRow) -> np.ndarray:
    """The row's frame at the reference's moment, at the binned size (raw rows 2x2 area-averaged)."""
    reader = open_stream(stream)
    recon = make_reconstructor(row.method, **row.options)
    sink = FrameCollector(keep=[stream.frame])
    readout = None if row.raw else RmbReadout(mode=ReadoutMode(row.readout))
    if row.gated:
        gate = raw_gate_stage("auto", row.options.get("model"))
        recon = FullResolution(recon, readout, step=RAW_STEP, output="binned", raw_gate=gate,
                               threads=row.options.get("threads"))
        readout = None
    reconstruct_stream(reader, recon, sink, readout=readout)
    if stream.frame not in sink.frames:
        raise InputError(f"{stream.capture}: {row.name} produced no frame {stream.frame}")
    # finite and >= 0 (the pipeline cleans every frame); a binned rate read as the harness reads it
    image = rate_as_light(row.method, sink.frames[stream.frame].image, CONVENTION, binned=not row.raw)
    height, width = stream.geometry.height // 2, stream.geometry.image_width // 2
    if image.shape != (height, width):
        image = cv2.resize(image[: 2 * height, : 2 * width], (width, height), interpolation=cv2.INTER_AREA)
    return image


def score_stream(stream: RealStream, rows: Iterable[RealRow]) -> dict[str, RealScore]:
    """Every row on ``stream``, plus the per-stream best of the raw rows (``BEST_RAW``)."""
    reference = binned_reference(stream)
    scores: dict[str, RealScore] = {}
    raw_names = []
    for row in rows:
        image = reconstruct_frame(stream, row)
        scaled = (least_squares_gain(image, reference) * image).astype(np.float32)
        scores[row.name] = RealScore(scaled, scaled_psnr(image, reference),
                                     ssim(np.clip(scaled, 0, 1), reference))
        if row.raw:
            raw_names.append(row.name)
        log.info("%s: %s %.2f dB", stream.name, row.name, scores[row.name].psnr)
    if raw_names:
        best = max(raw_names, key=lambda name: scores[name].psnr)
        scores[BEST_RAW] = scores[best]
    likeness = max((score.ssim for score in scores.values()), default=1.0)
    if likeness < UNLIKE_SSIM:
        geometry = stream.geometry
        log.warning("%s: no method's frame looks like %s (best SSIM %.2f): is the capture laid out as %dx%d? "
                    "(`rmbvideo info %s --guess-geometry`)", stream.capture, stream.reference.name, likeness,
                    geometry.image_width, geometry.height, stream.capture)
    return scores


def real_video_rows(model: Path | None = None, device: str = "cpu", threads: int | None = 1,
                    precision: str = "auto") -> list[RealRow]:
    """The real-video table: the baselines and RMB-Net on the model's input (the binned stream through
    the readout it was trained on), RMB-Net as the default job runs it on these 1-bit captures (with the raw gate,
    ``GATED_ROW``, when installed), RMB-Net on the RMB readout when the model reads another and
    ``rmbnet-binned-rmb`` sits beside it, and the raw-capture classical methods."""
    from rmbvideo.net.weights import default_model_path, default_raw_gate_path, model_readout

    model = Path(model) if model is not None else default_model_path("binned")
    readout = model_readout(model)
    options = {"device": device, "precision": precision, "input_mode": "binned", "threads": threads,
               "convention": CONVENTION}
    rows = [
        RealRow("TFW-S", "tfw", {"window": 10, "step": 10}, readout=readout),
        RealRow("TFW-L", "tfw", {"window": 70, "step": 10}, readout=readout),
        RealRow("GC20", "gc20", {"convention": CONVENTION}, readout=readout),
        RealRow("MG20", "mg20", {"convention": CONVENTION}, readout=readout),
        RealRow("RMB-Net", "rmbnet", {"model": model, **options}, readout=readout),
    ]
    if default_raw_gate_path().is_file():
        rows.append(RealRow(GATED_ROW, "rmbnet", {"model": model, **options}, readout=readout, gated=True))
    rmb_model = model.with_name("rmbnet-binned-rmb.safetensors")
    if readout != "rmb" and rmb_model.is_file():
        rows.append(RealRow(RMB_ROW, "rmbnet", {"model": rmb_model, **options}, readout="rmb"))
    rows += [RealRow(f"TFP-{window} (raw, 2x2-avg)", "tfp", {"window": window, "step": RAW_STEP}, raw=True)
             for window in TFP_WINDOWS]
    rows.append(RealRow("TFI (raw, 2x2-avg)", "tfi", {"step": RAW_STEP}, raw=True))
    rows += [RealRow(f"TFI-{window} (raw, 2x2-avg)", "tfi", {"step": RAW_STEP, "window": window}, raw=True)
             for window in TFI_WINDOWS]
    return rows


def evaluate_streams(streams: Sequence[RealStream], rows: Sequence[RealRow]) -> dict[str, dict[str, RealScore]]:
    """Scores per stream name, then per row name (``score_stream``)."""
    return {stream.name: score_stream(stream, rows) for stream in streams}


def markdown_table(results: dict[str, dict[str, RealScore]]) -> str:
    """Rows = methods, columns = streams (PSNR dB / SSIM), plus the mean PSNR."""
    streams = list(results)
    names = list(next(iter(results.values())))
    lines = ["| method | " + " | ".join(streams) + " | mean PSNR |",
             "|---|" + "---|" * (len(streams) + 1)]
    for name in names:
        cells = [f"{results[s][name].psnr:.2f} / {results[s][name].ssim:.3f}" for s in streams]
        mean = float(np.mean([results[s][name].psnr for s in streams]))
        label = f"**{name}**" if name in ("RMB-Net", GATED_ROW, BEST_RAW) else name
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {mean:.2f} |")
    return "\n".join(lines) + "\n"


def comparison_image(results: dict[str, dict[str, RealScore]], references: dict[str, np.ndarray],
                     names: Sequence[str]) -> np.ndarray:
    """One row per stream: the reference and each named method's gain-scaled frame (8-bit, labelled)."""
    rows = []
    for stream, scores in results.items():
        panels = [("reference", references[stream])] + [(name, scores[name].image) for name in names]
        tiles = []
        for label, image in panels:
            tile = (np.clip(image, 0, 1) * 255).astype(np.uint8)
            tile = cv2.resize(tile, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
            tile = cv2.cvtColor(tile, cv2.COLOR_GRAY2BGR)
            text = label if label == "reference" else f"{label} {scores[label].psnr:.1f} dB"
            (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
            tile[: h + 10, : w + 8] = 0  # a dark box behind the label: an outline at this size smudged the glyphs
            cv2.putText(tile, text, (4, h + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
            tiles.append(np.pad(tile, ((2, 2), (2, 2), (0, 0)), constant_values=255))
        rows.append(np.hstack(tiles))
    width = max(row.shape[1] for row in rows)  # streams of other sizes: narrower rows padded white on the right
    return np.vstack([np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0)), constant_values=255) for row in rows])
