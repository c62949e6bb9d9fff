"""Every k-th frame of a method whose frame step is fixed (RMB-Net: a frame every N readouts, its model's): the
method still makes every frame, since its recurrent state steps through them all, and the output keeps one in k,
numbered on from 0 at the capture's start (``--step`` a multiple of the fixed step: fewer frames a second)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from rmbvideo.chunks import Frame


class EveryKthFrame:
    """``method``'s frames whose index is a multiple of ``every``, frame ``i`` renumbered ``i // every`` (its time
    kept: the moment it shows). What the streaming loop reads of a method (``iter_frames``) is ``method``'s."""

    def __init__(self, method: Any, every: int) -> None:
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.method = method
        self.every = every

    @property
    def input_kind(self) -> str:
        return self.method.input_kind

    @property
    def stage_seconds(self) -> dict[str, float]:
        return getattr(self.method, "stage_seconds", {})

    @property
    def max_push_planes(self) -> int | None:
        return getattr(self.method, "max_push_planes", None)

    @property
    def accepts_packed(self) -> bool:
        return getattr(self.method, "accepts_packed", False)

    def push(self, chunk: Any) -> list[Frame]:
        return self._kept(self.method.push(chunk))

    def flush(self) -> list[Frame]:
        return self._kept(self.method.flush())

    def _kept(self, frames: list[Frame]) -> list[Frame]:
        return [replace(f, index=f.index // self.every) for f in frames if f.index % self.every == 0]
