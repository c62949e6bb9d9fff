"""Where the bundled ffmpeg stops writing correct MP4s: the limits behind ``PLAYBACK_FPS_RANGE`` and
``HEVC_MIN_SIDE`` (``rmbvideo/io/sinks.py``, ``rmbvideo/io/hdr_video.py``).

``python models/experiments/ffmpeg-limits/scan.py`` prints, for H.264 (the mp4 format's) and HEVC Main10 (hdr10/hlg),
whether a stream of N grey frames at each playback rate is written and read back with N frames and N / fps seconds,
and which frame sizes each encoder takes (even sizes: the sinks pad an odd side by one for 4:2:0). Results of the stop that set the limits are in ``results.txt``.
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import imageio_ffmpeg

FFMPEG = imageio_ffmpeg.get_ffmpeg_exe()
CODECS = {"h264": ("libx264", "gray", "yuv420p", 1), "hevc": ("libx265", "yuv420p10le", "yuv420p10le", 3)}


def encode(codec: str, width: int, height: int, fps: float, frames: int, folder: Path) -> str:
    """'ok N frames S s', or the first line ffmpeg gave for refusing it."""
    encoder, pix_in, pix_out, bytes_per_pixel = CODECS[codec]
    out = folder / "probe.mp4"
    cmd = [FFMPEG, "-v", "error", "-f", "rawvideo", "-pix_fmt", pix_in, "-s", f"{width}x{height}", "-r", repr(fps),
           "-i", "-", "-frames:v", str(frames), "-c:v", encoder, "-pix_fmt", pix_out, "-movflags", "+faststart",
           "-f", "mp4", "-y", str(out)]
    done = subprocess.run(cmd, input=bytes(width * height * bytes_per_pixel * frames), capture_output=True)
    if done.returncode != 0:
        return "refused: " + (done.stderr.decode().strip().splitlines() or ["?"])[0]
    try:
        count, seconds = imageio_ffmpeg.count_frames_and_secs(str(out))
    except (RuntimeError, OSError) as exc:
        return f"unreadable: {str(exc).splitlines()[-1]}"
    return f"ok {count} frames {seconds:g} s (expected {frames} frames {frames / fps:g} s)"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for fps, frames in [(1e-6, 2), (1e-5, 1000), (1e-3, 1000), (0.01, 20000), (30.0, 200), (1e4, 20000),
                            (1e5, 200), (1e6, 200)]:
            for codec in CODECS:
                print(f"fps {fps:g} x {frames} frames, {codec}: {encode(codec, 16, 16, fps, frames, folder)}")
        for width, height in [(2, 2), (8, 8), (14, 64), (16, 16), (64, 14), (10, 250), (250, 16)]:
            for codec in CODECS:
                print(f"{width}x{height}, {codec}: {encode(codec, width, height, 30.0, 2, folder)}")


if __name__ == "__main__":
    main()
