"""Learned detail stage for full camera resolution: the binned result, upsampled, times a per-pixel
detail factor predicted from the raw stream's full-resolution spike rates.

The binned path (RMB-Net) decides each 2x2 block's level; this stage decides only how that level is
shared among the block's four pixels. It reads the raw TFP rates over a few windows (short ones
follow motion, long ones resolve faint texture), each as its relative deviation from its block mean
with the block's spike count (how far that deviation can be trusted), plus the bilinear upsampling's
own deviation from the block level, and optionally (``interval_reach``) TFI, the inverse interval
between the spikes around the frame's centre: the sharpest estimate of a moving bright pixel. The
predicted relative deviation d is made zero-mean over every 2x2 block, and

    full = to_block_levels(bilinear(binned) * max(1 + d, 0), binned),

where ``to_block_levels`` rescales each 2x2 block so that its mean is the binned pixel itself (bilinear
upsampling alone blurs each block's level with its neighbours': on the real-video streams that blur
cost 1.4 dB at full resolution). So averaging the output over 2x2 blocks gives the binned result back
exactly: the stage adds detail, never a tone change.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from rmbvideo.mulaw import mu_law
from rmbvideo.net.pooling import mean_2x2


@dataclass(frozen=True)
class DetailConfig:
    """``windows``: raw planes of the TFP rates the stage reads (centred on the frame; the 6-plane one
    follows fast motion, which blurs over 20 planes at a raw pixel per plane); ``interval_reach``: raw
    planes TFI searches on each side of the frame's centre (``rmbvideo.recon.classical.Tfi``'s
    ``max_reach``), 0 for no TFI input; ``interval_windows``: more TFI inputs over that reach, each the whole
    intervals covering that many central planes (``Tfi``'s ``window``: TFI-4, TFI-16, the raw gate's candidates),
    steadier than one interval where nothing moves; ``channels`` and ``layers``: the width and depth of its 3x3
    convolution stack."""

    windows: tuple[int, ...] = (6, 20, 40, 80)
    channels: int = 16
    layers: int = 4
    interval_reach: int = 0
    interval_windows: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "windows", tuple(int(w) for w in self.windows))
        object.__setattr__(self, "interval_windows", tuple(int(w) for w in self.interval_windows))
        if self.interval_windows and (not self.interval_reach or min(self.interval_windows) < 1):
            raise ValueError(f"interval_windows need an interval_reach and positive plane counts, got "
                             f"{self.interval_windows} at reach {self.interval_reach}")
        if not self.windows or min(self.windows) < 1:
            raise ValueError(f"windows must be positive plane counts, got {self.windows}")
        if self.channels < 1 or self.layers < 2:
            raise ValueError(f"channels must be >= 1 and layers >= 2, got {self.channels}, {self.layers}")
        if self.interval_reach < 0:
            raise ValueError(f"interval_reach must be >= 0, got {self.interval_reach}")

    @property
    def rate_channels(self) -> int:
        """Rate planes the stage reads: one per window, then TFI when ``interval_reach`` > 0, then one per
        ``interval_windows``."""
        return len(self.windows) + int(self.interval_reach > 0) + len(self.interval_windows)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (no ``interval_reach`` key without TFI input, no ``interval_windows`` without them:
        older cards stay valid)."""
        out = asdict(self)
        out["windows"] = list(self.windows)
        out["interval_windows"] = list(self.interval_windows)
        for key in ("interval_reach", "interval_windows"):
            if not out[key]:
                del out[key]
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DetailConfig:
        """Rebuild from ``to_dict`` output; unknown keys raise ``KeyError`` naming them."""
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise KeyError(f"unknown detail config keys {unknown}")
        return cls(**{**data, "windows": tuple(data.get("windows", cls.windows)),
                      "interval_windows": tuple(data.get("interval_windows", ()))})


def block_mean(x: torch.Tensor) -> torch.Tensor:
    """2x2 block means of (B,C,H,W) (even H, W), spread back to every pixel of the block."""
    return F.interpolate(mean_2x2(x), scale_factor=2.0, mode="nearest")


def upsample(binned: torch.Tensor) -> torch.Tensor:
    """Bilinear 2x upsampling, pixel centres aligned (each binned pixel covers a 2x2 block)."""
    return F.interpolate(binned, scale_factor=2.0, mode="bilinear", align_corners=False)


def to_block_levels(image: torch.Tensor, binned: torch.Tensor) -> torch.Tensor:
    """``image`` (B,1,2h,2w), >= 0, rescaled per 2x2 block so that every block's mean is its ``binned``
    pixel (B,1,h,w): its shape inside the block kept, the binned level exact. A block of ``image`` that
    is 0 throughout stays 0."""
    level = F.interpolate(binned, scale_factor=2.0, mode="nearest")
    return image * (level / block_mean(image).clamp(min=1e-30))


