"""Run any reconstruction method on a held-out sequence, match its frames to ground truth, score, time.

Input: every method on the binned stream gets the sequence's binned pure-M stream passed through the
row's readout design (``RmbReadout(mode=...)``; the default model's design for the baselines and
RMB-Net, "rmb" for the RMB-readout row, the ablation designs for the pure-S/pure-M/full-M rows).
Methods on 1-bit planes (TFI) get the 1-bit plane of that same stream (the kept pixel of every bin,
at the binned rate), so every baseline sees the default's input, as in the paper's Table 2. Frame i is centred at binned readout 10i + 5 (raw plane 20i + 10).

Ground truth is clipped at the sensor's saturation (1: one spike per raw readout interval, the most
any 1-bit or binned readout can report) before scoring: radiance above it is invisible to every
method, and leaving it in would let light sources 1e3x above saturation set the mu-law normalisation
and squash the rest of the scene for every row alike.

Scores: mu-law PSNR and SSIM (mu = 5000) and PU21 PSNR per scored frame (``Sequence.scored_frames``),
averaged over the frames of a sequence; a row's score over several sequences is the mean of the
per-sequence means (``aggregate``). Time: wall-clock seconds from the first chunk pushed to the last
frame returned (readout design, upsampling, preliminary frames and the method itself; not the
simulation or the unpacking of the cached arrays), over every frame the method emits.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from rmbvideo.chunks import Frame, SpikeChunk
from rmbvideo.evaluate.heldout import Sequence
from rmbvideo.evaluate.metrics import mu_law_psnr, mu_law_ssim, pu21_psnr, temporal_mu_law_psnr
from rmbvideo.net.weights import default_raw_gate_path, model_readout
from rmbvideo.recon.full_resolution import FullResolution, raw_gate_stage
from rmbvideo.recon.methods import get_method, make_reconstructor
from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
from rmbvideo.sensor.readout import RmbReadout

log = logging.getLogger(__name__)

CHUNK_READOUTS = 64  # binned readouts pushed at once (results do not depend on it)
# Largest linear value any 1-bit or binned readout can report: one spike per raw readout interval.
SATURATION = 1.0


@dataclass(frozen=True)
class MethodSpec:
    """A table row: display ``name``, registered ``method`` (``recon.methods.METHODS``), its
    keyword ``options``, and the readout design applied to RMB input (ignored for raw-input methods).
    ``raw`` rows get the raw 1-bit capture at full resolution instead of any RMB input."""

    name: str
    method: str
    options: dict[str, Any] = field(default_factory=dict)
    readout: str = "rmb"
    raw: bool = False  # runs on the raw full-resolution capture; frames are 2x2-averaged to the GT size
    gated: bool = False  # RMB-Net's frames mixed with the raw capture's intervals by the shipped gate (``GATED_ROW``)

    @property
    def model_path(self) -> Path | None:
        """The weight file this row needs, if any (``options["model"]``)."""
        model = self.options.get("model")
        return Path(model) if model is not None else None

    @property
    def available(self) -> bool:
        """False when the row needs a weight file that does not exist (an untrained ablation)."""
        path = self.model_path
        return path is None or path.with_suffix(".safetensors").is_file()


@dataclass
class MethodResult:
    """One method on one sequence: its scored ``frames`` (index -> linear image, at GT size), mean
    metrics over them (``temporal``: ``temporal_mu_law_psnr`` over consecutive scored frames), wall-clock
    ``seconds`` for all ``frames_emitted`` frames, and for RMB-Net the part of that spent in the network
    (``network_seconds``; None for other methods)."""

    frames: dict[int, np.ndarray]
    psnr: float
    ssim: float
    pu21: float
    seconds: float
    frames_emitted: int
    network_seconds: float | None = None
    temporal: float = math.nan

    @property
    def frames_per_second(self) -> float:
        """Output frames per wall-clock second, end to end from the input stream."""
        return self.frames_emitted / self.seconds if self.seconds > 0 else math.inf


def downsample_2x(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """2x2 area average of a raw-resolution frame, cropped to the binned ``shape`` (H, W)."""
    h, w = shape
    return cv2.resize(image[: 2 * h, : 2 * w], (w, h), interpolation=cv2.INTER_AREA)


class SinglePlaneSource:
    """A sequence's RMB stream seen as 1-bit planes: the single-bit plane of every readout after the
    readout design (the input TFI gets in the table: the same RMB data as every other row)."""

    def __init__(self, seq: Sequence, readout: RmbReadout) -> None:
        self.seq, self.readout = seq, readout
        self.n_planes = seq.readouts

    def chunks(self, chunk_planes: int, start: int = 0, stop: int | None = None) -> Iterator[SpikeChunk]:
        for chunk in self.seq.rmb_chunks(chunk_planes):
            yield SpikeChunk(planes=self.readout.apply(chunk).single, start=chunk.start, rate_hz=chunk.rate_hz)


#: How RMB-Net reads a camera's rates back as light on the evaluation's synthetic streams: rmbvideo's emission model
#: made every one, so the camera's response is known (``rmbvideo.sensor.conventions.RESPONSES``; a reconstruction of
#: a real capture uses the closed form, and streams in spikezoo's convention do not read it).
SIMULATED_RESPONSE = "emission-model"


#: Methods whose frames are spike rates per raw pixel-plane, not light: on a camera's stream (the physical
#: convention) the evaluation reads them through the same response RMB-Net is given (``rate_as_light``), so every
#: row is scored in the ground truth's units; in spikezoo's convention a rate is the light itself, except that on the
#: binned stream the 3-bit clamp holds the counts of bright pixels below it (``CLAMPED_RATE_METHODS``), which RMB-Net's
#: reading undoes too.
RATE_METHODS = ("tfp", "tfi", "tfw")
#: Rate methods whose frames on the binned stream are means of its clamped counts (TFI there reads the 1-bit plane,
#: one raw pixel of each bin: nothing clamps it).
CLAMPED_RATE_METHODS = ("tfw",)


def rate_as_light(method: str, image: np.ndarray, convention: str, binned: bool = False) -> np.ndarray:
    """``image`` of ``method`` in the ground truth's units: a rate method's frame of a camera's stream read through
    the emission model's response (``SIMULATED_RESPONSE``; per pixel, before any 2x2 average); in spikezoo's
    convention, for the mean of the ``binned`` stream's clamped counts, through the inverse of the clamp
    (``rate_convention_intensity``); else as it is."""
    clamped = binned and method in CLAMPED_RATE_METHODS
    if method not in RATE_METHODS or (convention != "physical" and not clamped):
        return image
    import torch

    from rmbvideo.net.blend import rate_convention_intensity, reset_to_zero_intensity

    read = reset_to_zero_intensity if convention == "physical" else rate_convention_intensity
    return read(torch.from_numpy(np.ascontiguousarray(image, np.float32))).numpy()


def sequence_convention(seq: Sequence) -> str:
    """The sensor convention that made ``seq`` (its description says; panorama pans are physical)."""
    try:
        return str(json.loads(seq.description or "{}").get("convention", "physical"))
    except ValueError:
        return "physical"


def run_frames(spec: MethodSpec, seq: Sequence) -> tuple[list[Frame], float, float | None]:
    """All frames of ``spec`` on ``seq`` (at GT size, finite), wall-clock seconds, network seconds.

    One streaming run (``reconstruct_stream``); its time leaves out reading the cached arrays
    (the "read" stage), so rows differ only by what their method does."""
    options = dict(spec.options)
    if "convention" in get_method(spec.method).extra_options:  # RMB-Net, GC20 and MG20 are told what made the spikes
        options.setdefault("convention", sequence_convention(seq))
    if spec.method == "rmbnet":
        options.setdefault("response", SIMULATED_RESPONSE)
    recon = make_reconstructor(spec.method, **options)
    readout = RmbReadout(mode=spec.readout)
    sink = FrameCollector()
    if spec.gated:
        gate = raw_gate_stage("auto", options.get("model"))
        recon = FullResolution(recon, readout, step=20, output="binned", raw_gate=gate, threads=options.get("threads"))
    if spec.raw or spec.gated or recon.input_kind == "rmb":
        summary = reconstruct_stream(seq, recon, sink, chunk_planes=2 * CHUNK_READOUTS,
                                     readout=None if spec.raw or spec.gated else readout)
    else:
        summary = reconstruct_stream(SinglePlaneSource(seq, readout), recon, sink, chunk_planes=CHUNK_READOUTS)
    convention = sequence_convention(seq)
    frames = [Frame(f.index, f.time_s, rate_as_light(spec.method, f.image, convention, binned=not spec.raw))
              for f in sink.frames.values()]
    if spec.raw:
        frames = [Frame(f.index, f.time_s, downsample_2x(f.image, seq.shape)) for f in frames]
    seconds = summary.seconds - summary.stages["read"]
    return frames, seconds, summary.stages.get("network")


def scored_truth(seq: Sequence, indices: Iterable[int]) -> dict[int, np.ndarray]:
    """``seq``'s ground truth at ``indices`` as it is scored: clipped at the sensor's saturation."""
    return {i: np.minimum(seq.gt[i], SATURATION) for i in indices}


def score_frames(frames: dict[int, np.ndarray], seq: Sequence) -> tuple[float, float, float]:
    """Mean mu-law PSNR, mu-law SSIM and PU21 PSNR of ``frames`` (index -> image) against ``seq.gt``."""
    truth = scored_truth(seq, frames)
    scores = np.array([(mu_law_psnr(image, truth[i]), mu_law_ssim(image, truth[i]), pu21_psnr(image, truth[i]))
                       for i, image in frames.items()])
    return tuple(float(v) for v in scores.mean(axis=0))  # type: ignore[return-value]


def run_method(spec: MethodSpec, seq: Sequence) -> MethodResult:
    """Run ``spec`` on ``seq``, keep the scored frames, and score them against the ground truth.

    Raises ``ValueError`` when the method does not produce every scored frame (at the right time).
    """
    frames, seconds, network = run_frames(spec, seq)
    by_index = {f.index: f for f in frames}
    scored: dict[int, np.ndarray] = {}
    for i in seq.scored_frames:
        frame = by_index.get(i)
        if frame is None:
            raise ValueError(f"{spec.name} on {seq.name}: no frame {i} (emitted {sorted(by_index)})")
        if not math.isclose(frame.time_s, seq.frame_time(i), rel_tol=1e-9, abs_tol=1e-9):
            raise ValueError(f"{spec.name} on {seq.name}: frame {i} at {frame.time_s} s, "
                             f"ground truth at {seq.frame_time(i)} s")
        if frame.image.shape != seq.shape:
            raise ValueError(f"{spec.name} on {seq.name}: frame shape {frame.image.shape}, GT {seq.shape}")
        scored[i] = frame.image
    psnr, ssim, pu21 = score_frames(scored, seq)
    return MethodResult(frames=scored, psnr=psnr, ssim=ssim, pu21=pu21, seconds=seconds,
                        frames_emitted=len(frames), network_seconds=network,
                        temporal=temporal_score(scored, scored_truth(seq, scored)))


def temporal_score(frames: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> float:
    """``temporal_mu_law_psnr`` of ``frames`` (index -> image) against ``truth`` (the same indices), over the runs of
    consecutive indices, weighted by their pairs; NaN without a pair."""
    keys = sorted(frames)
    runs: list[list[int]] = []
    for i in keys:
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    pairs = [(run, len(run) - 1) for run in runs if len(run) > 1]
    if not pairs:
        return math.nan
    scores = [temporal_mu_law_psnr([frames[i] for i in run], [truth[i] for i in run]) for run, _ in pairs]
    return float(np.average(scores, weights=[n for _, n in pairs]))


@dataclass
class RowResult:
    """A table row over the whole set: ``status`` "ok", "not trained" or "failed: ..."; means of the
    per-sequence scores; frames per second over all sequences; frames of the figure sequence."""

    name: str
    status: str
    psnr: float = math.nan
    ssim: float = math.nan
    pu21: float = math.nan
    fps: float = math.nan
    network_fps: float = math.nan
    temporal: float = math.nan
    figure_frames: dict[int, np.ndarray] = field(default_factory=dict)
    per_sequence: dict[str, float] = field(default_factory=dict)  # sequence name -> mu-law PSNR
    middle_frames: dict[str, np.ndarray] = field(default_factory=dict)  # sequence name -> its middle scored frame


def aggregate(name: str, results: list[MethodResult], sequences: list[Sequence]) -> RowResult:
    """Combine per-sequence results: metric means of the sequence means, fps over all frames and time."""
    frames = sum(r.frames_emitted for r in results)
    seconds = sum(r.seconds for r in results)
    network = [r.network_seconds for r in results if r.network_seconds is not None]
    return RowResult(
        name=name, status="ok",
        psnr=float(np.mean([r.psnr for r in results])),
        ssim=float(np.mean([r.ssim for r in results])),
        pu21=float(np.mean([r.pu21 for r in results])),
        temporal=float(np.mean([r.temporal for r in results])),
        fps=frames / seconds if seconds > 0 else math.inf,
        network_fps=(frames / sum(network) if sum(network) > 0 else math.inf) if network else math.nan,
        figure_frames=results[0].frames,
        per_sequence={seq.name: r.psnr for seq, r in zip(sequences, results)},
        middle_frames={seq.name: r.frames[middle_frame(seq)] for seq, r in zip(sequences, results)},
    )


def middle_frame(seq: Sequence) -> int:
    """The scored frame in the middle of ``seq`` (the one figures show)."""
    return seq.scored_frames[len(seq.scored_frames) // 2]


def best_of(name: str, rows: list[RowResult]) -> RowResult:
    """Per sequence, the best of ``rows`` by mu-law PSNR (an oracle choice among them); its metrics
    are the means over sequences of the chosen rows' scores; fps is that of the slowest row."""
    ok = [r for r in rows if r.status == "ok"]
    if not ok:
        return RowResult(name=name, status="no rows")
    sequences = list(ok[0].per_sequence)
    chosen = {seq: max(ok, key=lambda r: r.per_sequence[seq]) for seq in sequences}
    return RowResult(name=name, status="ok", psnr=float(np.mean([chosen[s].per_sequence[s] for s in sequences])),
                     ssim=math.nan, pu21=math.nan, fps=min(r.fps for r in ok),
                     figure_frames=chosen[sequences[0]].figure_frames,
                     per_sequence={s: chosen[s].per_sequence[s] for s in sequences},
                     middle_frames={s: chosen[s].middle_frames[s] for s in sequences})


