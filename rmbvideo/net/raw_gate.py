"""Raw-interval gate: on a 1-bit capture, RMB-Net's binned frame mixed per pixel with TFI of the raw planes.

The binned counts blur dim fine texture of a slow, bright scene that single inter-spike intervals at full resolution
still resolve (on the development pans TFI on the raw capture, 2x2-averaged, has 1.1-2.4x less error than RMB-Net
between 0.003 and 0.03 of a threshold per plane), while TFI is far noisier everywhere else. A small network
reads a few features of the two images (their levels and ratio, their local roughness, how much the
binned frame changed since the last one, the convention) and gives the share of TFI in the output: 0 keeps
RMB-Net's frame. With a ``long_window`` the gate has a second TFI candidate over more central planes (steadier where
nothing moves, smeared where things do) and three more features (its level, its ratio to the first TFI: motion, its
roughness); the shares of the three images are a softmax. With ``frame_features`` it also reads how far the
candidates disagree over the whole frame: far in a dark, noisy frame (TFI's shot noise) or one where much moves (the
long TFI smears), little where TFI reads the whole frame well (the real-video streams: 0.03-0.05 against 0.03-0.6 on
the simulated captures), which a pixel's own features, seeing only its neighbourhood, cannot tell. With a
``kernel`` above 1 its convolutions read the features around each pixel too, so a lone pixel where TFI disagrees
(noise) and a region where it does (motion, or detail the binned frame blurs) get different shares. All images are
light at the binned size; TFI is read as light per raw pixel (``tfi_light``) before its 2x2 average, as the
evaluation reads it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from rmbvideo.net.blend import box_intensity
from rmbvideo.net.pooling import mean_3x3

#: Per-pixel inputs of the gate, in this order (``gate_features``).
FEATURES = ("binned level", "TFI level", "log ratio", "TFI roughness", "binned roughness", "binned change",
            "rate convention")
#: The features a gate with a ``long_window`` reads after ``FEATURES``.
LONG_FEATURES = ("long TFI level", "long/short TFI log ratio", "long TFI roughness")
#: The features a gate with ``frame_features`` reads last, the same at every pixel of a frame: the frame's mean
#: absolute log ratio of TFI to the binned frame, and (with a ``long_window``) of the long TFI to the first.
FRAME_FEATURES = ("frame TFI/binned disagreement", "frame long/short TFI disagreement")
#: Initial bias of the gate's logit: a new gate keeps RMB-Net's frame (TFI's share about 0.05).
INITIAL_LOGIT = -3.0


@dataclass(frozen=True)
class RawGateConfig:
    """``hidden``: width of the gate's network; ``tfi_reach``: raw planes TFI searches on each side of a frame's
    centre (``rmbvideo.recon.classical.Tfi``'s ``max_reach``; 200 reads down to about 1/400 of a spike a plane);
    ``tfi_window``: its central planes (``Tfi``'s ``window``: 0 one interval, M the whole intervals covering M);
    ``long_window``: the central planes of a second TFI candidate (0: none; else more than ``tfi_window``);
    ``frame_features``: whether the gate also reads the ``FRAME_FEATURES``; ``kernel``: the size of its convolutions:
    1 reads each pixel's features alone (one hidden layer), an odd k > 1 the features around it through two k x k
    layers, so it can tell a lone pixel where TFI disagrees (its noise) from a region (motion, or detail the binned
    frame blurs)."""

    hidden: int = 16
    tfi_reach: int = 200
    tfi_window: int = 0
    long_window: int = 0
    frame_features: bool = False
    kernel: int = 1

    def __post_init__(self) -> None:
        if self.hidden < 1 or self.tfi_reach < 1 or self.tfi_window < 0:
            raise ValueError(f"hidden and tfi_reach must be >= 1 and tfi_window >= 0, got {self.hidden}, "
                             f"{self.tfi_reach}, {self.tfi_window}")
        if self.kernel < 1 or self.kernel % 2 == 0:
            raise ValueError(f"kernel must be odd and >= 1, got {self.kernel}")
        if self.long_window and self.long_window <= self.tfi_window:
            raise ValueError(f"long_window must be 0 or more than tfi_window ({self.tfi_window}), got "
                             f"{self.long_window}")

    @property
    def candidates(self) -> int:
        """How many TFI images the gate mixes into RMB-Net's frame (1, or 2 with a ``long_window``)."""
        return 2 if self.long_window else 1

    @property
    def feature_count(self) -> int:
        """How many features the gate reads per pixel (``gate_features``)."""
        frame = (1 + bool(self.long_window)) if self.frame_features else 0
        return len(FEATURES) + (len(LONG_FEATURES) if self.long_window else 0) + frame

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (no ``tfi_window``, ``long_window`` or ``frame_features`` key at 0 or False, no
        ``kernel`` at 1: cards written before they existed stay as they are)."""
        out = asdict(self)
        for key in ("tfi_window", "long_window", "frame_features"):
            if not out[key]:
                del out[key]
        if out["kernel"] == 1:
            del out["kernel"]
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RawGateConfig:
        """Rebuild from ``to_dict`` output; unknown keys raise ``KeyError`` naming them."""
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise KeyError(f"unknown raw-gate config keys {unknown}")
        return cls(**data)


def tfi_light(rate: torch.Tensor, convention: float, tabulated: bool) -> torch.Tensor:
    """Light (charge per raw plane / threshold) of raw TFI rates per pixel: the rate itself in the rate convention
    (the raw planes are not clamped), else a reset-to-zero pixel's inverse response (the emission model's table when
    ``tabulated``, else the closed form r / (1 - r/2)), as RMB-Net's box candidates read a camera."""
    rate = torch.nan_to_num(rate.float(), nan=0.0).clamp(0.0, 1.0)
    return rate if convention == 1 else box_intensity(rate, 0.0, tabulated)


def _roughness(image: torch.Tensor) -> torch.Tensor:
    """log of the 3x3 standard deviation over the 3x3 mean (edges replicated): texture or noise around a pixel."""
    padded = F.pad(image, (1, 1, 1, 1), mode="replicate")
    mean = mean_3x3(padded)
    spread = (mean_3x3(padded * padded) - mean * mean).clamp(min=0.0).sqrt()
    return torch.log((spread + 1e-4) / (mean + 1e-3))


def _frame_disagreement(log_ratio: torch.Tensor) -> torch.Tensor:
    """log of the mean over each frame of |``log_ratio``| (B,1,H,W), as a (B,1,H,W) image."""
    return torch.log(log_ratio.abs().mean(dim=(2, 3), keepdim=True) + 1e-3).expand_as(log_ratio)


def gate_features(binned: torch.Tensor, tfi: torch.Tensor, previous: torch.Tensor, convention: float,
                  long_tfi: torch.Tensor | None = None, frame: bool = False) -> torch.Tensor:
    """(B, features, H, W) from the binned frame, the 2x2-averaged TFI light and the previous binned frame
    (B,1,H,W each, linear, >= 0); ``convention``: 0 a reset-to-zero pixel, 1 the rate convention. With ``long_tfi``
    (the long-window candidate, alike) the ``LONG_FEATURES`` follow, and with ``frame`` the ``FRAME_FEATURES``."""
    features = [torch.log(binned + 1e-4), torch.log(tfi + 1e-4), torch.log((tfi + 1e-3) / (binned + 1e-3)),
                _roughness(tfi), _roughness(binned), torch.log((binned - previous).abs() / (binned + 1e-3) + 1e-3),
                torch.full_like(binned, float(convention))]
    if long_tfi is not None:
        features += [torch.log(long_tfi + 1e-4), torch.log((long_tfi + 1e-3) / (tfi + 1e-3)), _roughness(long_tfi)]
    if frame:  # the log ratios are features 2 (TFI over binned) and, with a long window, len(FEATURES) + 1
        features.append(_frame_disagreement(features[2]))
        if long_tfi is not None:
            features.append(_frame_disagreement(features[len(FEATURES) + 1]))
    return torch.cat(features, dim=1)


class RawGate(nn.Module):
    """The gate: a small convolutional network on standardised ``gate_features`` (per pixel at ``kernel`` 1);
    ``forward`` -> the mixed frame."""

    def __init__(self, config: RawGateConfig = RawGateConfig()) -> None:
        super().__init__()
        self.config = config
        count = config.feature_count
        self.register_buffer("feature_mean", torch.zeros(count))
        self.register_buffer("feature_std", torch.ones(count))
        if config.kernel == 1:
            self.body = nn.Sequential(nn.Conv2d(count, config.hidden, 1), nn.ReLU(),
                                      nn.Conv2d(config.hidden, config.candidates, 1))
        else:  # edges replicated, as the features' own 3x3 statistics read them
            def conv(inputs: int) -> nn.Conv2d:
                return nn.Conv2d(inputs, config.hidden, config.kernel, padding=config.kernel // 2,
                                 padding_mode="replicate")
            self.body = nn.Sequential(conv(count), nn.ReLU(), conv(config.hidden), nn.ReLU(),
                                      nn.Conv2d(config.hidden, config.candidates, 1))
        with torch.no_grad():
            self.body[-1].bias.fill_(INITIAL_LOGIT)

    def share(self, features: torch.Tensor) -> torch.Tensor:
        """The TFI candidates' shares (B, candidates, H, W), each in [0, 1] and together at most 1, from
        ``gate_features``: a sigmoid of one logit, or a softmax of the logits beside RMB-Net's fixed 0."""
        scale = self.feature_std.clamp(min=1e-6).reshape(1, -1, 1, 1)
        # channels-last: oneDNN's kernels for so few channels run 1.04-1.09x faster so (full_shares_checks.py gate-cost)
        standard = ((features - self.feature_mean.reshape(1, -1, 1, 1)) / scale).contiguous(
            memory_format=torch.channels_last)
        logits = self.body(standard)
        if self.config.candidates == 1:
            return torch.sigmoid(logits)
        return torch.softmax(torch.cat([torch.zeros_like(logits[:, :1]), logits], dim=1), dim=1)[:, 1:]

    def forward(self, binned: torch.Tensor, tfi: torch.Tensor, previous: torch.Tensor, convention: float,
                long_tfi: torch.Tensor | None = None) -> torch.Tensor:
        """The frame (B,1,H,W), linear, >= 0 and finite: ``binned`` where the gate keeps it, ``tfi`` (light, 2x2-
        averaged) and ``long_tfi`` (the long-window candidate, with a ``long_window`` only) where it trusts them;
        ``previous`` is the binned frame before (the frame itself at a clip's start)."""
        if (long_tfi is None) != (not self.config.long_window):
            raise ValueError("long_tfi must be given exactly when the gate has a long_window")
        return self.mix(binned, torch.cat([tfi, *(() if long_tfi is None else (long_tfi,))], dim=1), previous,
                        convention)[0]

    def mix(self, binned: torch.Tensor, candidates: torch.Tensor, previous: torch.Tensor,
            convention: float) -> tuple[torch.Tensor, torch.Tensor]:
        """``forward`` with the TFI candidates stacked (B, ``config.candidates``, H, W), returning the frame and the
        candidates' shares (B, candidates, H, W) in it."""
        if candidates.shape[1] != self.config.candidates:
            raise ValueError(f"the gate mixes {self.config.candidates} TFI candidates, got {candidates.shape[1]}")
        clean = [torch.nan_to_num(x.float(), nan=0.0, posinf=0.0, neginf=0.0).clamp(min=0.0)
                 for x in (binned, candidates, previous)]
        long_tfi = clean[1][:, 1:] if self.config.long_window else None
        share = self.share(gate_features(clean[0], clean[1][:, :1], clean[2], convention, long_tfi,
                                         frame=self.config.frame_features))
        mixed = (1.0 - share.sum(1, keepdim=True)) * clean[0] + (share * clean[1]).sum(1, keepdim=True)
        return mixed, share