class DetailNet(nn.Module):
    """The detail stage; ``forward(binned, rates)`` -> the full-resolution linear frame."""

    def __init__(self, config: DetailConfig = DetailConfig()) -> None:
        super().__init__()
        self.config = config
        inputs = 1 + 2 * config.rate_channels
        layers: list[nn.Module] = []
        for k in range(config.layers - 1):
            layers += [nn.Conv2d(inputs if k == 0 else config.channels, config.channels, 3, padding=1),
                       nn.ReLU(inplace=True)]
        layers.append(nn.Conv2d(config.channels, 1, 3, padding=1))
        self.body = nn.Sequential(*layers)
        # one spike's worth per rate plane, 1 / (4 * window): a block holds 4 * window trials over a window, and this
        # keeps the relative deviation finite in a block that never fired (made once; not a weight, not saved)
        self.register_buffer("spike_floor", torch.tensor([1.0 / (4 * w) for w in self.rate_windows],
                                                         dtype=torch.float32).reshape(1, -1, 1, 1), persistent=False)
        with torch.no_grad():  # start as bilinear upsampling rescaled to the block levels
            layers[-1].weight.zero_()
            layers[-1].bias.zero_()

    def features(self, up: torch.Tensor, rates: torch.Tensor, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """(B, 1 + 2K, H, W), channels-last, in ``dtype``: the bilinear deviation from the block level, then per rate
        plane (each window, then each TFI, read as if over 2 * ``interval_reach`` planes) the rate's relative
        deviation from its block mean and the block's spike count (mu-law compressed). Every plane is computed in
        float32, all at once, and written once into the convolutions' layout and dtype (bf16 rounds as autocast
        would)."""
        level = F.interpolate(mean_2x2(up), scale_factor=2.0, mode="nearest")
        planes = len(self.rate_windows)
        r = rates[:, :planes].float()
        mean = block_mean(r)  # a block's mean rate: its spike count per trial
        out = torch.empty((r.shape[0], 1 + 2 * planes, *r.shape[2:]), dtype=dtype, device=r.device,
                          memory_format=torch.channels_last)
        out[:, :1] = (up / level.clamp(min=1e-12) - 1.0).clamp(-1.0, 1.0) * (level > 0)
        out[:, 1::2] = ((r - mean) / (mean + self.spike_floor)).clamp(-1.0, 3.0)
        out[:, 2::2] = mu_law(mean, 255.0)
        return out

    @property
    def rate_windows(self) -> tuple[int, ...]:
        """The planes each rate input counts over: each window, then each TFI, read as if over 2 * ``interval_reach``
        planes."""
        intervals = 1 + len(self.config.interval_windows) if self.config.interval_reach else 0
        return self.config.windows + (2 * self.config.interval_reach,) * intervals

    def widened(self, config: DetailConfig) -> DetailNet:
        """A stage of ``config`` (this one's with more ``interval_windows``) that computes this one's frames: its
        first convolution reads the new inputs with zero weights, so a fine-tune starts from this stage exactly."""
        if replace(config, interval_windows=self.config.interval_windows) != self.config or \
                config.interval_windows[: len(self.config.interval_windows)] != self.config.interval_windows:
            raise ValueError(f"a stage of {self.config} widens only by more interval_windows, not to {config}")
        wider = DetailNet(config)
        state = self.state_dict()
        first = state["body.0.weight"]
        state["body.0.weight"] = torch.cat([first, first.new_zeros(first.shape[0], 2 * (config.rate_channels
                                                                                    - self.config.rate_channels),
                                                                   *first.shape[2:])], dim=1)
        wider.load_state_dict(state)
        return wider

    def forward(self, binned: torch.Tensor, rates: torch.Tensor) -> torch.Tensor:
        """``binned`` (B,1,h,w) linear; ``rates`` (B,K,2h,2w) raw spike rates per plane over each of the
        config's windows, then TFI and its ``interval_windows`` when it reads them (``config.rate_channels``) ->
        (B,1,2h,2w) linear, >= 0 and finite."""
        binned = torch.nan_to_num(binned.float(), nan=0.0, posinf=0.0, neginf=0.0).clamp(min=0.0)
        rates = torch.nan_to_num(rates.float(), nan=0.0, posinf=0.0, neginf=0.0).clamp(0.0, 1.0)
        up = upsample(binned)
        # channels-last: oneDNN's kernels for so few channels are several times faster so; the engine holds the
        # weights channels-last anyway, this makes the stage as loaded (training) run the same kernels. In the
        # weights' dtype: bf16 weights (``detail_inference_copy``) run under autocast, which would cast the features
        features = self.features(up, rates, self.body[0].weight.dtype)
        d = self.body(features).float()  # float32 whatever the body ran in: 1 + d keeps its digits
        d = d - block_mean(d)  # mean 1 + d over a block is 1, so no block of the factor is 0 throughout
        return to_block_levels(up * (1.0 + d).clamp(min=0.0), binned)