def evaluate_rows(specs: Iterable[MethodSpec], sequences: list[Sequence], progress: bool = False) -> list[RowResult]:
    """Every row on every sequence; the frames of the first sequence are kept for the figure.

    A row whose weight file is missing is "not trained"; a weight file that cannot be used
    (``RmbvideoError``) gives "failed: <reason>" for that row only.
    """
    from tqdm import tqdm

    from rmbvideo.errors import RmbvideoError

    specs = list(specs)
    rows = []
    total = sum(len(sequences) for s in specs if s.available)
    with tqdm(total=total, unit="run", disable=not progress, dynamic_ncols=True) as bar:
        for spec in specs:
            if not spec.available:
                log.info("%s: %s not found: not trained", spec.name, spec.model_path)
                rows.append(RowResult(name=spec.name, status="not trained"))
                continue
            bar.set_description(spec.name)
            results = []
            try:
                for seq in sequences:
                    results.append(run_method(spec, seq))
                    bar.update(1)
            except RmbvideoError as exc:
                log.warning("%s: %s", spec.name, exc)
                rows.append(RowResult(name=spec.name, status=f"failed: {exc}"))
                bar.update(len(sequences) - len(results))
                continue
            row = aggregate(spec.name, results, sequences)
            log.info("%s: mu-PSNR %.2f dB, SSIM %.3f, PU21 %.2f dB, %.1f fps",
                     row.name, row.psnr, row.ssim, row.pu21, row.fps)
            rows.append(row)
    return rows


