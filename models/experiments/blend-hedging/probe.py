"""Why the default trails MG20 on a slow pan of fine texture (held-out random-1000000), measured on development seeds
only, with the shipped model and no retraining. Run from the repository root (each a few minutes on 2 cores):

    python models/experiments/blend-hedging/probe.py bands 57     # each blend candidate's error by texture band
    python models/experiments/blend-hedging/probe.py bias         # the aligned mean's logit raised by b at inference
    python models/experiments/blend-hedging/probe.py gates        # hard gates on the robust merge's support / chi^2
    python models/experiments/blend-hedging/probe.py window       # the window's neighbours marked missing throughout
    python models/experiments/blend-hedging/probe.py prime        # first-frame figures with --prime 3 and 8
    python models/experiments/blend-hedging/probe.py radius       # the aligned mean over 3, 5 (shipped) and 8 frames
    python models/experiments/blend-hedging/probe.py flip         # the network also on the mirrored stream, averaged
    python models/experiments/blend-hedging/probe.py sharpen      # the blend's logits scaled by s at inference
    python models/experiments/blend-hedging/probe.py learned-gate odd|even|heldout all|noflow|nomerge|images [SEEDS]   # a learned mix
    python models/experiments/blend-hedging/probe.py models A.safetensors B.safetensors ...   # candidates side by side
    python models/experiments/blend-hedging/probe.py flow         # per pan: how much the aligned mean helps, the flow
    python models/experiments/blend-hedging/probe.py car A.safetensors   # a model against the default on car.dat
    python models/experiments/blend-hedging/probe.py cost         # what the aligned mean's statistics cost per frame
    python models/experiments/blend-hedging/probe.py picture 4768347   # stage14-random-1000000.png (stage 13 at 4768347)
    python models/experiments/blend-hedging/probe.py edges prime0|noshift|symmetric   # edge frames' timing, a cause off
    python models/experiments/blend-hedging/probe.py edge-models A.safetensors ...   # edge frames of candidate models
    python models/experiments/blend-hedging/probe.py stride       # the DIS patch stride 3, 4 (shipped), 5: scores, ms
    python models/experiments/blend-hedging/probe.py warps        # the neighbours warped bilinear (shipped) or bicubic
    python models/experiments/blend-hedging/probe.py profile      # where a frame's time goes, one thread, bf16

The blend is hooked at ``rmbvideo.net.model.blend`` (its candidates in linear units and the softmax weights), the
aligned mean at ``rmbvideo.recon.aligned_box.AlignedBox.mean`` (its per-pixel statistics, ``STATISTICS`` there).
"""

import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

import rmbvideo.net.model as model_module
import rmbvideo.recon.aligned_box as aligned_module
import rmbvideo.recon.rmbnet as engine_module
from rmbvideo.evaluate.harness import SATURATION, MethodSpec, run_frames, score_frames
from rmbvideo.evaluate.heldout import (DEVELOPMENT_RANDOM_OFFSET, DEVELOPMENT_VIDEO_FIRST, FULL, load_heldout,
                                       load_heldout_config, load_video_heldout)
from rmbvideo.evaluate.metrics import robust_scale
from rmbvideo.evaluate.video_checks import edge_report
from rmbvideo.mulaw import mu_law
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import default_model_path, load_model, save_model

CANDIDATES = ["own", "reference", "pool 3", "pool 7", "centre 2", "centre 4", "centre 6", "aligned"]
RECORD: list = []  # (candidates (1, K, H, W), weights (1, K, H, W)) of every blend call
STATISTICS: dict[int, np.ndarray] = {}  # frame -> its aligned mean's per-pixel statistics (aligned_box.STATISTICS)
BLEND_KNOBS = {"aligned": 0.0, "scale": 1.0}
_blend, _mean = model_module.blend, aligned_module.AlignedBox.mean


def blend(own, candidates, logits):
    logits = logits.clone() * BLEND_KNOBS["scale"]
    logits[:, -1] += BLEND_KNOBS["aligned"]
    weights = torch.softmax(logits.float(), 1)
    RECORD.append((torch.cat([own.float(), *(c.float() for c in candidates)], 1).numpy().copy(), weights.numpy().copy()))
    return _blend(own, candidates, logits)


def aligned_mean(self, i, neighbours, statistics=False):
    mean, STATISTICS[i] = _mean(self, i, neighbours, statistics=True)
    return (mean, STATISTICS[i]) if statistics else mean


