"""Why does the gate still trail the best classical method on the real-video streams? On the frames cached by
``frame_features.py cache``: how each candidate scores per capture (``candidates``); where on a frame RMB-Net's
binned frame loses to TFI and what share the gate gives each candidate there (``regions``); display-referred
captures made to look like REDS (natural panoramas, dense texture, slow to moderate motion), cached alike
(``reds-like``); the cache with its long candidate replaced by TFI-W (``window``); and gate variants fitted at
``frame_features.PIXELS`` a frame and scored on the development set and the real streams (``variant``: other
windows, none, or the recipe's other loss). Run from the repository root, one thread:

    python models/experiments/raw-tfi-gate/real_gap.py candidates DIR            # seconds
    python models/experiments/raw-tfi-gate/real_gap.py regions DIR GATE          # seconds
    python models/experiments/raw-tfi-gate/real_gap.py shares DIR GATE           # about a minute
    python models/experiments/raw-tfi-gate/real_gap.py reds-like DIR             # ~5 min (24 captures)
    python models/experiments/raw-tfi-gate/real_gap.py window DIR OUT W STREAMS  # ~5 min (train, development, real)
    python models/experiments/raw-tfi-gate/real_gap.py variant DIR SHORT LONG SEED [LOSS]   # ~10 min (LONG 0: none)

and where each method's frame sits in time: the moment a real stream's reference shows (``moment``: TFP over a few
planes slid plane by plane), the reference frames and simulated scenes' frames replayed as noise-free rigid pans in
spikezoo's convention and scored as the real streams are (``replay``), the streams read from their second plane, so
that frame ``plane // 20`` is made at the reference's moment (``shift``), and the cache with TFI-4 and TFI-16 centred
on the frame time and the real streams' binned frames made at the reference's moment (``centred``):

    python models/experiments/raw-tfi-gate/real_gap.py moment STREAMS                 # seconds
    python models/experiments/raw-tfi-gate/real_gap.py replay OUT SPEEDS [0.5]        # ~1 min a replay
    python models/experiments/raw-tfi-gate/real_gap.py shift STREAMS OUT              # seconds
    python models/experiments/raw-tfi-gate/real_gap.py centred DIR OUT SHIFTED        # ~8 min

and whether the real streams are sharp only every few planes, as a stream rendered from sharp frames with
interpolated ones between would be (``sharpness``: the detail of a few planes' rate over time):

    python models/experiments/raw-tfi-gate/real_gap.py sharpness STREAMS [WINDOW]     # seconds
"""

import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

import frame_features as ff
import rmbvideo.train.raw_gate as recipe_module
from rmbvideo.evaluate.harness import MethodSpec, run_frames
from rmbvideo.evaluate.heldout import FULL, VideoHeldout, load_development, simulate_video_sequence
from rmbvideo.evaluate.real_video import scaled_psnr
from rmbvideo.net.raw_gate import RawGateConfig, gate_features
from rmbvideo.net.weights import default_model_path, load_raw_gate
from rmbvideo.scenes.video import VideoSceneRanges
from rmbvideo.train.raw_gate import GateFrame, RawGateRecipe, gate_frames, training_sequences

#: REDS-like display-referred scenes (training seeds 750,000, 760,000, 771,000 and 772,000 on): moving, mostly still,
#: and rigid pans at 0.15 raw px a plane, of any brightness and bright.
REDS_LIKE = {
    "reds": (750_000, VideoSceneRanges(camera_speed=(0.05, 0.4), static_probability=0.0, object_speed=(0.05, 0.6),
                                       panorama_probability=0.7, median_rate=(0.1, 0.5), light_probability=0.0,
                                       coverage=(6.0, 12.0))),
    "redsstill": (760_000, VideoSceneRanges(camera_speed=(0.02, 0.2), static_probability=0.3,
                                            object_speed=(0.05, 0.4), max_objects=3, panorama_probability=1.0,
                                            median_rate=(0.1, 0.5), light_probability=0.0)),
    # rigid pans at the real streams' speed (DIS flow 0.12-0.19 raw px a plane, ``slow_display.py speeds``), and as
    # bright as they are (0.18-0.35 spikes a plane on average), without lights
    "pan": (771_000, VideoSceneRanges(pan_probability=1.0, pan_speed=(0.14, 0.16))),
    "brightpan": (772_000, VideoSceneRanges(pan_probability=1.0, pan_speed=(0.14, 0.16), median_rate=(0.15, 0.4),
                                            light_probability=0.0)),
}
#: A pixel is still where TFI-16 and TFI-4 agree within 3 %, flat where the truth's 3x3 gradient is below its median.
STILL_LOG_RATIO = 0.03


