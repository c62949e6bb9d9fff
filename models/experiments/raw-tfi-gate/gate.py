"""What the raw capture's TFI could add to the default as one more blend candidate, measured before any training: a
small per-pixel gate mixes the default's frame with TFI on the raw 1-bit capture (2x2-averaged, read as light as the
evaluation reads it), fitted on development sequences only and scored once on the held-out set (both pixels). The
gate sees only a few per-pixel features of the two images, less than the network's head would, so its gain is a
figure for deciding whether to build and train the candidate, never a model to ship. Run from the repository root
(about 15 minutes on one core once the held-out caches exist):

    python models/experiments/raw-tfi-gate/gate.py [SEEDS]          # a gate fitted on development data (a figure only)
    python models/experiments/raw-tfi-gate/gate.py fitted PATH development|heldout   # a gate file (``rmbvideo
                                                                    # train-raw-gate``, training seeds) scored
    python models/experiments/raw-tfi-gate/gate.py real PATH ../shared/data/spikezoo-base   # the same on real video
    python models/experiments/raw-tfi-gate/gate.py car ../shared/data/real/car.dat   # grain on a smooth surface
    python models/experiments/raw-tfi-gate/gate.py cost           # what the gate costs a frame, one thread
    python models/experiments/raw-tfi-gate/gate.py picture        # models/figures/raw-gate.png: where it mixes
    python models/experiments/raw-tfi-gate/gate.py edges [PATH]   # the clips' first and last frames, with and without
    python models/experiments/raw-tfi-gate/gate.py mixes ../shared/data/spikezoo-base   # the best constant mixes of the
                                                                    # binned default and TFI-M per stream (an oracle)
"""

import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

from rmbvideo.evaluate.harness import RAW_SPECS, SATURATION, run_method, score_frames, sequence_convention, table2_specs
from rmbvideo.evaluate.heldout import (DEVELOPMENT_RANDOM_OFFSET, DEVELOPMENT_VIDEO_FIRST, FULL, load_development, load_heldout,
                                       load_heldout_config, load_video_heldout)
from rmbvideo.evaluate.metrics import robust_scale

FEATURES = ("default level", "TFI level", "log ratio", "TFI roughness", "default roughness", "default change",
            "rate convention")
PIXELS_PER_FRAME = 2000


def _roughness(image: np.ndarray) -> np.ndarray:
    """Local 3x3 standard deviation over the local mean (log), the texture or noise around a pixel."""
    mean = cv2.blur(image, (3, 3))
    spread = np.sqrt(np.maximum(cv2.blur(image * image, (3, 3)) - mean * mean, 0.0))
    return np.log((spread + 1e-4) / (mean + 1e-3))


def pairs(seq) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per scored frame of ``seq``: the default's image, raw TFI's image and their per-pixel ``FEATURES``."""
    specs = {s.name: s for s in [*table2_specs(Path("models")), *RAW_SPECS]}
    default, tfi = run_method(specs["RMB-Net"], seq).frames, run_method(specs["TFI (raw)"], seq).frames
    rate = float(sequence_convention(seq) != "physical")
    out = {}
    for i in sorted(default):
        d, t = default[i].astype(np.float32), tfi[i].astype(np.float32)
        before = default.get(i - 1, d).astype(np.float32)
        features = np.stack([np.log(d + 1e-4), np.log(t + 1e-4), np.log((t + 1e-3) / (d + 1e-3)), _roughness(t),
                             _roughness(d), np.log(np.abs(d - before) / (d + 1e-3) + 1e-3), np.full_like(d, rate)])
        out[i] = (d, t, features.astype(np.float32))
    return out


def _tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(image, np.float32))[None, None]


def apply_gate(gate, frames: list, code: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The gate's mixed frames and its total TFI share per frame (``rmbvideo.train.raw_gate.GateFrame``s in order),
    each with the binned frame before it (the frame itself at the start), as ``reconstruct`` mixes them."""
    from rmbvideo.net.raw_gate import gate_features

    mixed, shares, previous = [], [], frames[0].binned
    with torch.no_grad():
        for frame in frames:
            x = [_tensor(frame.binned), _tensor(frame.tfi), _tensor(previous), code,
                 *(_tensor(v) for v in frame.candidates[1:])]
            mixed.append(gate(*x)[0, 0].numpy())
            shares.append(gate.share(gate_features(*x, frame=gate.config.frame_features))[0].sum(0).numpy())
            previous = frame.binned
    return mixed, shares