model_module.blend = blend
aligned_module.AlignedBox.mean = aligned_mean


def development(names=()) -> list:
    sequences = load_heldout_config(replace(FULL, count=16, first_seed_offset=DEVELOPMENT_RANDOM_OFFSET))
    sequences += load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST)
    return [s for s in sequences if not names or s.name in names]


def run(seq, **options):
    """The default's frames of ``seq`` (index -> image) and, per frame, its blend record (priming calls dropped)."""
    RECORD.clear()
    STATISTICS.clear()
    spec = MethodSpec("default", "rmbnet", {"threads": 1, "input_mode": "binned", "precision": "fp32", **options},
                      "pure-m")
    frames, _, _ = run_frames(spec, seq)
    records = RECORD[len(RECORD) - len(frames):]
    order = sorted(f.index for f in frames)
    return {f.index: f.image for f in frames}, dict(zip(order, records))


def score(images, seq) -> float:
    return score_frames({i: images[i] for i in seq.scored_frames}, seq)[0]


def table(rows: dict, columns: list[str]) -> None:
    print("| sequence | " + " | ".join(columns) + " |")
    print("|---|" + "---:|" * len(columns))
    for name, values in rows.items():
        print(f"| {name} | " + " | ".join(f"{v:.2f}" for v in values) + " |")
    print("| mean | " + " | ".join(f"{v:.2f}" for v in np.mean(list(rows.values()), axis=0)) + " |")


def bands(seed: str = "57") -> None:
    """Mean squared mu-law error of each candidate, the blend and MG20 in four bands of the ground truth's local
    gradient (below its median, to the 80th percentile, to the 95th, above), and the candidates' mean weights."""
    seq = development([f"random-{1_000_000 + int(seed)}"])[0]
    _, records = run(seq)
    mg20 = {f.index: f.image for f in run_frames(MethodSpec("MG20", "mg20", {}, "pure-m"), seq)[0]}
    h, w = seq.shape
    errors, weights = {}, np.zeros((len(CANDIDATES), 4))
    counts = np.zeros(4)
    for i in seq.scored_frames:
        truth = np.minimum(seq.gt[i], SATURATION)
        scale = robust_scale(truth)
        tone = mu_law(np.clip(truth / scale, 0, 1)).astype(np.float32)
        gradient = np.hypot(cv2.Sobel(tone, cv2.CV_32F, 1, 0), cv2.Sobel(tone, cv2.CV_32F, 0, 1))
        band = np.digitize(gradient, np.quantile(gradient, [0.5, 0.8, 0.95]))
        candidates, weight = records[i][0][0, :, :h, :w], records[i][1][0, :, :h, :w]
        images = {**dict(zip(CANDIDATES, candidates)), "blend": (candidates * weight).sum(0), "MG20": mg20[i]}
        for name, image in images.items():
            error = (mu_law(np.clip(image / scale, 0, 1)) - tone) ** 2
            errors.setdefault(name, np.zeros(4))
            errors[name] += [error[band == b].sum() for b in range(4)]
        weights += np.stack([[weight[k][band == b].sum() for b in range(4)] for k in range(len(CANDIDATES))])
        counts += [(band == b).sum() for b in range(4)]
    print(f"{seq.name}: mean squared mu-law error by gradient band (flat -> edges), and the blend's mean weight")
    for name, error in errors.items():
        k = CANDIDATES.index(name) if name in CANDIDATES else None
        extra = "" if k is None else "   weight " + " ".join(f"{v:.3f}" for v in weights[k] / counts)
        print(f"{name:10s} " + " ".join(f"{v:.2e}" for v in error / counts) + extra)


def sweep(key: str, values: tuple[float, ...], label: str) -> None:
    """Mean mu-law PSNR with the blend hook's ``key`` set to each value in turn."""
    default = BLEND_KNOBS[key]
    rows: dict[str, list[float]] = {}
    for seq in development():
        rows[seq.name] = []
        for value in values:
            BLEND_KNOBS[key] = value
            rows[seq.name].append(score(run(seq)[0], seq))
    BLEND_KNOBS[key] = default
    table(rows, [f"{label} = {v}" for v in values])


def bias() -> None:
    """Mean mu-law PSNR with the aligned mean's logit raised by b."""
    sweep("aligned", (0.0, 0.5, 1.0, 2.0), "b")


