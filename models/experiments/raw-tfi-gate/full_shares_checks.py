"""Checks behind the candidates' own detail and the detail stage that reads TFI-4/16 (the sixth stop of
2026-11-29; ``results.md``, "At full resolution, the candidates' own pixels"). Run from the repository root:

    python models/experiments/raw-tfi-gate/full_shares_checks.py variants [NAME ...]   # noise-aware variants, development
    python models/experiments/raw-tfi-gate/full_shares_checks.py pictures OUT   # crops, the share 0 against 1/2
    python models/experiments/raw-tfi-gate/full_shares_checks.py cost BEFORE.safetensors CAPTURE.dat [ROUNDS]
    python models/experiments/raw-tfi-gate/full_shares_checks.py gate-cost   # the gate's convolutions, channels-last

``variants`` scores three alternatives to ``with_candidate_detail`` at a share of 1/2 (every candidate's detail in
TFI-4's shape, in TFI-16's, and only the part of it both candidates share over 6x6 pixels) beside it (2 minutes each).
``pictures`` writes, for the share 0 and 1/2 with the shipped stages: the held-out random-1000005's middle frame where
the two differ most (a flat wall), ``car.dat``'s middle frame (a real camera) and the held-out fast-0 clip's first,
middle and last frames where they differ most (moving edges). ``cost`` times the default full-resolution job on
CAPTURE (e.g. ``rmbvideo simulate fast-motion -o fm.dat --duration 0.1``) with the detail stage BEFORE (e.g. ``git
show 23c75e7:models/detail-binned.safetensors``, with its ``.json``) and the shipped one, alternated, one thread,
everything inline. ``gate-cost`` times the shipped gate's convolutions on standard- and
channels-last input at 200x125 and 500x500 and prints how far their logits differ.
"""

import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

import rmbvideo.recon.full_resolution as fr
from full_shares import STREAMS, frames
from rmbvideo.evaluate.full_resolution import full_ground_truth
from rmbvideo.evaluate.harness import SATURATION, sequence_convention
from rmbvideo.evaluate.heldout import load_development, load_heldout, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.real_video import CONVENTION, find_streams, open_stream, scaled_psnr
from rmbvideo.mulaw import mu_law
from rmbvideo.recon.full_resolution import block_mean, spread

CAR = Path("../shared/data/real/car.dat")


def _shaped_by(k: int):
    """``with_candidate_detail`` with every candidate's detail in candidate ``k``'s relative shape."""
    def mix(full, gated, shares, candidates, strength=0.5):
        level = spread(gated.astype(np.float32))
        shape = np.where(level > 0, full / np.maximum(level, 1e-30), 1.0)
        mean = block_mean(candidates[k])
        relative = np.where(mean > 0, candidates[k] / np.maximum(mean, 1e-30), 1.0)
        own = sum(spread(s) * block_mean(c) * (relative - shape) for s, c in zip(shares, candidates))
        return np.maximum(full + np.float32(strength) * own, 0).astype(np.float32)
    return mix


def _agreement(full, gated, shares, candidates, strength=0.5):
    """``with_candidate_detail`` keeping, per pixel, the part of each candidate's relative detail that the other
    candidate shares (their correlation over 6x6 pixels, clipped to 0..1)."""
    level = spread(gated.astype(np.float32))
    shape = np.where(level > 0, full / np.maximum(level, 1e-30), 1.0)
    rels = [np.where(block_mean(c) > 0, c / np.maximum(block_mean(c), 1e-30), 1.0) - 1 for c in candidates]
    cov = cv2.blur(block_mean(rels[0] * rels[1]), (6, 6))
    var = [cv2.blur(block_mean(r * r), (6, 6)) for r in rels]
    gain = np.clip(cov / np.maximum(np.sqrt(var[0] * var[1]), 1e-12), 0, 1)
    own = sum(spread(s) * block_mean(c) * (1 + gain * r - shape) for s, c, r in zip(shares, candidates, rels))
    return np.maximum(full + np.float32(strength) * own, 0).astype(np.float32)