def _disagreement(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean(np.abs(np.log((a + 1e-3) / (b + 1e-3)))))


def candidates(folder: str) -> None:
    """Per cached capture: the mean linear PSNR (least-squares gain, as the real streams are scored) of RMB-Net's
    binned frame, TFI-4 and TFI-16, and the frame features (mean |log TFI-4/binned|, |log TFI-16/TFI-4|)."""
    print("| capture | binned | TFI-4 | TFI-16 | TFI-4/binned | TFI-16/TFI-4 |\n|---|---:|---:|---:|---:|---:|")
    paths = [p for pattern in ("train-*", "reds-like-*", "real-*") for p in sorted(Path(folder).glob(pattern + ".npz"))]
    for path in paths:
        d = dict(np.load(path))
        truth = d["truth"] if "truth" in d else d["reference"][None]
        images = [d[k] if d[k].ndim == 3 else d[k][None] for k in ("binned", "tfi", "long")]
        psnr = [np.mean([scaled_psnr(x[i], truth[i]) for i in range(len(truth))]) for x in images]
        print(f"| {path.stem} | {psnr[0]:.2f} | {psnr[1]:.2f} | {psnr[2]:.2f} | "
              f"{_disagreement(images[1], images[0]):.3f} | {_disagreement(images[2], images[1]):.3f} |")


def regions(folder: str, gate_path: str) -> None:
    """Per real stream's reference frame and the middle frame (10) of every display-referred capture: relative MSE
    (x 1e4, after TFI-16's least-squares gain) of binned, TFI-4, TFI-16 and the gate on still flat, still textured
    and moving pixels, with the gate's mean share of each TFI candidate there."""
    gate = load_raw_gate(gate_path)[0].eval()
    t = ff._tensor
    print("| frame | region | pixels | binned | TFI-4 | TFI-16 | gate | share TFI-4 | share TFI-16 |\n"
          "|---|---|---:|---:|---:|---:|---:|---:|---:|")
    rows = [(p, dict(np.load(p))) for p in sorted(Path(folder).glob("real-*.npz"))]
    rows += [(p, dict(np.load(p))) for p in sorted(Path(folder).glob("train-*display*.npz"))]
    rows += [(p, dict(np.load(p))) for p in sorted(Path(folder).glob("reds-like-*.npz"))]
    for path, d in rows:
        if "reference" in d:
            b, t4, t16, prev, truth = d["binned"], d["tfi"], d["long"], d["previous"], d["reference"]
        else:
            b, t4, t16, prev, truth = (d["binned"][10], d["tfi"][10], d["long"][10], d["binned"][9], d["truth"][10])
        with torch.no_grad():
            share = gate.share(gate_features(t(b), t(t4), t(prev), float(d["convention"]), t(t16),
                                             frame=gate.config.frame_features))[0].numpy()
            mixed = gate(t(b), t(t4), t(prev), float(d["convention"]), t(t16))[0, 0].numpy()
        truth = truth.astype(np.float64) / ((t16 * truth).sum() / (t16 * t16).sum())
        f32 = truth.astype(np.float32)
        grad = cv2.blur(np.hypot(cv2.Sobel(f32, cv2.CV_32F, 0, 1), cv2.Sobel(f32, cv2.CV_32F, 1, 0)), (3, 3))
        still, flat = np.abs(np.log((t16 + 1e-3) / (t4 + 1e-3))) < STILL_LOG_RATIO, grad < np.median(grad)
        for name, mask in (("still, flat", still & flat), ("still, textured", still & ~flat), ("moving", ~still)):
            err = [np.mean((x - truth)[mask] ** 2) / np.mean(truth ** 2) * 1e4 for x in (b, t4, t16, mixed)]
            print(f"| {path.stem} | {name} | {mask.mean():.2f} | " + " | ".join(f"{e:.2f}" for e in err)
                  + f" | {share[0][mask].mean():.2f} | {share[-1][mask].mean() if len(share) > 1 else 0:.3f} |")