def sharpen() -> None:
    """Mean mu-law PSNR with the blend's logits times s (s > 1: each pixel leans harder on its favourite)."""
    sweep("scale", (1.0, 1.5, 2.0), "s")


def gates() -> None:
    """The blend, and the aligned mean where the merge's support reaches s (else the blend), where the warped
    neighbours' spread is within c x (a Bernoulli rate's variance) (smoothed, sigma 1), and where the flow is close
    to one rigid motion (its gradient below r pixels per pixel; else the blend)."""
    supports, spreads, rough = (0.8, 0.95), (0.03, 0.1), (0.02, 0.05)
    rows = {}
    for seq in development():
        _, records = run(seq)
        h, w = seq.shape
        blended = {i: (r[0][0] * r[1][0]).sum(0)[:h, :w] for i, r in records.items()}
        aligned = {i: r[0][0, -1, :h, :w] for i, r in records.items()}
        chi2 = {i: cv2.GaussianBlur(np.expm1(STATISTICS[i][3]), (0, 0), 1.0) for i in seq.scored_frames}
        row = [score(blended, seq)]
        row += [score({i: np.where(STATISTICS[i][2] >= s, aligned[i], blended[i]) for i in seq.scored_frames}, seq)
                for s in supports]
        row += [score({i: np.where(chi2[i] < c, aligned[i], blended[i]) for i in seq.scored_frames}, seq)
                for c in spreads]
        row += [score({i: np.where(STATISTICS[i][0] < r, aligned[i], blended[i]) for i in seq.scored_frames}, seq)
                for r in rough]
        rows[seq.name] = row
    table(rows, ["blend"] + [f"support >= {s}" for s in supports] + [f"chi2 < {c}" for c in spreads]
          + [f"flow gradient < {r}" for r in rough])


def gate_features(seq) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per scored frame: the blend, the aligned mean and per-pixel features a gate between them could use (the
    flow's gradient and magnitude, the light, their relative difference, the merge's support and spread)."""
    _, records = run(seq)
    h, w = seq.shape
    out = {}
    for i in seq.scored_frames:
        candidates, weights = records[i][0][0, :, :h, :w], records[i][1][0, :, :h, :w]
        blended, aligned = (candidates * weights).sum(0), candidates[-1]
        level = np.log(np.maximum(blended, 1e-4))
        difference = np.abs(aligned - blended) / np.maximum(blended, 1e-3)
        roughness, magnitude, support, spread = STATISTICS[i]
        features = np.stack([roughness, magnitude, level, difference, support, spread])
        out[i] = (blended, aligned, features.astype(np.float32))
    return out


def learned_gate(half: str = "odd", features: str = "all", seeds: str = "1") -> None:
    """How much a gate that sees the flow could gain: a small network maps per-pixel features (``gate_features``) to
    the share of the aligned mean in the output, fitted on ``half`` ("odd" or "even") of the development sequences to
    the mu-law L2 and scored on the other half ("heldout": fitted on all of them, scored on the held-out set): what
    the head could learn from these features (fitted on development data, so a figure for a decision, never a
    model). ``features``: "all", "noflow" (without the flow's two), "nomerge" (without the merge's support and
    spread), "images" (the light and the two images' difference only). ``seeds``: initialisations fitted (torch
    seeds 0..); each sequence's score is their mean, and the mean gain of each is printed."""
    sequences = development()
    if half == "heldout":  # fitted on every development sequence, scored once on the held-out set
        fit, test = sequences, load_heldout(False) + load_video_heldout(False)
    else:
        fit, test = (sequences[1::2], sequences[0::2]) if half == "odd" else (sequences[0::2], sequences[1::2])
    data = {seq.name: gate_features(seq) for seq in [*fit, *test]}
    keep = {"all": [0, 1, 2, 3, 4, 5], "noflow": [2, 3, 4, 5], "nomerge": [0, 1, 2, 3], "images": [2, 3]}[features]
    rng = np.random.default_rng(0)
    feats, blends, aligned, truths = [], [], [], []
    for seq in fit:  # 2,000 pixels of every scored frame
        for i, (b, a, f) in data[seq.name].items():
            truth = np.minimum(seq.gt[i], SATURATION)
            scale = robust_scale(truth)
            pick = rng.integers(0, b.size, 2000)
            feats.append(f[keep].reshape(len(keep), -1)[:, pick].T)
            blends.append((b / scale).ravel()[pick]), aligned.append((a / scale).ravel()[pick])
            truths.append((truth / scale).ravel()[pick])
    feats, blends, aligned, truths = (torch.from_numpy(np.concatenate(x).astype(np.float32))
                                      for x in (feats, blends, aligned, truths))
    mean, std = feats.mean(0), feats.std(0) + 1e-6
    tone = lambda x: torch.log1p(5000 * x.clamp(0, 1)) / np.log1p(5000)  # noqa: E731
    blend_scores = {seq.name: score({i: v[0] for i, v in data[seq.name].items()}, seq) for seq in test}
    gated: dict[str, list[float]] = {seq.name: [] for seq in test}
    for seed in range(int(seeds)):
        torch.manual_seed(seed)
        gate = torch.nn.Sequential(torch.nn.Linear(len(keep), 16), torch.nn.ReLU(), torch.nn.Linear(16, 1))
        optimiser = torch.optim.Adam(gate.parameters(), lr=3e-3)
        for _ in range(1500):
            share = torch.sigmoid(gate((feats - mean) / std))[:, 0]
            loss = ((tone(share * aligned + (1 - share) * blends) - tone(truths)) ** 2).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        with torch.no_grad():
            for seq in test:
                images = {}
                for i, (b, a, f) in data[seq.name].items():
                    x = (torch.from_numpy(f[keep].reshape(len(keep), -1).T) - mean) / std
                    share = torch.sigmoid(gate(x))[:, 0].numpy().reshape(b.shape)
                    images[i] = share * a + (1 - share) * b
                gated[seq.name].append(score(images, seq))
        print(f"initialisation {seed}: mean gain "
              f"{np.mean([gated[n][-1] - blend_scores[n] for n in gated]):+.2f} dB", flush=True)
    table({name: [blend_scores[name], float(np.mean(values))] for name, values in gated.items()},
          ["blend", "learned gate (fitted on the other sequences)"])