#: Ablation row name -> (weight file stem, readout design of its input). The stems are the ``name``s of
#: the short recipes ``rmbvideo/train/recipes/ablation-*.toml``.
ABLATIONS: dict[str, tuple[str, str]] = {
    # The shipped model trained longer than the ablations; this row is the main recipe on the
    # ablations' short budget, so ablation rows are compared with it, not with "RMB-Net".
    "RMB-Net (ablation budget)": ("rmbnet-binned-short", "rmb"),
    "w = 0": ("rmbnet-binned-w0", "rmb"),
    "Pure-S": ("rmbnet-binned-pure-s", "pure-s"),
    "Pure-M": ("rmbnet-binned-pure-m", "pure-m"),
    "Full-M": ("rmbnet-binned-full-m", "full-m"),
    "w/o XBA": ("rmbnet-binned-no-xba", "rmb"),
    "w/o XTA": ("rmbnet-binned-no-xta", "rmb"),
}


#: The classical baselines of paper Table 2, all on the same RMB input (TFI on its 1-bit plane).
BASELINE_SPECS = (
    MethodSpec("TFW-S", "tfw", {"window": 10, "step": 10}),
    MethodSpec("TFW-L", "tfw", {"window": 70, "step": 10}),
    MethodSpec("TFI", "tfi", {"step": 10}),
    MethodSpec("GC20", "gc20", {}),
    MethodSpec("MG20", "mg20", {}),
)


