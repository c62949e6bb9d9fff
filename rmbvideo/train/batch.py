"""Training samples stacked on a device as one batch (with optional left-right mirroring), and which
of a sample's outputs are supervised."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from rmbvideo.net.blend import BIN_TRIALS
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.recon.aligned_box import AlignedBoxConfig, aligned_means, network_input
from rmbvideo.recon.prelim import select_centre
from rmbvideo.train.dataset import Sample


@dataclass
class Batch:
    """Samples stacked on a device: ``i_s``, ``i_m``, ``gt`` (B, F, H, W) float32, ``convention`` (B,),
    ``i_c`` (B, F, C, H, W): central sums over the model's centre windows, or None when it has none;
    ``i_a`` (B, F, H, W), or (B, F, C, H, W) with ``aligned_centre`` or ``aligned_evidence``: each frame's aligned
    window mean(s) of the multi-bit sums, then their statistics (``RmbNet.step``; the model's radius and edge policy
    at the sample's ends, as at a clip's), or None when the model does not read it."""

    i_s: torch.Tensor
    i_m: torch.Tensor
    gt: torch.Tensor
    convention: torch.Tensor
    i_c: torch.Tensor | None = None
    i_a: torch.Tensor | None = None

    @classmethod
    def from_samples(cls, samples: list[Sample], device: torch.device, flips: list[bool] | None = None,
                     centre: tuple[int, ...] = (), n: int = 10, aligned: RmbNetConfig | None = None) -> "Batch":
        """Stack samples, mirroring sample j left-right where ``flips[j]`` (rows, hence the
        rolling band, are unchanged by a horizontal mirror); ``centre``: the model's centre windows
        (frames of ``n`` readouts); ``aligned``: the config of a model that reads the aligned window means
        (its radius and edge policy; None: none), computed after the mirror, as the engine would on a mirrored clip."""
        flips = flips or [False] * len(samples)

        def stack(arrays: list[np.ndarray]) -> torch.Tensor:
            arrays = [a[..., ::-1] if f else a for a, f in zip(arrays, flips)]
            return torch.from_numpy(np.ascontiguousarray(np.stack(arrays), dtype=np.float32)).to(device)

        convention = torch.tensor([float(s.convention) for s in samples], dtype=torch.float32, device=device)
        i_c = stack([select_centre(s.i_c, n, centre) for s in samples]) if centre else None
        i_s, i_m, gt = (stack([getattr(s, name) for s in samples]) for name in ("i_s", "i_m", "gt"))
        i_a = None
        if aligned is not None and aligned.aligned:
            scale, k = BIN_TRIALS * n, aligned.aligned_centre
            sharp = (stack([select_centre(s.i_c, n, (k,))[:, 0] for s in samples]).cpu().numpy() / (BIN_TRIALS * k)
                     if k else [None] * len(samples))
            box = AlignedBoxConfig.for_frames(n, k)
            clips = []
            for m, c in zip(i_m.cpu().numpy(), sharp):
                means = aligned_means(m / scale, aligned.aligned_half_width, box, aligned.aligned_shift, c,
                                      aligned.aligned_evidence)
                means, statistics = means if aligned.aligned_evidence else (means, [None] * len(means))
                clips.append(np.stack([network_input(a, e, scale) for a, e in zip(means, statistics)]))
            i_a = torch.from_numpy(np.stack(clips)).to(device)
        return cls(i_s, i_m, gt, convention, i_c, i_a)


def output_range(count: int, w: int, edges: bool) -> range:
    """Supervised outputs of a sample of ``count`` frames: every frame (the first and last w as a
    clip's edges, their windows cut at the sample's ends) when ``edges``, else the full windows."""
    outputs = range(count) if edges else range(w, count - w)
    if len(outputs) < 1:
        raise ValueError(f"samples have {count} frames, need at least 2w+1 = {2 * w + 1}")
    return outputs