def window() -> None:
    """The default, and with its window's neighbours marked missing at every frame (the aligned mean unchanged)."""
    valid = engine_module.window_valid
    rows = {}
    for seq in development():
        rows[seq.name] = [score(run(seq)[0], seq)]
        engine_module.window_valid = lambda i, w, count: [j == w for j in range(2 * w + 1)]
        rows[seq.name].append(score(run(seq)[0], seq))
        engine_module.window_valid = valid
    table(rows, ["window", "neighbours missing"])


def prime() -> None:
    """First frame below the clip's median, and its edge cost, on two development video sequences of each kind."""
    sequences = load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST, per_kind=2)
    rows = {}
    for seq in sequences:
        reports = [edge_report(seq, "rmbnet", {"threads": 1, "prime": p}) for p in (3, 8)]
        rows[seq.name] = [v for r in reports for v in (r.first_drop_db, r.first_edge_cost_db)]
    table(rows, ["prime 3: first below median", "prime 3: edge cost", "prime 8: first below median",
                 "prime 8: edge cost"])


def radius() -> None:
    """The shipped weights with the aligned mean's half-width (``aligned_radius``) at 3, 5 (shipped) and 8 frames."""
    shipped, card = load_model(default_model_path())
    rows: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as folder:
        paths = []
        for r in (3, 5, 8):
            network = RmbNet(replace(shipped.config, aligned_radius=r))
            network.load_state_dict(shipped.state_dict())
            paths.append(save_model(Path(folder) / f"radius-{r}.safetensors", network, card))
        for seq in development():
            rows[seq.name] = [score(run(seq, model=path)[0], seq) for path in paths]
    table(rows, ["radius 3", "radius 5 (shipped)", "radius 8"])


def flip() -> None:
    """The default, and the mean of it and of its frames of the left-right mirrored stream, mirrored back."""
    rows = {}
    for seq in development():
        mirrored = replace(seq, single=np.ascontiguousarray(seq.single[..., ::-1]),
                           multi=np.ascontiguousarray(seq.multi[..., ::-1]), gt=seq.gt[..., ::-1])
        plain, other = run(seq)[0], run(mirrored)[0]
        rows[seq.name] = [score(plain, seq), score({i: 0.5 * (plain[i] + other[i][..., ::-1]) for i in plain}, seq)]
    table(rows, ["default", "with its mirror"])


