"""TFP and TFI of the raw 1-bit stream on a torch device: the full-resolution detail stage's inputs where the
network runs on a GPU, so they do not cap the frame rate at what one CPU core makes (TFP over four windows and TFI
cost about 2.8 ms a 400x250 frame of one core: 360 frames/s at most).

The frames are those of ``rmbvideo.recon.classical.Tfp`` and ``Tfi`` bit for bit (the same window schedule through
``_WindowSums``, the same interval search; integer sums and intervals, one float64 division, rounded to float32).
A chunk's planes go to the device once, packed as stored when they come packed (a bit-plane is 1/8 of the bytes),
and are decoded there; every method reads the same device planes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from rmbvideo.chunks import Frame, SpikeChunk
from rmbvideo.io.dat import DatGeometry, PackedChunk
from rmbvideo.recon.classical import Tfi, _NONE_IN_BLOCK, _WindowSums

@dataclass(frozen=True)
class DeviceSpikes:
    """Consecutive raw 1-bit planes on a device: ``planes`` (T, H, W) uint8 of 0/1, image orientation."""

    planes: torch.Tensor
    start: int
    rate_hz: float


def unpack_on(data: np.ndarray, geometry: DatGeometry, device: torch.device) -> torch.Tensor:
    """Stored plane bytes (T, plane_bytes) -> (T, H, image_width) uint8 planes on ``device``: the bits decoded there
    as ``rmbvideo.io.dat.unpack_planes`` decodes them (little bit order, rows flipped when the geometry says)."""
    g = geometry
    data = np.ascontiguousarray(data)
    # torch wants writable memory (it warns of undefined behaviour otherwise): a read-only buffer, e.g. a file's
    # mapped bytes, is copied (the packed bytes, an eighth of the planes)
    packed = torch.from_numpy(data if data.flags.writeable else data.copy()).to(device)
    shifts = torch.arange(8, dtype=torch.uint8, device=device)
    bits = ((packed[..., None] >> shifts) & 1).reshape(len(data), g.height, g.width)
    if g.flip:
        bits = bits.flip(1)
    return bits[:, :, : g.image_width].contiguous()


def to_device(chunk: SpikeChunk | PackedChunk, device: torch.device) -> DeviceSpikes:
    """A chunk's planes on ``device`` (decoded there when they come packed)."""
    if isinstance(chunk, PackedChunk):
        planes = unpack_on(chunk.data, chunk.geometry, device)
    else:
        planes = torch.from_numpy(np.ascontiguousarray(chunk.planes)).to(device)
    return DeviceSpikes(planes, chunk.start, chunk.rate_hz)


class _DeviceTotals:
    """``_WindowSums``' running totals as int64 tensors on the planes' device."""

    def __init__(self, channels: Sequence[torch.Tensor]) -> None:
        self._total = [torch.zeros(c.shape[1:], dtype=torch.int64, device=c.device) for c in channels]

    def add(self, channels: Sequence[torch.Tensor], a: int, b: int) -> None:
        for total, channel in zip(self._total, channels):
            total += channel[a:b].sum(dim=0, dtype=torch.int64)

    def snapshot(self) -> list[torch.Tensor]:
        return [t.clone() for t in self._total]

    def since(self, snapshot: list[torch.Tensor]) -> list[torch.Tensor]:
        return [total - snap for total, snap in zip(self._total, snapshot)]


def _image(values: torch.Tensor, on_device: bool) -> np.ndarray | torch.Tensor:
    """A frame's float32 image: left on the device for a consumer there (the detail stage on a GPU reads it without a
    round trip through host memory), else a numpy array."""
    image = values.float()
    return image if on_device else image.cpu().numpy()


class DeviceTfp:
    """``Tfp`` (mean of ``window`` raw planes centred on each frame time) on ``DeviceSpikes``; with ``on_device`` its
    frames' images stay device tensors."""

    def __init__(self, window: int = 41, step: int = 20, on_device: bool = False) -> None:
        self._sums = _WindowSums(window, step, _DeviceTotals)
        self._rate_hz = 0.0
        self._on_device = on_device

    def push(self, spikes: DeviceSpikes) -> list[Frame]:
        self._rate_hz = spikes.rate_hz
        return [self._frame(w) for w in self._sums.push(spikes.start, [spikes.planes])]

    def flush(self) -> list[Frame]:
        return [self._frame(w) for w in self._sums.flush()]

    def _frame(self, total) -> Frame:
        image = _image(total.sums[0].double() / total.count, self._on_device)
        return Frame(index=total.index, time_s=total.centre / self._rate_hz, image=image)


class DeviceTfi(Tfi):
    """``Tfi`` (1 / the interval between the spikes around each frame time, searched at most ``max_reach`` planes
    either side) on ``DeviceSpikes``: the same search, its array operations torch's, a block's running max/min
    as device scans; with ``on_device`` its frames' images stay device tensors."""

    _where = staticmethod(torch.where)

    def __init__(self, step: int = 20, max_reach: int = 200, on_device: bool = False,
                 shorter: tuple[int, ...] = (), window: int = 0) -> None:
        super().__init__(step, max_reach, shorter, window)
        self._on_device = on_device

    @staticmethod
    def _stack(images: list[np.ndarray | torch.Tensor]) -> np.ndarray | torch.Tensor:
        return torch.stack(images) if isinstance(images[0], torch.Tensor) else np.stack(images)

    @staticmethod
    def _indices_like(like: torch.Tensor, value: int) -> torch.Tensor:
        return torch.full(like.shape, value, dtype=torch.int64, device=like.device)

    @staticmethod
    def _counts_like(like: torch.Tensor) -> torch.Tensor:
        return torch.zeros(like.shape, dtype=torch.int64, device=like.device)

    @staticmethod
    def _indices(a: torch.Tensor) -> torch.Tensor:
        return a.to(torch.int64)

    def _widen_indices(self, stop: int) -> None:
        """Plane numbers are int64 tensors throughout on a device (its memory is not the bound)."""

    @staticmethod
    def _count(planes: torch.Tensor) -> torch.Tensor:
        return planes.sum(dim=0, dtype=torch.int64)

    @staticmethod
    def _fill_next(nxt: torch.Tensor, first: torch.Tensor, start: int, limit: int) -> None:
        take = (first <= limit) & (nxt < 0)
        nxt[take] = first[take].to(torch.int64) + start

    def _image(self, interval: torch.Tensor, spikes: torch.Tensor | None = None) -> np.ndarray | torch.Tensor:
        return _image((1.0 if spikes is None else spikes.double()) / interval.double(), self._on_device)

    @staticmethod
    def _scan(planes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        offsets = torch.arange(len(planes), dtype=torch.int16, device=planes.device)[:, None, None]
        spikes = planes.to(torch.bool)
        last_in = torch.cummax(spikes * (offsets + 1), dim=0).values
        none = int(_NONE_IN_BLOCK)
        first_from = torch.cummin((none - spikes * (none - offsets)).flip(0), dim=0).values
        return last_in, first_from.flip(0)