def shares(folder: str, gate_path: str) -> None:
    """Per development capture and real stream: the gate's mean share of each TFI candidate and the largest share
    of the last one at any pixel of any frame."""
    gate = load_raw_gate(gate_path)[0].eval()
    t = ff._tensor
    print("| capture | mean share TFI-4 | mean share, last candidate | its largest |\n|---|---:|---:|---:|")
    for path in sorted(Path(folder).glob("development-*.npz")) + sorted(Path(folder).glob("real-*.npz")):
        d = dict(np.load(path))
        if "reference" in d:
            frames = [(d["binned"], d["tfi"], d["long"], d["previous"])]
        else:
            frames = [(d["binned"][i], d["tfi"][i], d["long"][i], d["binned"][max(i - 1, 0)])
                      for i in range(len(d["binned"]))]
        with torch.no_grad():
            share = np.stack([gate.share(gate_features(t(b), t(s), t(p), float(d["convention"]), t(lg),
                                                       frame=gate.config.frame_features))[0].numpy()
                              for b, s, lg, p in frames])
        print(f"| {path.stem} | {share[:, 0].mean():.3f} | {share[:, -1].mean():.4f} | {share[:, -1].max():.4f} |")


def reds_like(folder: str, count: int = 6) -> None:
    """``count`` captures of each ``REDS_LIKE`` kind in spikezoo's convention, cached as ``reds-like-*.npz`` (no gate
    is fitted on them: ``frame_features._cached_recipe`` reads ``train-*``) with their candidates'
    linear PSNRs printed."""
    out = Path(folder)
    for name, (first, ranges) in REDS_LIKE.items():
        for j in range(count):
            seq = simulate_video_sequence(first + j, VideoHeldout(name, ranges, "spikezoo"), replace(FULL, reset="zero"),
                                          training=True)
            frames = gate_frames(seq, default_model_path("binned"), ff.WINDOWS)
            ff._save(out / f"reds-like-{seq.name}.npz", seq, frames)
            psnr = [np.mean([scaled_psnr(getattr(f, a), f.truth) for f in frames]) for a in ("binned", "tfi", "long_tfi")]
            print(f"{seq.name}: binned {psnr[0]:.2f}, TFI-4 {psnr[1]:.2f}, TFI-16 {psnr[2]:.2f}", flush=True)


def _cached_captures():  # noqa: ANN202
    """The training and development captures, each with its file name in the cache (``frame_features.cache``)."""
    for k, seq in enumerate(training_sequences(RawGateRecipe())):
        yield seq, f"train-{k:02d}-{seq.name}.npz"
    for reset in ("zero", "subtract"):
        for seq in load_development(reset=reset):
            yield seq, f"development-{reset}-{seq.name}.npz"


def _tfi(seq, window: int) -> dict[int, np.ndarray]:  # noqa: ANN001
    spec = MethodSpec("TFI (raw)", "tfi", {"step": 20, "max_reach": 200, "window": window}, raw=True)
    return {f.index: f.image for f in run_frames(spec, seq)[0]}


def window(folder: str, out: str, w: int, streams: str) -> None:
    """Copy the training, development and real-stream frames of ``folder`` into ``out`` with the long candidate
    replaced by TFI-``w`` (checking that TFI-4 made again equals the cached one)."""
    from rmbvideo.evaluate.real_video import RealRow, find_streams, reconstruct_frame

    src, dst = Path(folder), Path(out)
    dst.mkdir(parents=True, exist_ok=True)

    def redo(seq, path: Path) -> None:  # noqa: ANN001
        d = dict(np.load(path))
        short, long = _tfi(seq, 4), _tfi(seq, w)
        index = sorted(short)
        if len(index) != len(d["tfi"]) or not np.allclose(np.stack([short[i] for i in index]), d["tfi"], atol=1e-6):
            raise RuntimeError(f"{path}: TFI-4 made again differs from the cache")
        d["long"] = np.stack([long[i] for i in index]).astype(np.float32)
        np.savez(dst / path.name, **d)

    for seq, name in _cached_captures():
        redo(seq, src / name)
    for stream in find_streams(Path(streams)):
        path = src / f"real-{stream.name}.npz"
        d = dict(np.load(path))
        short = reconstruct_frame(stream, RealRow("TFI-4", "tfi", {"step": 20, "window": 4}, raw=True))
        if not np.allclose(short, d["tfi"], atol=1e-6):
            raise RuntimeError(f"{path}: TFI-4 made again differs from the cache")
        d["long"] = reconstruct_frame(stream, RealRow(f"TFI-{w}", "tfi", {"step": 20, "window": w}, raw=True))
        np.savez(dst / path.name, **d)