def baseline_specs(readout: str) -> list[MethodSpec]:
    """The baselines on the binned stream through ``readout`` (the default model's input)."""
    return [MethodSpec(s.name, s.method, s.options, readout) for s in BASELINE_SPECS]
#: Central planes of the raw capture's TFI-M rows (``Tfi``'s ``window``: the whole inter-spike intervals covering
#: them), a doubling sweep like TFP's windows; 0, plain TFI, is a row of its own.
TFI_WINDOWS = (4, 8, 16)
#: Classical methods on the raw capture at full resolution, scored after 2x2 averaging; the table
#: adds their per-sequence best as ``BEST_RAW``.
RAW_SPECS = (
    *(MethodSpec(f"TFP-{window} (raw)", "tfp", {"window": window, "step": 20}, raw=True)
      for window in (20, 41, 80, 140)),
    MethodSpec("TFI (raw)", "tfi", {"step": 20}, raw=True),
    *(MethodSpec(f"TFI-{window} (raw)", "tfi", {"step": 20, "window": window}, raw=True) for window in TFI_WINDOWS),
)
BEST_RAW = "best classical on the raw capture"
RMB_ROW = "RMB-Net, RMB readout"
#: What the default job makes of a 1-bit capture at this size (``reconstruct --resolution binned``, and the default
#: full-resolution frames 2x2-averaged): RMB-Net's frames mixed with the raw intervals by the shipped raw gate
GATED_ROW = "RMB-Net + raw gate (1-bit capture)"
#: The default model reading the cameras by the closed form, as it reads a real capture (``SIMULATED_RESPONSE``)
CLOSED_FORM_ROW = "RMB-Net, closed-form response"