def development() -> list:
    """Every development sequence: 16 random scenes and the video kinds with the paper's pixel, and the set again
    with a pixel reset by subtraction (never the held-out seeds)."""
    randoms = load_heldout_config(replace(FULL, count=16, first_seed_offset=DEVELOPMENT_RANDOM_OFFSET))
    return randoms + load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST) + load_development(reset="subtract")


def main(seeds: int = 3) -> None:
    torch.set_num_threads(1)
    fit = development()
    test = {reset: load_heldout(False, reset=reset) + load_video_heldout(False, reset=reset)
            for reset in ("zero", "subtract")}
    data = {(seq.name, seq.description): pairs(seq) for seq in [*fit, *test["zero"], *test["subtract"]]}
    rng = np.random.default_rng(0)
    feats, defaults, tfis, truths = [], [], [], []
    for seq in fit:
        for i, (d, t, f) in data[(seq.name, seq.description)].items():
            truth = np.minimum(seq.gt[i], SATURATION)
            scale = robust_scale(truth)
            pick = rng.integers(0, d.size, PIXELS_PER_FRAME)
            feats.append(f.reshape(len(FEATURES), -1)[:, pick].T)
            defaults.append((d / scale).ravel()[pick]), tfis.append((t / scale).ravel()[pick])
            truths.append((truth / scale).ravel()[pick])
    feats, defaults, tfis, truths = (torch.from_numpy(np.concatenate(x).astype(np.float32))
                                     for x in (feats, defaults, tfis, truths))
    mean, std = feats.mean(0), feats.std(0) + 1e-6
    tone = lambda x: torch.log1p(5000 * x.clamp(0, 1)) / np.log1p(5000)  # noqa: E731
    rows: dict[str, list[float]] = {}
    gated: dict[str, list[float]] = {}
    for reset, sequences in test.items():
        for seq in sequences:
            key = f"{seq.name} ({reset})"
            frames = data[(seq.name, seq.description)]
            rows[key] = [score_frames({i: v[0] for i, v in frames.items()}, seq)[0],
                         score_frames({i: v[1] for i, v in frames.items()}, seq)[0]]
            gated[key] = []
    for seed in range(seeds):
        torch.manual_seed(seed)
        gate = torch.nn.Sequential(torch.nn.Linear(len(FEATURES), 16), torch.nn.ReLU(), torch.nn.Linear(16, 1))
        with torch.no_grad():
            gate[-1].bias.fill_(-3.0)  # start from the default alone
        optimiser = torch.optim.Adam(gate.parameters(), lr=3e-3)
        for _ in range(2000):
            share = torch.sigmoid(gate((feats - mean) / std))[:, 0]
            loss = ((tone(share * tfis + (1 - share) * defaults) - tone(truths)) ** 2).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        with torch.no_grad():
            for reset, sequences in test.items():
                for seq in sequences:
                    images = {}
                    for i, (d, t, f) in data[(seq.name, seq.description)].items():
                        x = (torch.from_numpy(f.reshape(len(FEATURES), -1).T) - mean) / std
                        share = torch.sigmoid(gate(x))[:, 0].numpy().reshape(d.shape)
                        images[i] = share * t + (1 - share) * d
                    gated[f"{seq.name} ({reset})"].append(score_frames(images, seq)[0])
        gains = [gated[k][-1] - rows[k][0] for k in rows]
        print(f"initialisation {seed}: mean gain {np.mean(gains):+.2f} dB, least {min(gains):+.2f}", flush=True)
    print("| sequence | default | TFI (raw) | gated | gain |")
    print("|---|---:|---:|---:|---:|")
    for key, (d, t) in rows.items():
        g = float(np.mean(gated[key]))
        print(f"| {key} | {d:.2f} | {t:.2f} | {g:.2f} | {g - d:+.2f} |")
    for reset in test:
        keys = [k for k in rows if k.endswith(f"({reset})")]
        d = np.mean([rows[k][0] for k in keys])
        g = np.mean([np.mean(gated[k]) for k in keys])
        print(f"| mean ({reset}) | {d:.2f} | {np.mean([rows[k][1] for k in keys]):.2f} | {g:.2f} | {g - d:+.2f} |")


