"""One ffmpeg process that encodes raw frames from its stdin into a video file.

ffmpeg's own messages are kept, not printed, so that a failure, such as a full disk while it writes the file's
trailer, reaches the user as one line naming the file and ffmpeg's reason. It runs in a session of its own, so a
terminal's Ctrl-C reaches only this program, which then stops ffmpeg and removes the file.
"""

from __future__ import annotations

import logging
import re
import signal
import subprocess
import threading
from fractions import Fraction
from pathlib import Path

from rmbvideo.errors import OutputError

log = logging.getLogger(__name__)

#: ffmpeg's first lines, kept for the error message (the first is the cause; later ones follow from it)
_KEPT_LINES = 20
#: the "[out#0/mp4 @ 0x55d1c0de]" context ffmpeg puts before a message
_CONTEXT = re.compile(r"^\[[^\]]*@ 0x[0-9a-f]+\]\s*")


class FfmpegEncoder:
    """ffmpeg reading ``pix_fmt_in`` frames of ``size`` (width, height) at ``fps`` from stdin, encoding them with
    ``codec`` into ``path``; ``output_params`` go before the output file. ``send`` a frame's bytes, then ``close``."""

    def __init__(self, path: Path, size: tuple[int, int], *, pix_fmt_in: str, pix_fmt_out: str, fps: float,
                 codec: str, output_params: list[str], display_path: Path | None = None) -> None:
        import imageio_ffmpeg

        self.display_path = display_path or path
        rate = Fraction(fps).limit_denominator()
        try:
            executable = imageio_ffmpeg.get_ffmpeg_exe()
        except RuntimeError as exc:  # no bundled binary for this platform and none on the PATH
            raise OutputError(f"{self.display_path}: cannot start ffmpeg: {exc}") from exc
        command = [executable, "-y", "-v", "error", "-hide_banner",
                   "-f", "rawvideo", "-vcodec", "rawvideo", "-s", f"{size[0]}x{size[1]}", "-pix_fmt", pix_fmt_in,
                   "-r", str(rate), "-i", "-", "-an", "-vcodec", codec, "-pix_fmt", pix_fmt_out,
                   *output_params, str(path)]
        self._lines: list[str] = []
        try:
            self._process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                             stderr=subprocess.PIPE, start_new_session=True)
        except OSError as exc:
            raise OutputError(f"{self.display_path}: cannot start ffmpeg: {exc.strerror or exc}") from exc
        self._reader = threading.Thread(target=self._keep_messages, name="ffmpeg-messages", daemon=True)
        self._reader.start()

    def _keep_messages(self) -> None:
        for raw in self._process.stderr:
            line = _CONTEXT.sub("", raw.decode(errors="replace").strip())
            if line and len(self._lines) < _KEPT_LINES:
                self._lines.append(line)

    def reason(self) -> str:
        """ffmpeg's first message, or how it ended when it said nothing (a signal: e.g. a file-size limit)."""
        self._reader.join(timeout=5)
        if self._lines:
            return self._lines[0]
        status = self._process.returncode
        if status is not None and status < 0:
            return f"ffmpeg was stopped by a signal: {signal.strsignal(-status) or -status}"
        return f"ffmpeg exited with status {status}"

    def send(self, data: bytes) -> None:
        """Give ffmpeg one frame; a stopped ffmpeg is an ``OutputError`` with its reason."""
        try:
            self._process.stdin.write(data)
        except OSError as exc:  # a broken pipe: ffmpeg has stopped
            self._process.wait()
            raise OutputError(f"{self.display_path}: ffmpeg stopped accepting frames: {self.reason()}") from exc

    def close(self) -> None:
        """End the stream and wait for ffmpeg to finish the file; its failure is an ``OutputError`` with its reason."""
        try:
            self._process.stdin.close()
        except OSError:  # it had stopped already; its status says why
            pass
        status = self._process.wait()
        if status != 0:
            raise OutputError(f"{self.display_path}: ffmpeg could not write the video: {self.reason()}")
        self._reader.join(timeout=5)
        if self._lines:  # errors it recovered from: said, not swallowed
            log.warning("%s: ffmpeg reported: %s", self.display_path, "; ".join(self._lines[:3]))

    def kill(self) -> None:
        """Stop ffmpeg at once (an aborted run); what it wrote is the caller's to remove."""
        self._process.kill()
        try:
            self._process.stdin.close()
        except OSError:
            pass
        self._process.wait()
