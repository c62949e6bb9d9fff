"""Continuing an interrupted reconstruction (``reconstruct --resume``): the frames it wrote are kept, and the
method restarts a little before the first frame missing.

A resumable run writes frame files (EXR or PNG, each renamed into place whole) into its staging folder, with a
record of its fingerprint (``RESUME_RECORD``) and a log of the frames written (``RESUME_LOG``, a line a frame,
flushed as each frame is written). When it is interrupted (Ctrl-C, SIGTERM, a full disk, kill -9) that folder stays.
A later run with the same input and options adopts it, keeps the frames its log lists whose files are there, and
runs the method from ``WARM_UP_FRAMES`` frames before the first missing one, writing only the frames from there: a
method's windows refill over frames the old run had also seen. RMB-Net's recurrent state keeps a faint long memory a
warm-up rebuilds only to about 1 % of the light on a few pixels, so a run keeps a snapshot of it every few frames
(``RESUME_STATE``) and the resumed run sets it back, warming up before the snapshot's frame instead: its frames are
then the uninterrupted run's. The log also carries what the sink's next frame depends on (the PNG tone mapper's smoothed
exposure), which is set back.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from safetensors import SafetensorError, safe_open

from rmbvideo.chunks import Frame
from rmbvideo.errors import OptionError, OutputError
from rmbvideo.io.atomic import atomic_write_bytes, atomic_write_text, output_error
from rmbvideo.io.sinks import FrameSink, frame_file_name
from rmbvideo.recon.fingerprint import fingerprint_digest

if TYPE_CHECKING:  # torch itself is imported where a state is saved: a classical method's run never loads it
    import torch

#: Formats a run can be resumed in: one file a frame. A video stream cannot be continued where it was cut.
RESUMABLE_FORMATS = ("exr", "png")
#: Frames run again before the first missing one and not written: they refill every method's windows (TFI's
#: 200-plane reach, the aligned means' 11 frames) and give RMB-Net's recurrent state a past, whose cell state decays
#: by 0.95 a frame.
WARM_UP_FRAMES = 64
#: Raw planes TFI searches on each side of a frame (``Tfi``'s default reach, which the raw gate's TFI-16 shares), with
#: a margin: a frame at a --step of a few planes still has all its evidence inside the warm-up
INTERVAL_REACH = 400
RESUME_RECORD = ".resume.json"
RESUME_LOG = ".resume-frames.csv"
#: The recurrent state after a frame already written (safetensors: tensors and the frame's index, no code)
RESUME_STATE = ".resume-state.safetensors"
RECORD_FORMAT = "rmbvideo-resumable-run"


class StateCarrier(Protocol):
    """A method with a recurrent state a resumed run sets back (``RmbNetReconstructor``)."""

    def keep_state_snapshots(self) -> None: ...

    def recurrent_state(self, at_most: int) -> tuple[int, dict[str, torch.Tensor]] | None: ...

    def resume_from(self, after: int, tensors: dict[str, torch.Tensor]) -> None: ...


def state_carrier(method: Any) -> StateCarrier | None:
    """The part of ``method`` whose recurrent state a resumed run sets back: RMB-Net, alone or inside
    ``FullResolution``; None for the window methods, which have none."""
    for part in (method, getattr(method, "binned", None)):
        if hasattr(part, "recurrent_state"):
            return part
    return None


def saved_state(folder: Path, next_index: int | None) -> tuple[int, dict[str, torch.Tensor]] | None:
    """The recurrent state an interrupted run in ``folder`` saved, as (the frame it follows, tensors), when it can
    start the frames from ``next_index`` on: the frame after the snapshot's is made again too (the raw gate reads the
    change from the frame before it), so the snapshot must lie two frames before. None when there is none."""
    if next_index is None:
        return None
    try:
        with safe_open(str(folder / RESUME_STATE), framework="pt") as stored:
            after = int((stored.metadata() or {}).get("after", ""))
            tensors = {name: stored.get_tensor(name) for name in stored.keys()}
    except (OSError, ValueError, SafetensorError):
        return None
    return (after, tensors) if after + 1 < next_index else None


def check_resumable_format(fmt: str) -> None:
    """``OptionError`` for ``--resume`` with a format that cannot be continued (a video stream)."""
    if fmt not in RESUMABLE_FORMATS:
        raise OptionError(f"--resume: a {fmt} video cannot be continued where it was cut; give --format "
                          f"{' or '.join(RESUMABLE_FORMATS)} for a run that can be resumed")


def check_resumable_step(method: str, step: int, every: int) -> None:
    """``OptionError`` for ``--resume`` with a step at which ``method`` keeps one in ``every`` of its frames (RMB-Net at
    a multiple of its own): the frames a run wrote do not tell where the method's state stood."""
    if every > 1:
        raise OptionError(f"--resume: {method} at --step {step} keeps one in {every} of the frames it makes, which a "
                          "resumed run cannot pick up; give its own step or leave --resume out")