def fitted(path: str, which: str) -> None:
    """A gate file scored on the development sequences (both pixels) or the held-out set (both pixels), as
    ``reconstruct`` mixes the frames: RMB-Net's binned frame, the gated one, and raw TFI. A display-referred sequence
    (spikezoo's streams) gets a second row, "linear": linear PSNR after a least-squares gain, as real video is
    scored (mean over the scored frames, each divided by its truth's robust scale)."""
    from rmbvideo.evaluate.real_video import scaled_psnr
    from rmbvideo.net.weights import default_model_path, load_raw_gate
    from rmbvideo.train.raw_gate import display_referred, gate_frames

    torch.set_num_threads(1)
    gate = load_raw_gate(path)[0]
    if which == "development":
        sets = {reset: load_development(reset=reset) for reset in ("zero", "subtract")}
    else:
        sets = {reset: load_heldout(False, reset=reset) + load_video_heldout(False, reset=reset)
                for reset in ("zero", "subtract")}
    print("| sequence | default | TFI (raw) | gated | gain |")
    print("|---|---:|---:|---:|---:|")
    means = {}
    for reset, sequences in sets.items():
        rows = []
        for seq in sequences:
            frames = gate_frames(seq, default_model_path("binned"), gate.config)
            triples = [(f.binned, f.tfi, f.truth) for f in frames]
            gated = apply_gate(gate, frames, float(sequence_convention(seq) != "physical"))[0]
            scored = seq.scored_frames
            row = [score_frames({i: triples[i][k] for i in scored}, seq)[0] for k in (0, 1)]
            row.append(score_frames({i: gated[i] for i in scored}, seq)[0])
            rows.append(row)
            print(f"| {seq.name} ({reset}) | {row[0]:.2f} | {row[1]:.2f} | {row[2]:.2f} | {row[2] - row[0]:+.2f} |",
                  flush=True)
            if display_referred(seq):
                truths = {i: np.minimum(triples[i][2], SATURATION) for i in scored}
                linear = [np.mean([scaled_psnr(image(i), truths[i] / robust_scale(truths[i])) for i in scored])
                          for image in (lambda i: triples[i][0], lambda i: triples[i][1], lambda i: gated[i])]
                print(f"| {seq.name} ({reset}), linear | {linear[0]:.2f} | {linear[1]:.2f} | {linear[2]:.2f} "
                      f"| {linear[2] - linear[0]:+.2f} |", flush=True)
        means[reset] = np.mean(rows, axis=0)
    for reset, m in means.items():
        print(f"| mean ({reset}) | {m[0]:.2f} | {m[1]:.2f} | {m[2]:.2f} | {m[2] - m[0]:+.2f} |")


def real(path: str, folder: str) -> None:
    """A gate file on real-video streams at the binned size, as the real-video table scores every row: the 1-bit
    capture's default path (RMB-Net on the binned stream, the gate, then 2x2 blocks averaged: the detail keeps every
    block's mean, so it is left out) with and without the gate, linear PSNR after a least-squares gain."""
    from rmbvideo.evaluate.real_video import (CONVENTION, RAW_STEP, binned_reference, find_streams, open_stream,
                                              scaled_psnr)
    from rmbvideo.net.weights import default_model_path, load_raw_gate, model_readout
    from rmbvideo.recon.full_resolution import FullResolution
    from rmbvideo.recon.methods import make_reconstructor
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.sensor.readout import ReadoutMode, RmbReadout

    torch.set_num_threads(1)
    gate = load_raw_gate(path)[0]
    model = default_model_path("binned")
    print("| stream | default (binned) | with the raw gate | gain |")
    print("|---|---:|---:|---:|")
    gains = []
    for stream in find_streams(Path(folder)):
        reference = binned_reference(stream)
        scores = []
        for raw_gate in (None, gate):
            engine = make_reconstructor("rmbnet", model=str(model), input_mode="binned", threads=1,
                                        convention=CONVENTION)
            recon = FullResolution(engine, RmbReadout(mode=ReadoutMode(model_readout(model))), step=RAW_STEP,
                                   threads=1, raw_gate=raw_gate)
            sink = FrameCollector(keep=[stream.frame])
            reconstruct_stream(open_stream(stream), recon, sink)
            image = sink.frames[stream.frame].image
            h, w = reference.shape
            scores.append(scaled_psnr(cv2.resize(image[: 2 * h, : 2 * w], (w, h), interpolation=cv2.INTER_AREA),
                                      reference))
        gains.append(scores[1] - scores[0])
        print(f"| {stream.name} | {scores[0]:.2f} | {scores[1]:.2f} | {scores[1] - scores[0]:+.2f} |", flush=True)
    print(f"| mean gain | | | {np.mean(gains):+.2f} |")