def variant(folder: str, short: int, long: int, seed: int, loss: str = "mu-law") -> None:
    """A gate reading TFI-``short`` and the cache's long candidate (``long``: its window, 0 for none), frame features
    on, fitted by the recipe's ``fit_gate`` with ``loss`` at ``frame_features.PIXELS`` a frame, scored on the
    development set (mean gain per pixel kind) and on the real streams."""
    ff._cached_recipe(Path(folder))
    if not long:  # the cached long candidate left out
        cached = recipe_module.gate_frames
        recipe_module.gate_frames = lambda *a, **k: [GateFrame(f.binned, f.tfi, f.truth) for f in cached(*a, **k)]
    config = RawGateConfig(tfi_window=short, long_window=long, frame_features=True)
    recipe = RawGateRecipe(gate=config, pixels=ff.PIXELS, seed=seed, loss=loss, **ff.ONE_FIT)
    gate = recipe_module.fit_gate(recipe_module.gather_samples(recipe, default_model_path("binned")), recipe)[0]
    gate.eval()
    if not long:  # scored through a gate that is handed no long candidate
        forward = gate.forward
        gate.forward = lambda binned, tfi, previous, convention, long_tfi=None: forward(binned, tfi, previous,
                                                                                        convention)
    dev, real = ff.score(folder, gate, "development", quiet=True), ff.score(folder, gate, "real", quiet=True)
    streams = " / ".join(f"{v:.2f}" for k, v in real.items() if k != "mean")
    print(f"| TFI-{short}{f' + TFI-{long}' if long else ''}, {loss} ({seed}) | {dev['zero']:+.2f} / "
          f"{dev['subtract']:+.2f} | {streams} | {real['mean']:.2f} |", flush=True)


def moment(streams: str, windows: tuple[int, ...] = (6, 10)) -> None:
    """Per real stream: PSNR of TFP over ``windows`` planes slid plane by plane around the reference plane, and the
    vertex of a parabola through the best window position and its neighbours, as a time in planes (plane k spans
    [k, k+1); frame ``plane // 20`` is made at ``20 * (plane // 20) + 10``)."""
    from rmbvideo.evaluate.real_video import binned_reference, find_streams
    from rmbvideo.io.dat import DatReader

    for stream in find_streams(Path(streams)):
        planes = np.concatenate([c.planes for c in DatReader(stream.capture, stream.geometry).chunks(1000)])
        reference = binned_reference(stream)
        h, w = reference.shape
        for window in windows:
            starts = range(stream.plane - 10, stream.plane + 6)
            psnr = np.array([scaled_psnr(planes[a : a + window].reshape(window, h, 2, w, 2).mean((0, 2, 4)),
                                         reference) for a in starts])
            k = int(np.clip(np.argmax(psnr), 1, len(psnr) - 2))
            left, mid, right = psnr[k - 1 : k + 2]
            vertex = starts[k] + window / 2 + 0.5 * (left - right) / (left - 2 * mid + right)
            print(f"{stream.name} TFP-{window}: best at time {starts[int(np.argmax(psnr))] + window / 2:.1f}, "
                  f"vertex {vertex:.2f} (the frame's time {20 * (stream.plane // 20) + 10})")