def _regularity(tau: float):
    """``with_candidate_detail`` with a per-block strength from its intervals' regularity, exp(-|ln(TFI-4 / TFI-16)| /
    ``tau``) averaged over the block: up to the whole of the candidates' detail where the two windows agree (a still,
    noise-free pixel fires periodically), none where they do not (a camera's shot noise, or motion)."""
    def mix(full, gated, shares, candidates, strength=0.5):
        ratio = np.abs(np.log((candidates[0] + 1e-4) / (candidates[1] + 1e-4)))
        regular = block_mean(np.exp(-ratio / tau).astype(np.float32))
        level = spread(gated.astype(np.float32))
        shape = np.where(level > 0, full / np.maximum(level, 1e-30), 1.0)
        own = sum(spread(s) * (c - block_mean(c) * shape) for s, c in zip(shares, candidates))
        return np.maximum(full + regular * own, 0).astype(np.float32)
    return mix


def variants(*chosen: str) -> None:
    """Each variant (those ``chosen`` by name, all when none) on the development sets."""
    torch.set_num_threads(1)
    shipped = fr.with_candidate_detail
    sequences, streams = load_development(), find_streams(STREAMS) if STREAMS.is_dir() else []
    for name, mix in {"shipped": shipped, "TFI-4's shape": _shaped_by(0), "TFI-16's shape": _shaped_by(1),
                      "agreement": _agreement, "regularity 0.05": _regularity(0.05),
                      "regularity 0.1": _regularity(0.1), "regularity 0.2": _regularity(0.2)}.items():
        if chosen and name not in chosen:
            continue
        fr.with_candidate_detail = mix  # looked up by FullResolution at each frame
        scores = []
        for seq in sequences:
            truth = {i: np.minimum(g, SATURATION) for i, g in full_ground_truth(seq).items()}
            made = frames(lambda: seq, sequence_convention(seq), 0.5)
            scores.append(float(np.mean([mu_law_psnr(made[i], truth[i]) for i in truth])))
        real = []
        for stream in streams:
            reference = cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
            made = frames(lambda: open_stream(stream), CONVENTION, 0.5, keep=[stream.frame])[stream.frame]
            real.append(scaled_psnr(made[: reference.shape[0], : reference.shape[1]], reference))
        print(f"{name}: " + " ".join(f"{x:.2f}" for x in scores + real)
              + f" | synthetic {np.mean(scores):.2f}, real {np.mean(real) if real else float('nan'):.2f}", flush=True)
    fr.with_candidate_detail = shipped


