"""How far a resumed RMB-Net run's frames are from the uninterrupted run's, with the saved recurrent state and without
it (the warm-up alone): ``python models/experiments/resume-state/measure.py CAPTURE [--duration S] [reconstruct
options]``. Each stop: the run is stopped by SIGTERM once it has written that many frames, then resumed (once as is,
once with its ``.resume-state.safetensors`` removed); EXR float frames, one thread. Prints a Markdown table."""

from __future__ import annotations

import argparse
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rmbvideo.io.exr import read_exr
from rmbvideo.recon.resume import RESUME_STATE


def command(capture: Path, out: Path, options: list[str], resume: bool) -> list[str]:
    return [sys.executable, "-m", "rmbvideo", "reconstruct", str(capture), "-o", str(out), "--format", "exr",
            "--exr-dtype", "float", "--threads", "1", "-q", *options, *(["--resume"] if resume else [])]


def stopped_at(args: list[str], out: Path, frames: int) -> Path:
    """Run ``args``, SIGTERM it once its staging folder holds ``frames`` frames; the staging folder it kept."""
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while proc.poll() is None:
        kept = [p for p in out.parent.glob(f".{out.name}.partial-*") if len(list(p.glob("frame_*"))) >= frames]
        if kept:
            proc.send_signal(signal.SIGTERM)
            proc.wait()
            return kept[0]
        time.sleep(0.02)
    raise SystemExit(f"the run ended before frame {frames}")


def frames_of(folder: Path) -> dict[str, np.ndarray]:
    return {p.name: read_exr(p)[0] for p in sorted(folder.glob("frame_*.exr"))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("capture", type=Path)
    parser.add_argument("--stops", default="0.5,0.75", help="stop points as fractions of the frames")
    args, options = parser.parse_known_args()
    with tempfile.TemporaryDirectory() as work:
        root = Path(work)
        whole = root / "whole"
        subprocess.run(command(args.capture, whole, options, False), check=True)
        expected = frames_of(whole)
        print("| stop (frames written) | state | frames resumed | worst pixel / peak | PSNR vs peak (dB) | frames equal |")
        print("|---:|---|---:|---:|---:|---:|")
        for fraction in map(float, args.stops.split(",")):
            out = root / "out"
            partial = stopped_at(command(args.capture, out, options, True), out, int(fraction * len(expected)))
            kept = len(list(partial.glob("frame_*")))
            copy = root / partial.name.replace(".out.", ".warm.", 1)
            shutil.copytree(partial, copy)
            (copy / RESUME_STATE).unlink(missing_ok=True)
            for folder, label in ((out, "saved state"), (root / "warm", "warm-up alone")):
                subprocess.run(command(args.capture, folder, options, True), check=True)
                got = frames_of(folder)
                names = sorted(expected)[kept:]
                diffs = [np.abs(got[n] - expected[n]) / max(float(expected[n].max()), 1e-12) for n in names]
                mse = float(np.mean([np.mean(d ** 2) for d in diffs]))
                psnr = "inf" if mse == 0 else f"{-10 * np.log10(mse):.1f}"
                equal = sum(int(np.array_equal(got[n], expected[n])) for n in names)
                print(f"| {kept} | {label} | {len(names)} | {max(float(d.max()) for d in diffs):.1e} | {psnr} | "
                      f"{equal} of {len(names)} |", flush=True)
                shutil.rmtree(folder)


if __name__ == "__main__":
    main()