def sharpness(streams: str, window: int = 8) -> None:
    """Per stream: the fine detail of TFP over ``window`` planes slid plane by plane (variance of the Laplacian of the
    rate, Gaussian-smoothed by 1 px), detrended by a 21-plane mean; its strongest period, the times of its local
    maxima, and where the reference's moment falls on the detail folded at that period (0: at a peak, 0.5: halfway
    between). A stream rendered from sharp frames with interpolated ones between peaks at every sharp frame."""
    from rmbvideo.evaluate.real_video import find_streams
    from rmbvideo.io.dat import DatReader

    print("| stream | period (planes) | modulation | reference's moment: phase | local maxima |\n|---|---:|---:|---:|---|")
    for stream in find_streams(Path(streams)):
        planes = DatReader(stream.capture, stream.geometry).read().astype(np.float32)
        sums = np.concatenate([np.zeros((1, *planes.shape[1:]), np.float32), np.cumsum(planes, axis=0)])
        detail = np.array([cv2.Laplacian(cv2.GaussianBlur((sums[a + window] - sums[a]) / window, (0, 0), 1.0),
                                         cv2.CV_32F).var() for a in range(len(planes) - window + 1)])
        times = np.arange(len(detail)) + window / 2
        varying = (detail - np.convolve(detail, np.ones(21) / 21, mode="same"))[10:-10]
        times, spectrum = times[10:-10], np.abs(np.fft.rfft(varying))
        period = 1.0 / np.fft.rfftfreq(len(varying))[1 + int(np.argmax(spectrum[1:]))]
        folded = np.exp(2j * np.pi * times / period) @ varying  # the period's phasor: its peak's phase
        phase = ((stream.moment - np.angle(folded) * period / (2 * np.pi)) / period + 0.5) % 1.0 - 0.5
        maxima = [f"{times[i]:.0f}" for i in range(7, len(varying) - 7) if varying[i] == varying[i - 7 : i + 8].max()]
        print(f"| {stream.name} | {period:.1f} | {2 * abs(folded) / len(varying) / detail.mean():.3f} | "
              f"{phase:+.2f} | {', '.join(maxima)} |", flush=True)


