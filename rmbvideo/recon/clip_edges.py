"""A clip's edge frames by a model of their own: the first and last w frames of a clip, whose windows the clip's edges
cut, made with an edge model (an RMB-Net trained on those frames alone, ``optim.edge_only``) while the default model
makes every other frame as it does (bit for bit). An edge frame is the mean of the two models' (``EDGE_MIX``): their
errors are partly independent, so the mean gains on every kind of clip, where the edge model alone loses on some.

Each edge is made as the edge model was trained on it: as a clip of its own of 2w frames (its first 2w, its last 2w),
primed backwards as a clip's first frame is. That is 2w + prime extra network steps at each end, whatever the capture's
length, and the last 2w preliminary frames kept meanwhile.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence

import numpy as np

from rmbvideo.chunks import Frame

#: the edge model's run over a clip of its own: its preliminary frames in, its frames out
ClipRun = Callable[[Sequence], list[Frame]]
#: The edge model's share of an edge frame. On the 40 clips no evaluation uses (models/experiments/edge-timing), the
#: shipped edge model alone brought the edge costs 0.07 dB nearer on average but lost up to 0.36 on single frames; the
#: mean 0.06 nearer, on every kind, losing at most 0.15
EDGE_MIX = 0.5


class ClipEdges:
    """``see(prelim frames)`` as the default model receives them, then ``edge_frames(its frames, final)``: the same
    frames in order, those of the clip's first and last ``w`` frames with the edge model's images mixed in by ``mix``
    (1: the edge model's alone). Frames from the
    clip's first on wait until its first 2w frames are here (the default model's first frame waits for 2w + 1 unless
    its state is primed over fewer)."""

    def __init__(self, run_clip: ClipRun, w: int, mix: float = EDGE_MIX) -> None:
        if not 0.0 <= mix <= 1.0:
            raise ValueError(f"mix must be in [0, 1], got {mix}")
        self._run_clip = run_clip
        self._mix = mix
        self._w = w
        self._span = 2 * w
        self._head: list | None = []  # the clip's first 2w preliminary frames, until their edge run
        self._tail: deque = deque(maxlen=self._span)
        self._received = 0
        self._images: dict[int, np.ndarray | None] | None = None  # edge frames' images by frame index
        self._first_run: list[Frame] = []  # the first edge's run: the whole clip where it has 2w frames or fewer
        self._held: list[Frame] = []

    def see(self, frames: Sequence) -> None:
        """Preliminary frames as the default model receives them."""
        for frame in frames:
            if self._head is not None and len(self._head) < self._span:
                self._head.append(frame)
            self._tail.append(frame)
        self._received += len(frames)

    def edge_frames(self, frames: list[Frame], final: bool) -> list[Frame]:
        """``frames`` (the default model's, in order; all of them by ``final``) with the edge model's images on the
        clip's edge frames; frames held back until the first edge's run (when 2w frames are here) come out with it."""
        frames = self._held + frames
        self._held = []
        if self._images is None:
            if not final and len(self._head or ()) < self._span:
                self._held = frames
                return []
            self._first_run = self._run_clip(self._head) if self._head else []
            self._images = {f.index: f.image for f in self._first_run[: self._w]}
            self._head = None
        if final:  # a clip of 2w frames or fewer is its first edge's run
            last = self._first_run if self._received <= self._span else self._run_clip(list(self._tail))
            self._images.update({f.index: f.image for f in last[-self._w :]})
        return [self._edge_frame(f) for f in frames]

    def _edge_frame(self, frame: Frame) -> Frame:
        """``frame`` with the edge model's image mixed in where it made one and ``frame`` has one (a frame made for the
        recurrent state alone stays without)."""
        if frame.image is None or frame.index not in self._images:
            return frame
        image = self._images.pop(frame.index)
        if image is None:
            return frame
        mixed = (1.0 - self._mix) * frame.image + self._mix * image
        return Frame(index=frame.index, time_s=frame.time_s, image=mixed.astype(np.float32, copy=False))