def models(*paths: str) -> None:
    """Mean mu-law PSNR of model files (the shipped one first) on the 16 development pans and 5 video sequences."""
    files = [default_model_path(), *map(Path, paths)]
    rows = {seq.name: [score(run(seq, model=path)[0], seq) for path in files] for seq in development()}
    table(rows, [f"{path.parent.name}/{path.stem}" for path in files])


def flow() -> None:
    """Per development pan: what raising the aligned mean's logit by 2 gains, and the DIS flow's median and 90th
    percentile over its frames (the pans that move as one piece have a 90th percentile near the median)."""
    rows = {}
    for seq in development()[:16]:
        plain = score(run(seq)[0], seq)
        magnitudes = np.stack([STATISTICS[i][1] for i in seq.scored_frames])
        BLEND_KNOBS["aligned"] = 2.0
        raised = score(run(seq)[0], seq)
        BLEND_KNOBS["aligned"] = 0.0
        median, p90 = np.median(magnitudes), np.quantile(magnitudes, 0.9)
        rows[seq.name] = [raised - plain, median, p90, p90 / max(median, 1e-6)]
    table(rows, ["gain at b = 2 (dB)", "flow median (px/frame)", "flow 90th percentile", "ratio"])


def car(path: str) -> None:
    """A model file against the default on the real capture ``../shared/data/real/car.dat`` (no ground truth): the
    mean relative difference of their frames and the ratio of their means."""
    from rmbvideo.recon.run import reconstruct_frames

    capture = Path("../shared/data/real/car.dat")
    frames = [np.stack([f.image for f in reconstruct_frames(capture, "rmbnet", model=m, threads=1)])
              for m in (default_model_path(), Path(path))]
    print(f"mean relative difference {np.abs(frames[1] - frames[0]).mean() / frames[0].mean():.4f}, "
          f"ratio of means {frames[1].mean() / frames[0].mean():.4f}")


def cost() -> None:
    """What the aligned mean's statistics (``aligned_evidence``) cost: ``AlignedBox.mean`` at 200x125 on a panned noisy
    texture, flows cached, one OpenCV thread, with and without them (each flow's statistics made anew per round, as a
    stream makes them once), best of five rounds of 20 means."""
    import time

    cv2.setNumThreads(1)
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.random((125, 260)).astype(np.float32), (0, 0), 2)
    box = aligned_module.AlignedBox(aligned_module.AlignedBoxConfig.for_frames(10))
    for k in range(30):
        box.add(k, (rng.binomial(80, np.clip(texture[:, k : k + 200] * 0.8, 0, 1)) / 80).astype(np.float32))
    window = [aligned_module.aligned_window(i, 5, 30, True) for i in range(5, 25)]
    for i, frames in zip(range(5, 25), window):  # the flows, once
        _mean(box, i, frames)
    best = {False: np.inf, True: np.inf}
    for _ in range(5):
        for statistics in (False, True):
            box._flow_statistics.clear()
            began = time.perf_counter()
            for i, frames in zip(range(5, 25), window):
                _mean(box, i, frames, statistics)
            best[statistics] = min(best[statistics], (time.perf_counter() - began) / 20)
    print(f"AlignedBox.mean: {1e3 * best[False]:.2f} ms, with statistics {1e3 * best[True]:.2f} ms")