def _replay_images() -> dict[str, np.ndarray]:
    """The real streams' reference frames and two simulated display-referred scenes' frames (plane 150), in [0, 1]."""
    from rmbvideo.evaluate.real_video import find_streams
    from rmbvideo.scenes.video import VideoScene
    from rmbvideo.train.raw_gate import VIDEO_DISPLAY

    images = {s.name.split("_key")[0]: cv2.imread(str(s.reference), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255
              for s in find_streams(Path("../shared/data/spikezoo-base"))}
    for name, seed, ranges in (("video-display", 740_001, VIDEO_DISPLAY.ranges), ("reds", 750_001, REDS_LIKE["reds"][1])):
        image = VideoScene(seed, 400, 250, 400, ranges, "spikezoo").render(150)
        images[f"{name}-{seed}"] = np.clip(image / np.quantile(image, 0.995), 0, 1).astype(np.float32)
    return images


def replay(out: str, speeds: str, half: float = 0.0, mean_rate: float = 0.208) -> None:
    """Each ``_replay_images`` frame as a 301-plane noise-free stream in spikezoo's convention (mean rate
    ``mean_rate``: 203_part2's), the frame translated rigidly at each of ``speeds`` raw px a plane (x; 0.3 of it in
    y) so that plane k shows it at time k + ``half`` - 150 (0.5: the simulator's plane midpoints), written as a
    ``.dat`` + PNG pair and scored as the real streams are (RMB-Net, TFI-4, TFI-16)."""
    from rmbvideo.evaluate.real_video import find_streams, real_video_rows, score_stream
    from rmbvideo.io.dat import DatGeometry, write_dat

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    rows = [r for r in real_video_rows() if r.name in ("RMB-Net", "TFI-4 (raw, 2x2-avg)", "TFI-16 (raw, 2x2-avg)")]
    rng = np.random.default_rng(0)
    print("| frame | speed | RMB-Net | TFI-4 | TFI-16 |\n|---|---:|---:|---:|---:|")
    for (name, image), speed in [(item, float(v)) for item in _replay_images().items() for v in speeds.split(",")]:
        charge, planes = rng.random(image.shape), np.zeros((301, *image.shape), np.uint8)
        for k in range(len(planes)):
            dx = speed * (k + half - 150)
            moved = cv2.warpAffine(image, np.float32([[1, 0, dx], [0, 1, 0.3 * dx]]), image.shape[::-1],
                                   flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            charge += np.clip(moved * (mean_rate / image.mean()), 0, 1)
            planes[k] = charge >= 1
            charge -= planes[k]
        stem = f"{name}-{speed}-{half}_key_id151"
        write_dat(folder / f"{stem}.dat", planes, DatGeometry(400, 250))
        cv2.imwrite(str(folder / f"{stem}.png"), np.clip(image * 255 + 0.5, 0, 255).astype(np.uint8))
        scores = score_stream(next(s for s in find_streams(folder) if s.name == stem), rows)
        print(f"| {name} | {speed} | " + " | ".join(f"{scores[r.name].psnr:.2f}" for r in rows) + " |", flush=True)


def shift(streams: str, out: str, planes: int = 1) -> None:
    """Each real stream without its first ``planes`` planes, beside its reference (the same name and ``key_id``):
    frame ``plane // 20`` is then made ``planes`` planes later in the original stream."""
    import shutil

    from rmbvideo.evaluate.real_video import find_streams
    from rmbvideo.io.dat import DatReader, write_dat

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    for stream in find_streams(Path(streams)):
        data = np.concatenate([c.planes for c in DatReader(stream.capture, stream.geometry).chunks(1000)])
        write_dat(folder / stream.capture.name, data[planes:], stream.geometry)
        shutil.copy(stream.reference, folder / stream.reference.name)


def _centred_tfi(seq, window: int) -> dict[int, np.ndarray]:  # noqa: ANN001
    """TFI-``window`` of ``seq``'s frames (light, 2x2-averaged) with its central planes one plane earlier than
    ``Tfi`` places them: today's ``Tfi`` on the planes labelled one later, centred on the frame time as TFP is."""
    from rmbvideo.chunks import SpikeChunk
    from rmbvideo.evaluate.harness import downsample_2x, rate_as_light, sequence_convention
    from rmbvideo.evaluate.heldout import RAW_RATE_HZ
    from rmbvideo.recon.classical import Tfi

    planes = np.unpackbits(seq.raw_packed, axis=-1, bitorder="little")[..., : 2 * seq.shape[1]]
    search, frames = Tfi(step=20, max_reach=200, window=window), []
    for a in range(0, len(planes), 128):
        frames += search.push(SpikeChunk(planes[a : a + 128], a + 1, RAW_RATE_HZ))
    frames += search.flush()
    return {f.index: downsample_2x(rate_as_light("tfi", f.image, sequence_convention(seq)), seq.shape) for f in frames}


def centred(folder: str, out: str, shifted: str) -> None:
    """``folder``'s training and development frames with TFI-4 and TFI-16 centred on the frame time
    (``_centred_tfi``), and the real streams' frames with RMB-Net's binned frame (and the one before) made on the
    ``shifted`` streams (``shift``: at the reference's moment) and TFI as cached (today's TFI is centred there)."""
    from rmbvideo.evaluate.real_video import find_streams

    src, dst = Path(folder), Path(out)
    dst.mkdir(parents=True, exist_ok=True)

    def redo(seq, path: Path) -> None:  # noqa: ANN001
        d = dict(np.load(path))
        short, long = _centred_tfi(seq, 4), _centred_tfi(seq, 16)
        index = sorted(short)[: len(d["tfi"])]
        d["tfi"], d["long"] = (np.stack([x[i] for i in index]).astype(np.float32) for x in (short, long))
        np.savez(dst / path.name, **d)

    for seq, name in _cached_captures():
        redo(seq, src / name)
    for stream in find_streams(Path(shifted)):
        binned, _, previous, _, _ = ff.reference_frame_inputs(stream, default_model_path("binned"))
        d = dict(np.load(src / f"real-{stream.name}.npz"))
        d["binned"], d["previous"] = binned, previous
        np.savez(dst / f"real-{stream.name}.npz", **d)


if __name__ == "__main__":
    torch.set_num_threads(1)
    command, args = sys.argv[1], sys.argv[2:]
    if command == "candidates":
        candidates(*args)
    elif command == "regions":
        regions(*args)
    elif command == "shares":
        shares(*args)
    elif command == "reds-like":
        reds_like(*args)
    elif command == "window":
        window(args[0], args[1], int(args[2]), args[3])
    elif command == "moment":
        moment(*args)
    elif command == "replay":
        replay(args[0], args[1], *(float(a) for a in args[2:]))
    elif command == "shift":
        shift(*args)
    elif command == "centred":
        centred(*args)
    elif command == "sharpness":
        sharpness(args[0], *(int(a) for a in args[1:]))
    else:
        variant(args[0], int(args[1]), int(args[2]), int(args[3]), *args[4:])