def is_resumable(folder: Path, digest: str) -> bool:
    """Whether ``folder`` (an interrupted run's staging folder) was made by a run of fingerprint ``digest``."""
    try:
        record = json.loads((folder / RESUME_RECORD).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return isinstance(record, dict) and record.get("format") == RECORD_FORMAT and record.get("digest") == digest


def holds_frames(folder: Path) -> bool:
    """Whether a failed run's folder is worth keeping for a resume: its record and at least one logged frame."""
    return (folder / RESUME_RECORD).is_file() and scan_log(folder).frames > 0


@dataclass(frozen=True)
class LoggedFrames:
    """What an interrupted run's frame log holds: ``frames`` finished (its lines up to the first torn one or the first
    whose file is missing, ``valid_bytes`` of it), the next frame's index, and the sink's carried state after the
    last finished frame."""

    frames: int = 0
    next_index: int | None = None
    state: Any = None
    valid_bytes: int = 0


def scan_log(folder: Path) -> LoggedFrames:
    """Read ``folder``'s frame log a line at a time (it has a line a frame: memory stays bounded)."""
    frames, last, state, valid = 0, None, None, 0
    try:
        with open(folder / RESUME_LOG, "rb") as log_file:
            for raw in log_file:
                row = _parse(raw, folder)
                if row is None or (last is not None and row[0] <= last):
                    break  # a line cut short, a frame whose file is gone, or a log out of order
                frames, last, state, valid = frames + 1, row[0], row[1], valid + len(raw)
    except OSError:
        pass
    return LoggedFrames(frames, None if last is None else last + 1, state, valid)


def _parse(raw: bytes, folder: Path) -> tuple[int, Any, tuple[int, float, str]] | None:
    """(index, carried state, csv row) of one whole log line whose frame file is there, else None."""
    if not raw.endswith(b"\n"):
        return None
    try:
        index, time_s, name, carried = raw.decode("utf-8").rstrip("\n").split(",", 3)
        row = (int(index), float(time_s), name)
        state = json.loads(carried)
    except ValueError:
        return None
    if name != frame_file_name(row[0], name.rsplit(".", 1)[-1]) or not (folder / name).is_file():
        return None
    return row[0], state, row


def logged_rows(folder: Path, logged: LoggedFrames) -> Iterator[tuple[int, float, str]]:
    """The (index, time_s, file) rows of the frames ``logged`` counts, read from the log as they are taken."""
    with open(folder / RESUME_LOG, "rb") as log_file:
        for _ in range(logged.frames):
            parsed = _parse(log_file.readline(), folder)
            if parsed is None:
                raise OutputError(f"{folder / RESUME_LOG}: changed while it was read")
            yield parsed[2]


def start_record(folder: Path, fingerprint: dict[str, Any], logged: LoggedFrames) -> None:
    """Write the run's record into ``folder``, cut its log after the frames ``logged`` counts (a torn line dropped),
    and remove the temporary files a killed run left (a frame or ``frames.csv`` half written)."""
    for leftover in folder.glob(".*.tmp-*"):
        leftover.unlink(missing_ok=True)
    atomic_write_text(folder / RESUME_RECORD, json.dumps({"format": RECORD_FORMAT, "version": 1,
                                                          "digest": fingerprint_digest(fingerprint),
                                                          "fingerprint": fingerprint}, indent=2) + "\n")
    try:
        with open(folder / RESUME_LOG, "ab") as log_file:
            log_file.truncate(logged.valid_bytes)
    except OSError as exc:
        raise output_error(folder / RESUME_LOG, exc) from exc


def _log_line(index: int, time_s: float, name: str, state: Any) -> str:
    """One frame's line of the resume log: index, time (exactly, as Python's shortest repr), file, carried state."""
    return f"{index},{float(time_s)!r},{name},{json.dumps(state)}\n"


def finish_record(folder: Path) -> None:
    """Remove the record and log of a run that completed: the output folder holds the outputs alone."""
    for name in (RESUME_RECORD, RESUME_LOG, RESUME_STATE):
        try:
            os.unlink(folder / name)
        except FileNotFoundError:
            pass


def restart_plane(first_plane: int, next_index: int | None, step: int, reach: int = 0) -> int:
    """The raw plane a resumed run starts at: ``WARM_UP_FRAMES`` frames of ``step`` planes before frame
    ``next_index`` (frame i covers planes i*step .. (i+1)*step - 1 of the capture), or more where the method's window
    reaches further (``reach`` raw planes: a --window of thousands), never before the run's own start."""
    if next_index is None:
        return first_plane
    warm_up = max(WARM_UP_FRAMES, -(-reach // step) + 2)
    return max(first_plane, (next_index - warm_up) * step)


def window_reach(window: int | None, unit: str | None, raw_per_readout: int) -> int:
    """The raw planes a method's frame may read before its own: ``INTERVAL_REACH`` (TFI's search, the widest of the
    defaults) plus what its ``--window`` spans (``unit``: what it counts, as ``Method.window`` says)."""
    if window is None or unit is None or unit.startswith("half-width"):
        return INTERVAL_REACH  # the method's default window, or RMB-Net's few frames
    return INTERVAL_REACH + window * (raw_per_readout if unit == "readouts" else 1)


class ResumedSink:
    """The frames of a (resumed) run into ``sink``: those before ``next_index`` (made again as warm-up, or written
    by the run this one continues) are dropped; each one written (a file ``frame_NNNNNN.ext``) is logged in
    ``folder``'s resume log."""

    def __init__(self, sink: FrameSink, folder: Path, next_index: int | None, ext: str,
                 carrier: StateCarrier | None = None) -> None:
        self.sink = sink
        self.next_index = next_index
        self.ext = ext
        self.written = 0
        self._carrier = carrier
        self._saved = -1
        self._state_path = folder / RESUME_STATE
        self._log_path = folder / RESUME_LOG
        try:
            self._log = open(self._log_path, "a", encoding="utf-8", newline="\n")
        except OSError as exc:
            raise output_error(self._log_path, exc) from exc

    def write(self, frame: Frame) -> None:
        if self.next_index is not None and frame.index < self.next_index:
            return
        self.sink.write(frame)
        self.written += 1
        line = _log_line(frame.index, frame.time_s, frame_file_name(frame.index, self.ext), self.sink.carried_state())
        try:  # flushed a frame at a time: a kill -9 loses at most the frame being written
            self._log.write(line)
            self._log.flush()
        except OSError as exc:
            raise output_error(self._log_path, exc) from exc
        self._save_state(frame.index)

    def _save_state(self, written: int) -> None:
        """Replace the saved recurrent state with the carrier's newest snapshot that a resume can use after frame
        ``written`` (one before it: ``saved_state``), when there is a newer one."""
        snapshot = None if self._carrier is None else self._carrier.recurrent_state(at_most=written - 1)
        if snapshot is None or snapshot[0] <= self._saved:
            return
        after, tensors = snapshot
        from safetensors.torch import save

        try:
            atomic_write_bytes(self._state_path, save(tensors, metadata={"after": str(after)}))
        except OSError as exc:
            raise output_error(self._state_path, exc) from exc
        self._saved = after

    def close(self) -> None:
        """Close the frame log (again: nothing)."""
        try:
            self._log.close()
        except OSError as exc:
            raise output_error(self._log_path, exc) from exc