def picture(before: str, after: str = "", out: str = "models/figures/stage15-random-1000000.png") -> None:
    """Frame 10 of random-1000000 from ``models/figures/evaluation.png``: the columns ground truth, MG20 and TFI (raw)
    of the figure at git revision ``after`` (the file as it is when empty), with its RMB-Net column and that of the
    figure at ``before`` (an earlier default's evaluation) side by side, written to ``out``."""
    import subprocess

    path = "models/figures/evaluation.png"

    def figure(revision: str) -> np.ndarray:
        if not revision:
            return cv2.imread(path)
        data = subprocess.run(["git", "show", f"{revision}:{path}"], check=True, capture_output=True).stdout
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)

    new, old = figure(after), figure(before)
    width = new.shape[1] / 22  # the figure's 22 method columns
    column = lambda image, k: image[:, int(k * width) : int((k + 1) * width)].copy()  # noqa: E731
    parts = [(column(new, 0), "ground truth"), (column(new, 5), "MG20"), (column(old, 6), f"at {before[:7]}"),
             (column(new, 6), f"at {after[:7]}" if after else "default now"), (column(new, 13), "TFI (raw)")]
    for image, label in parts:
        cv2.rectangle(image, (0, 0), (image.shape[1], 22), (30, 30, 30), -1)
        cv2.putText(image, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.imwrite(out, np.concatenate([image for image, _ in parts], axis=1), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print("wrote", out)


def edges(variant: str = "symmetric") -> None:
    """The development video sequences' edge frames (dB below the clip's median, the time offset each shows, the
    middle frame's, the edge cost) with the default and with one suspected cause of their offsets turned off:
    ``prime0`` (no backward priming of the first state), ``noshift`` (the aligned window cut at the clip's ends, not
    slid inwards) or ``symmetric`` (the network's window cut symmetrically: positions beyond the nearer edge left
    out)."""
    import math

    shipped, card = load_model(default_model_path())
    valid = engine_module.window_valid

    def symmetric(i, w, count):
        last = math.inf if count is None else count - 1
        return [0 <= j <= last and abs(j - i) <= min(i, last - i) for j in range(i - w, i + w + 1)]

    with tempfile.TemporaryDirectory() as folder:
        options = {"threads": 1, "input_mode": "binned"}
        changed = dict(options, prime=0) if variant == "prime0" else dict(options)
        if variant == "noshift":
            network = RmbNet(replace(shipped.config, aligned_shift=False))
            network.load_state_dict(shipped.state_dict())
            changed["model"] = save_model(Path(folder) / "noshift.safetensors", network, card)
        elif variant != "prime0" and variant != "symmetric":
            raise SystemExit(f"edges: unknown variant {variant!r} (prime0, noshift, symmetric)")
        rows = {}
        for seq in development()[16:]:
            for label, opts in (("default", options), (variant, changed)):
                if variant == "symmetric" and label == variant:
                    engine_module.window_valid = symmetric
                r = edge_report(seq, "rmbnet", opts)
                engine_module.window_valid = valid
                rows[f"{seq.name} {label}"] = [r.first_drop_db, r.last_drop_db, r.first_offset_ms, r.last_offset_ms,
                                               r.middle_offset_ms, r.first_edge_cost_db, r.last_edge_cost_db]
    print("| sequence | first below median (dB) | last below median | first offset (ms) | last offset "
          "| middle offset | edge cost, first (dB) | edge cost, last |")
    print("|---|" + "---:|" * 7)
    for name, values in rows.items():
        print(f"| {name} | " + " | ".join(f"{v:+.2f}" for v in values) + " |")


def edge_models(*paths: str) -> None:
    """The development video sequences' edge frames (as ``edges``) with the shipped weights and each model file in
    ``paths``: dB below the clip's median, the time offset each edge frame shows, the edge cost."""
    rows = {}
    for seq in development()[16:]:
        for path in (str(default_model_path()), *paths):
            r = edge_report(seq, "rmbnet", {"threads": 1, "input_mode": "binned", "model": path})
            rows[f"{seq.name} {Path(path).parent.name}/{Path(path).stem}"] = [
                r.first_drop_db, r.last_drop_db, r.first_offset_ms, r.last_offset_ms, r.middle_offset_ms,
                r.first_edge_cost_db, r.last_edge_cost_db]
    print("| sequence, model | first below median (dB) | last below median | first offset (ms) | last offset "
          "| middle offset | edge cost, first (dB) | edge cost, last |")
    print("|---|" + "---:|" * 7)
    for name, values in rows.items():
        print(f"| {name} | " + " | ".join(f"{v:+.2f}" for v in values) + " |")


def _flow_images(count: int = 12) -> list[np.ndarray]:
    """8-bit flow images (as ``AlignedBox`` makes them) of a noisy texture panned by 1 px a frame at 200x125."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.random((125, 200 + count)).astype(np.float32), (0, 0), 1.2)
    images = []
    for k in range(count):
        rate = (rng.binomial(80, np.clip(texture[:, k : k + 200] * 0.8, 0, 1)) / 80).astype(np.float32)
        image = np.sqrt(cv2.GaussianBlur(rate, (0, 0), 1.0))
        images.append(np.clip(image * 255 / aligned_module._white(image) + 0.5, 0, 255).astype(np.uint8))
    return images


def stride() -> None:
    """The DIS patch stride of the aligned mean's flows at 3 (the medium preset's), 4 (shipped) and 5: milliseconds a
    flow at 200x125 on one thread (best of five rounds) and the mean error against the known 1 px shift of a panned
    noisy texture; then the shipped weights' scores on the development sequences with each."""
    import time

    cv2.setNumThreads(1)
    images, strides = _flow_images(), (3, 4, 5)
    for value in strides:
        dis = aligned_module.AlignedBox(aligned_module.AlignedBoxConfig(patch_stride=value))._dis()
        best = np.inf
        for _ in range(5):
            began = time.perf_counter()
            flows = [dis.calc(a, b, None) for a, b in zip(images[:-1], images[1:])]
            best = min(best, (time.perf_counter() - began) / len(flows))
        error = np.mean([np.abs(f[..., 0] + 1).mean() for f in flows])
        print(f"stride {value}: {1e3 * best:.2f} ms a flow, error {error:.3f} px")
    original = aligned_module.AlignedBoxConfig.for_frames
    rows: dict[str, list[float]] = {}
    for seq in development():
        rows[seq.name] = []
        for value in strides:
            aligned_module.AlignedBoxConfig.for_frames = classmethod(
                lambda cls, n, k=0, v=value: replace(original(n, k), patch_stride=v))
            rows[seq.name].append(score(run(seq)[0], seq))
    aligned_module.AlignedBoxConfig.for_frames = original
    table(rows, [f"stride {v}" for v in strides])


def warps() -> None:
    """The shipped weights with the aligned mean's neighbours warped bilinear (shipped) or bicubic (clipped to [0, 1];
    the flows' own compositions stay bilinear)."""
    real = aligned_module.cv2

    class Bicubic:
        def __getattr__(self, name):
            return getattr(real, name)

        @staticmethod
        def remap(src, map_x, map_y, interpolation, **kw):
            if src.ndim == 2 and interpolation == real.INTER_LINEAR:
                return np.clip(real.remap(src, map_x, map_y, real.INTER_CUBIC, **kw), 0.0, 1.0)
            return real.remap(src, map_x, map_y, interpolation, **kw)

    rows: dict[str, list[float]] = {}
    for seq in development():
        rows[seq.name] = [score(run(seq)[0], seq)]
        aligned_module.cv2 = Bicubic()
        rows[seq.name].append(score(run(seq)[0], seq))
        aligned_module.cv2 = real
    table(rows, ["bilinear (shipped)", "bicubic"])


def profile() -> None:
    """Where a frame's time goes: the engine (binned, one thread, bf16) on 40 frames of random spikes at 200x125 under
    torch.profiler (each operation's share of the profiled time) and, for the aligned mean, cProfile (its OpenCV
    calls and merges by total time)."""
    import cProfile
    import pstats

    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    from rmbvideo.bench.memory import write_random_capture
    from rmbvideo.recon.run import run_reconstruction

    with tempfile.TemporaryDirectory() as folder:
        path = write_random_capture(Path(folder) / "c.dat", 20 * 40, 400, 250)
        options = dict(device="cpu", precision="bf16", threads=1)
        kwargs = dict(fmt="null", capture=dict(width=400, height=250), extra_options=options, overwrite=True,
                      resolution="binned")
        run_reconstruction(path, Path(folder) / "warm", duration_s=0.02, **kwargs)
        with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
            summary = run_reconstruction(path, Path(folder) / "a", **kwargs)
        print(f"{summary.frames} frames;", {k: round(1e3 * v / summary.frames, 2) for k, v in summary.stages.items()})
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=15, max_name_column_width=40))
        profiler = cProfile.Profile()
        profiler.enable()
        run_reconstruction(path, Path(folder) / "b", **kwargs)
        profiler.disable()
        pstats.Stats(profiler).sort_stats("tottime").print_stats(r"remap|calc|aligned_box|boxFilter|partition", 12)


if __name__ == "__main__":
    command = sys.argv[1] if len(sys.argv) > 1 else "bands"
    {"bands": bands, "bias": bias, "gates": gates, "window": window, "prime": prime, "radius": radius,
     "flip": flip, "models": models, "sharpen": sharpen,
     "learned-gate": learned_gate, "flow": flow, "car": car, "cost": cost, "picture": picture,
     "edges": edges, "edge-models": edge_models, "stride": stride, "warps": warps, "profile": profile}[command](*sys.argv[2:])