def mixes(folder: str) -> None:
    """How much more a gate could take from TFI-M on real video: per stream, the binned default's frame mixed with
    TFI-4, TFI-8 or TFI-16 (and with TFI-4 and TFI-16 together) by the best constant share in steps of 0.1, each image
    first scaled onto the reference by least squares; an oracle of the validation streams, never a method."""
    from rmbvideo.evaluate.real_video import (RAW_STEP, RealRow, binned_reference, find_streams, real_video_rows,
                                              reconstruct_frame, scaled_psnr)

    torch.set_num_threads(1)
    network = next(row for row in real_video_rows() if row.name == "RMB-Net")
    steps = np.linspace(0.0, 1.0, 11)
    print("| stream | default (binned) | TFI-4: alone / best mix @ share | TFI-8 | TFI-16 | TFI-4 + TFI-16 @ shares |")
    print("|---|---:|---:|---:|---:|---:|")
    for stream in find_streams(Path(folder)):
        reference = binned_reference(stream)
        onto = lambda x: x * float((x * reference).sum() / max(float((x * x).sum()), 1e-12))  # noqa: E731
        binned = onto(reconstruct_frame(stream, network))
        tfi = {m: onto(reconstruct_frame(stream, RealRow(f"TFI-{m}", "tfi", {"step": RAW_STEP, "window": m,
                                                                              "max_reach": 200}, raw=True)))
               for m in (4, 8, 16)}
        cells = [f"{scaled_psnr(binned, reference):.2f}"]
        for image in tfi.values():
            best = max((scaled_psnr((1 - s) * binned + s * image, reference), s) for s in steps)
            cells.append(f"{scaled_psnr(image, reference):.2f} / {best[0]:.2f} @ {best[1]:.1f}")
        both = max((scaled_psnr((1 - a - c) * binned + a * tfi[4] + c * tfi[16], reference), a, c)
                   for a in steps for c in steps if a + c <= 1.0 + 1e-9)
        cells.append(f"{both[0]:.2f} @ {both[1]:.1f}, {both[2]:.1f}")
        print(f"| {stream.name} | " + " | ".join(cells) + " |", flush=True)


