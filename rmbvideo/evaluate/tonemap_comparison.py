"""Every tone-mapping operator side by side on real and synthetic captures, at their light and at
1/100 of it: the figure and numbers behind the choice of the default SDR operator.

``python -m rmbvideo.evaluate.tonemap_comparison OUT.png [--capture car.dat]`` writes the figure
and prints, per capture and operator, the median 8-bit luma, the 1st-99th percentile spread and the
flicker (standard deviation of the frame means) of the middle frame of a TFP reconstruction.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

from rmbvideo.io.png import write_png
from rmbvideo.io.tonemap import TONE_METHODS, ToneMapConfig, ToneMapper
from rmbvideo.recon.run import reconstruct_frames
from rmbvideo.scenes.scene import resolve_scene
from rmbvideo.simulate.capture import simulate_capture


def compare(captures: dict[str, Path], darker: float = 0.01) -> tuple[np.ndarray, list[str]]:
    """The comparison image (rows: capture at full light, then x ``darker``; columns: operators)
    and one report line per (capture, light, operator)."""
    rows, report = [], []
    for label, path in captures.items():
        frames = [f.image for f in reconstruct_frames(path, method="tfp")]
        for suffix, scale in (("", 1.0), (f" x{darker:g}", darker)):
            tiles = []
            for method in TONE_METHODS:
                mapper = ToneMapper(ToneMapConfig(method=method))
                out = [mapper(f * np.float32(scale)) for f in frames]
                image = out[len(out) // 2]
                median = float(np.median(image))
                p1, p99 = np.percentile(image, [1, 99])
                flicker = float(np.std([o.mean() for o in out[2:]]))
                report.append(f"{label + suffix:32s} {method:9s} median {median:5.0f}  p1-p99 {p99 - p1:5.0f}  "
                              f"flicker {flicker:5.2f}")
                tile = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
                text = f"{method} {label + suffix} med {median:.0f}"
                cv2.putText(tile, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 3, cv2.LINE_AA)
                cv2.putText(tile, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 255, 255), 1, cv2.LINE_AA)
                tiles.append(np.pad(tile, ((2, 2), (2, 2), (0, 0)), constant_values=255))
            rows.append(np.hstack(tiles))
    width = max(r.shape[1] for r in rows)
    image = np.vstack([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows])
    return image, report


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--capture", type=Path, action="append", default=[], help="real captures to include")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        demo = Path(folder) / "demo.dat"
        simulate_capture(resolve_scene("demo"), demo, duration_s=0.02)
        captures = {f"{p.name} (real)": p for p in args.capture}
        captures["demo pan (synthetic)"] = demo
        image, report = compare(captures)
    write_png(args.out, image)
    print("\n".join(report))


if __name__ == "__main__":
    main()