def with_best_raw(rows: list[RowResult]) -> list[RowResult]:
    """``rows`` with the per-sequence best of the raw rows (``BEST_RAW``) after the last raw row."""
    raw_names = {spec.name for spec in RAW_SPECS}
    raw = [r for r in rows if r.name in raw_names]
    if not raw:
        return rows
    last = max(i for i, r in enumerate(rows) if r.name in raw_names)
    return rows[: last + 1] + [best_of(BEST_RAW, raw)] + rows[last + 1:]


def ablation_model_path(models_dir: Path, stem: str) -> Path:
    """``models_dir/ablations/<stem>.safetensors``, or ``models_dir/<stem>.safetensors`` when only that
    exists (where ``rmbvideo train`` writes by default)."""
    nested = models_dir / "ablations" / f"{stem}.safetensors"
    flat = models_dir / f"{stem}.safetensors"
    return flat if flat.is_file() and not nested.is_file() else nested


def table2_specs(models_dir: Path, device: str = "auto", precision: str = "auto") -> list[MethodSpec]:
    """The rows of the paper's Table 2 (without Spk2ImgNet): the baselines on the default model's input
    (the binned stream through the readout it was trained on), RMB-Net (``rmbnet-binned`` in
    ``models_dir``), RMB-Net on the RMB readout (``rmbnet-binned-rmb``, when the default reads another),
    the classical methods on the raw capture, and the ablations (``ablation_model_path``). RMB-Net also reads the
    cameras as it would a real one (``CLOSED_FORM_ROW``), and is run as the default job runs it on a 1-bit capture,
    with the raw gate (``GATED_ROW``), when the gate is installed. ``precision``: the network's, as ``reconstruct
    --precision``."""
    models_dir = Path(models_dir)

    def rmbnet(name: str, path: Path, readout: str, **options: str) -> MethodSpec:
        return MethodSpec(name, "rmbnet", {"model": str(path), "device": device, "precision": precision,
                                           "input_mode": "binned", **options},
                          readout)

    default = models_dir / "rmbnet-binned.safetensors"
    readout = model_readout(default)
    specs = [*baseline_specs(readout), rmbnet("RMB-Net", default, readout),
             rmbnet(CLOSED_FORM_ROW, default, readout, response="closed-form")]
    if default_raw_gate_path().is_file():
        specs.insert(len(specs) - 1, replace(rmbnet(GATED_ROW, default, readout), gated=True))
    rmb_model = models_dir / "rmbnet-binned-rmb.safetensors"
    if readout != "rmb" and rmb_model.is_file():
        specs.append(rmbnet(RMB_ROW, rmb_model, "rmb"))
    specs += RAW_SPECS
    specs += [rmbnet(name, ablation_model_path(models_dir, stem), readout)
              for name, (stem, readout) in ABLATIONS.items()]
    return specs