def _crop_where_they_differ(images: list[np.ndarray], size: int = 96) -> tuple[int, int]:
    difference = cv2.blur(np.abs(images[1] - images[0]).astype(np.float32), (size // 2, size // 2))
    y, x = np.unravel_index(int(np.argmax(difference)), difference.shape)
    h, w = images[0].shape
    return max(0, min(y - size // 2, h - size)), max(0, min(x - size // 2, w - size))


def _tiles(images: list[np.ndarray], scale: float, corner: tuple[int, int], size: int = 96) -> np.ndarray:
    y, x = corner
    shown = [(255 * mu_law(torch.from_numpy(np.clip(i / scale, 0, 1)), 5000).numpy()).astype(np.uint8)[y:y + size,
                                                                                                      x:x + size]
             for i in images]
    return cv2.resize(np.concatenate(shown, 1), None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST)


def pictures(out: str) -> None:
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.recon.run import prepare_run

    torch.set_num_threads(1)
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    sequences = {s.name: s for s in load_heldout(False) + load_video_heldout(False)}
    for name, picks in (("random-1000005", "middle"), ("fast-0", "first"), ("fast-0", "middle"), ("fast-0", "last")):
        seq = sequences[name]
        # every frame's truth, the clip's edge frames too (the evaluation's tables leave them out)
        truth = {i: np.minimum(g, SATURATION) for i, g in full_ground_truth(replace(seq, edge_readouts=0)).items()}
        index = {"first": 0, "middle": len(truth) // 2, "last": len(truth) - 1}[picks]
        made = [frames(lambda: seq, sequence_convention(seq), a)[index] for a in (0.0, 0.5)]
        print(f"{name} {picks} frame {index}: share 0 {mu_law_psnr(made[0], truth[index]):.2f} dB, "
              f"1/2 {mu_law_psnr(made[1], truth[index]):.2f} dB")
        images = [truth[index], *made]
        tiles = _tiles(images, float(np.percentile(truth[index], 99.9)), _crop_where_they_differ(made))
        cv2.imwrite(str(folder / f"{name}-{picks}.png"), tiles)  # truth, share 0, share 1/2
    if CAR.is_file():
        made = []
        for strength in (0.0, 0.5):
            run = prepare_run(CAR, resolution="full", extra_options=dict(threads=1))
            run.method.candidate_detail = strength
            sink = FrameCollector()
            reconstruct_stream(run.reader, run.method, sink, chunk_planes=128, readout=run.readout)
            made.append(sink.frames[len(sink.frames) // 2].image)
        print(f"car.dat middle frame: mean |difference| {np.mean(np.abs(made[1] - made[0])) / np.mean(made[0]):.4f} "
              "of the mean level")
        cv2.imwrite(str(folder / "car-middle.png"),
                    _tiles(made, float(np.percentile(made[0], 99.5)), _crop_where_they_differ(made)))


def cost(before: str, capture: str, rounds: int = 4) -> None:
    from rmbvideo.net.weights import load_detail_model
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.recon.run import prepare_run

    torch.set_num_threads(1)
    stages = {"before": load_detail_model(before)[0], "shipped": fr.detail_stage("learned")}
    times: dict[str, list[float]] = {k: [] for k in stages}
    for round_ in range(rounds):
        for name in list(stages) if round_ % 2 == 0 else list(stages)[::-1]:
            run = prepare_run(Path(capture), resolution="full", extra_options=dict(threads=1))
            method = run.method
            full = fr.FullResolution(method.binned, method.readout, step=20, detail=stages[name], threads=1,
                                     raw_gate=method.raw_gate, finish_beside=False)
            began = time.perf_counter()
            reconstruct_stream(run.reader, full, FrameCollector(keep=[]), chunk_planes=128)
            times[name].append(time.perf_counter() - began)
            print(name, f"{times[name][-1]:.2f} s", {k: round(v, 2) for k, v in full.stage_seconds.items()},
                  flush=True)
    print("medians:", {k: round(statistics.median(v), 2) for k, v in times.items()})


def gate_cost(rounds: int = 40) -> None:
    from rmbvideo.net.raw_gate import gate_features

    torch.set_num_threads(1)
    gate = fr.raw_gate_stage("auto").eval()
    for h, w in ((125, 200), (500, 500)):
        binned, candidates = torch.rand(1, 1, h, w) * 0.3, torch.rand(1, 2, h, w) * 0.3
        with torch.inference_mode():
            features = gate_features(binned, candidates[:, :1], binned, 0.0, candidates[:, 1:], frame=True)
            x = (features - gate.feature_mean.reshape(1, -1, 1, 1)) / gate.feature_std.clamp(min=1e-6).reshape(
                1, -1, 1, 1)
            last = x.contiguous(memory_format=torch.channels_last)
            times: dict[str, list[float]] = {"standard": [], "channels-last": []}
            for round_ in range(rounds):
                for name in list(times) if round_ % 2 else list(times)[::-1]:
                    began = time.perf_counter()
                    gate.body(x if name == "standard" else last)
                    times[name].append(time.perf_counter() - began)
            gap = float((gate.body(x) - gate.body(last)).abs().max())
        print(f"{w}x{h}: median ms", {k: round(1e3 * statistics.median(v[4:]), 2) for k, v in times.items()},
              f"logits differ by at most {gap:.1e}")


if __name__ == "__main__":
    command, *args = sys.argv[1:] or ["variants"]
    {"variants": variants, "pictures": pictures, "cost": cost, "gate-cost": gate_cost}[command](
        *[int(a) if a.isdigit() else a for a in args])