def car(path: str, out: str = "models/figures/car-raw-gate.png") -> None:
    """A real camera's capture with and without the shipped gate (no ground truth): the middle frame's fine grain
    (high-pass standard deviation over the level) on the bright, smooth car body, and a zoom of it (top: without)."""
    from rmbvideo.recon.run import reconstruct_frames

    torch.set_num_threads(1)
    frames = [list(reconstruct_frames(path, threads=1, raw_gate=kind)) for kind in ("off", "auto")]
    middle = len(frames[0]) // 2
    plain, gated = (f[middle].image for f in frames)
    scale = float(np.percentile(plain, 99.5))
    body = (slice(100, 150), slice(20, 120))
    for name, image in (("without the gate", plain), ("with the gate", gated)):
        grain = image - cv2.GaussianBlur(image, (0, 0), 2)
        print(f"{name}: car body level {image[body].mean() / scale:.3f} of the 99.5th percentile, "
              f"grain {100 * grain[body].std() / image[body].mean():.2f} %")
    zoom = [cv2.resize((np.clip(im[80:180, 0:200] / scale, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8), (400, 200),
                       interpolation=cv2.INTER_NEAREST) for im in (plain, gated)]
    cv2.imwrite(out, np.vstack(zoom))
    print(f"wrote {out}")


def cost(repeats: int = 5) -> None:
    """The default full-resolution job on a random 400x250 capture of 2,000 planes (100 frames), one thread, with and
    without the gate, alternated; then the gate's parts alone: TFI over 200 planes a side (and over 40, the detail
    stage's) on the same planes, the gate's two TFI searches each scanning every block and sharing one scan
    (``BlockScans``; alternated), and the gate on 100 binned frames."""
    import tempfile
    import time

    from rmbvideo.chunks import SpikeChunk
    from rmbvideo.io.dat import DatGeometry, write_dat
    from rmbvideo.net.weights import default_raw_gate_path, load_raw_gate
    from rmbvideo.recon.classical import BlockScans, Tfi, push_by_block
    from rmbvideo.recon.run import reconstruct_frames

    gate_config = load_raw_gate(default_raw_gate_path())[0].config

    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    rate = np.clip(rng.gamma(0.6, 0.15, (250, 400)), 0.0, 0.95)
    planes = (rng.random((2000, 250, 400)) < rate).astype(np.uint8)
    with tempfile.TemporaryDirectory() as folder:
        dat = Path(folder) / "random.dat"
        write_dat(dat, planes, DatGeometry(400, 250))
        seconds: dict[str, list[float]] = {"auto": [], "off": []}
        cpu: dict[str, list[float]] = {"auto": [], "off": []}
        for _ in range(repeats):
            for kind in seconds:
                began, began_cpu = time.perf_counter(), time.process_time()
                count = sum(1 for _ in reconstruct_frames(dat, threads=1, raw_gate=kind))
                seconds[kind].append((time.perf_counter() - began) / count)
                cpu[kind].append((time.process_time() - began_cpu) / count)
    for kind, values in seconds.items():
        print(f"raw gate {kind}: {1000 * min(values):.1f} ms a frame, {1000 * min(cpu[kind]):.1f} ms of CPU (every "
              f"thread; best of {repeats}), {count} frames")
    print(f"ratio: {min(seconds['auto']) / min(seconds['off']):.3f} in time, "
          f"{min(cpu['auto']) / min(cpu['off']):.3f} in CPU")
    for reach in (200, 40):
        tfi, began = Tfi(step=20, max_reach=reach), time.perf_counter()
        frames = []
        for start in range(0, len(planes), 128):
            frames += tfi.push(SpikeChunk(planes[start : start + 128], start, 20000.0))
        frames += tfi.flush()
        print(f"TFI, reach {reach}: {1000 * (time.perf_counter() - began) / len(frames):.2f} ms a frame")
    windows = (gate_config.tfi_window, gate_config.long_window)
    for shared in (False, True, False, True):  # alternated: the host's speed drifts
        scans = BlockScans() if shared else None
        searches, began = [Tfi(step=20, max_reach=200, window=w, scans=scans) for w in windows], time.perf_counter()
        count = 0
        for start in range(0, len(planes), 128):
            count += len(push_by_block(searches, SpikeChunk(planes[start : start + 128], start, 20000.0))[0])
            if scans is not None:
                scans.clear()
        for search in searches[1:]:
            search.flush()
        count += len(searches[0].flush())
        how = "one scan of each block" if shared else "each its own scan"
        print(f"the gate's TFI-{windows[0]} and TFI-{windows[1]}, {how}: "
              f"{1000 * (time.perf_counter() - began) / count:.2f} ms a frame")
    gate = load_raw_gate(default_raw_gate_path())[0]
    binned = torch.rand(100, 1, 125, 200) * 0.5
    with torch.inference_mode():
        began = time.perf_counter()
        for k in range(100):
            gate(binned[k : k + 1], binned[k : k + 1] * 1.1, binned[k - 1 : k] if k else binned[:1], 0.0,
                 *([binned[k : k + 1] * 1.2] if gate.config.long_window else []))
    print(f"gate alone: {10 * (time.perf_counter() - began):.2f} ms a frame")


def picture(out: str = "models/figures/raw-gate.png") -> None:
    """The middle frame of two held-out sequences (a bright pan, a dark clip): truth, RMB-Net's binned frame, raw TFI,
    the gate's share of TFI (black 0, white 1) and the mixed frame, each tone-mapped as the evaluation's pictures
    (mu-law of the frame over the truth's robust scale)."""
    from rmbvideo.mulaw import mu_law as curve
    from rmbvideo.net.weights import default_model_path, default_raw_gate_path, load_raw_gate
    from rmbvideo.train.raw_gate import gate_frames

    torch.set_num_threads(1)
    gate = load_raw_gate(default_raw_gate_path())[0]
    sequences = [s for s in load_heldout(False) + load_video_heldout(False)
                 if s.name in ("random-1000002", "dark-100")]
    rows = []
    for seq in sequences:
        frames = gate_frames(seq, default_model_path("binned"), gate.config)
        i = len(frames) // 2
        binned, tfi, truth = frames[i].binned, frames[i].tfi, frames[i].truth
        mixed, share = (x[-1] for x in apply_gate(gate, frames[i - 1:i + 1], float(sequence_convention(seq) != "physical")))
        scale = robust_scale(truth)
        tone = lambda im: (255 * np.clip(curve(np.clip(im / scale, 0, 1), 5000.0), 0, 1)).astype(np.uint8)  # noqa: E731
        tiles = [tone(truth), tone(binned), tone(tfi), (255 * share).astype(np.uint8), tone(mixed)]
        rows.append(np.hstack(tiles))
        print(f"{seq.name} frame {i}: mean share {share.mean():.3f}, above a half on {100 * (share > 0.5).mean():.1f} %")
    cv2.imwrite(out, cv2.resize(np.vstack(rows), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST))
    print(f"wrote {out} (columns: truth, RMB-Net binned, raw TFI, the gate's share of TFI, mixed)")


def edges(path: str | None = None) -> None:
    """The held-out video clips' first, median and last frames (mu-law PSNR, every frame scored as ``evaluate``'s
    checks do) of RMB-Net's binned frames and of the gated ones: the gate at a clip's edge, where the binned frame's
    change since the last is zero (the first frame is its own previous); then the moment each edge frame shows
    (``evaluate``'s offset search), binned and gated; then the edge's own cost as ``evaluate``'s checks measure it:
    the middle frame made mid-clip against the same frame made as a clip's first (the streams cut to start there)
    and as its last, binned and gated."""
    from rmbvideo.evaluate.metrics import mu_law_psnr
    from rmbvideo.evaluate.video_checks import FRAME_STEP, best_time_offset_ms, clip_frames, video_scene_of
    from rmbvideo.net.weights import default_model_path, default_raw_gate_path, load_raw_gate
    from rmbvideo.train.raw_gate import gate_frames

    torch.set_num_threads(1)
    gate = load_raw_gate(path or default_raw_gate_path())[0]
    print("| clip | first: binned / gated | median frame: binned / gated | last: binned / gated "
          "| offset ms first: binned / gated | last | middle | edge cost as first: binned / gated | as last |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for seq in load_video_heldout(False):
        frames = gate_frames(seq, default_model_path("binned"), gate.config)
        gated = apply_gate(gate, frames, float(sequence_convention(seq) != "physical"))[0]
        scores = [(mu_law_psnr(f.binned, f.truth), mu_law_psnr(g, f.truth)) for f, g in zip(frames, gated)]
        median = np.median(np.array(scores), axis=0)
        cells = [f"{a:.2f} / {b:.2f}" for a, b in (scores[0], median, scores[-1])]
        scene, count = video_scene_of(seq), len(frames)
        for i in (0, count - 1, count // 2):  # evaluate's edge_report: frame i's centre is raw plane 2 step i + step
            plane = 2 * FRAME_STEP * i + FRAME_STEP
            cells.append(" / ".join(f"{best_time_offset_ms(image, scene, plane):+.2f}"
                                    for image in (frames[i].binned, gated[i])))
        mid, truth = count // 2, frames[count // 2].truth
        for clip, k in ((clip_frames(seq, mid, count), 0), (clip_frames(seq, 0, mid + 1), mid)):
            cut = gate_frames(clip, default_model_path("binned"), gate.config)
            cut_gated = apply_gate(gate, cut, float(sequence_convention(seq) != "physical"))[0]
            cells.append(" / ".join(f"{whole - mu_law_psnr(image, truth):.2f}" for whole, image in
                                    zip(scores[mid], (cut[k].binned, cut_gated[k]))))
        print(f"| {seq.name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "fitted":
        fitted(sys.argv[2], sys.argv[3])
    elif len(sys.argv) > 1 and sys.argv[1] == "edges":
        edges(sys.argv[2] if len(sys.argv) > 2 else None)
    elif len(sys.argv) > 1 and sys.argv[1] == "picture":
        picture()
    elif len(sys.argv) > 1 and sys.argv[1] == "cost":
        cost()
    elif len(sys.argv) > 1 and sys.argv[1] == "car":
        car(sys.argv[2])
    elif len(sys.argv) > 1 and sys.argv[1] == "mixes":
        mixes(sys.argv[2])
    elif len(sys.argv) > 1 and sys.argv[1] == "real":
        real(sys.argv[2], sys.argv[3])
    else:
        main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
