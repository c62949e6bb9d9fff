"""Cross-bit (XBA, paper Eqns. 9-11) and cross-time (XTA, Eqn. 12) attention, plus the plain
fusions used by the "without XBA" / "without XTA" ablations.

The mask projection F(C(a, b)) is "two conv layers on the concatenation". A convolution of a
concatenation is the sum of convolutions of its parts, so the first layer is split into one conv
per input: the per-frame parts are computed once per frame and every pair only adds them, applies
ReLU and a 1x1 conv. All (2w+1)^2 pairs go through that second conv in one batched call (the
supplement's "cyclic shift to obtain (2w+1)^2 feature pairs"). XBA pair logits depend on a pair of
frames only, so a streaming engine can cache them across overlapping windows.

Tensor layout: stacks over window positions are (K, B, C, H, W); pair logits are (Q, K, B, C, H, W)
with one mask channel per feature channel (the masks multiply features element-wise, Eqn. 11);
``attend`` takes them one key at a time.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from rmbvideo.net import layout
from rmbvideo.net.activations import relu_

#: log2(e): e^x = 2^(x log2 e)
LOG2E = 1.4426950408889634


class PairProjection(nn.Module):
    """F(C(x_0, x_1, ...)): split first conv (one per input, bias on the first) + ReLU + 1x1 conv."""

    def __init__(self, in_channels: Sequence[int], hidden: int, out_channels: int, kernel: int) -> None:
        super().__init__()
        self.parts = nn.ModuleList(
            nn.Conv2d(c, hidden, kernel, padding=kernel // 2, bias=(i == 0)) for i, c in enumerate(in_channels)
        )
        self.out = nn.Conv2d(hidden, out_channels, 1)

    def part(self, index: int, x: torch.Tensor) -> torch.Tensor:
        """First-layer contribution of input ``index`` (computed once per frame)."""
        return self.parts[index](x)

    def combine(self, summed: torch.Tensor) -> torch.Tensor:
        """Mask logits from the summed first-layer parts; any leading dims are batched in one call. ``summed`` is
        consumed: without gradients its ReLU is taken in place (``relu_``)."""
        lead = summed.shape[:-3]
        flat = summed.reshape(-1, *summed.shape[-3:])
        hidden = torch.relu(flat) if flat.requires_grad and torch.is_grad_enabled() else relu_(flat)
        return self.out(hidden).reshape(*lead, -1, *summed.shape[-2:])


def attend(logits: Sequence[torch.Tensor], values: Sequence[torch.Tensor],
           valid: Sequence[bool] | None = None) -> torch.Tensor:
    """SoftMax over keys (in float32) and weighted sum: ``logits[k]`` (Q,B,C,H,W) and ``values[k]``
    (B,C,H,W) per key k -> (Q,B,C,H,W).

    Keys are visited one at a time (running maximum, then exp-weighted sums): no stack of the window
    is built and no SoftMax runs across a strided key dimension, about twice as fast on CPU as both.
    ``valid`` (one bool per key) leaves keys out (window positions past a clip's edge); the maximum
    is subtracted first, so every weight is <= 1 and the denominator >= 1.
    """
    keys = [k for k in range(len(logits)) if valid is None or valid[k]]
    peak = logits[keys[0]]
    for k in keys[1:]:  # in the logits' own dtype (bf16 under autocast): a maximum is exact in any
        peak = torch.maximum(peak, logits[k])
    peak = peak.float()
    numerator = denominator = None
    for n, k in enumerate(keys):
        # bf16 - float32 promotes to float32: the cast and the subtraction in one pass; e^x as 2^(x log2 e), as
        # PyTorch's CPU exp2 is ~4x faster than exp
        weight = (logits[k] - peak).mul_(LOG2E).exp2_()
        if n == 0:  # float32 weights times the values promote to float32
            numerator, denominator = weight * values[k], weight
        else:  # accumulate in place (one pass each, no new tensors); the first weight is kept for autograd
            numerator = numerator.addcmul_(weight, values[k])
            denominator = denominator + weight if n == 1 else denominator.add_(weight)
    return (numerator / denominator).to(values[keys[0]].dtype)


def masked_mean(x: torch.Tensor, valid: Sequence[bool] | None) -> torch.Tensor:
    """Mean over dim 0 of the positions where ``valid`` (one bool per position) is True (all when None)."""
    if valid is None or all(valid):
        return x.mean(dim=0)
    return x[[k for k, ok in enumerate(valid) if ok]].mean(dim=0)


class CrossBitAttention(nn.Module):
    """XBA: masks from pairs (F_s(q), F_m(k)), SoftMax over k, weighted sum of F_m(k), then
    concat with F_s(q) and a 1x1 conv -> F_ms(q)."""

    def __init__(self, channels: int, hidden: int, kernel: int) -> None:
        super().__init__()
        self.proj = PairProjection((channels, channels), hidden, channels, kernel)
        self.reduce = nn.Conv2d(2 * channels, channels, 1)

    def query_part(self, f_s: torch.Tensor) -> torch.Tensor:
        """Per-frame first-layer term of F_s(q)."""
        return self.proj.part(0, f_s)

    def key_part(self, f_m: torch.Tensor) -> torch.Tensor:
        """Per-frame first-layer term of F_m(k)."""
        return self.proj.part(1, f_m)

    def pair_logits(self, query_parts: torch.Tensor, key_parts: torch.Tensor) -> torch.Tensor:
        """Logits of the pairs (query_parts[p], key_parts[p]), (P, B, Ch, H, W) each (or one query part
        broadcast over P) -> (P, B, C, H, W)."""
        return self.proj.combine(query_parts + key_parts)

    def fuse(self, f_s: torch.Tensor, f_m: Sequence[torch.Tensor], logits: Sequence[torch.Tensor],
             valid: Sequence[bool] | None = None) -> torch.Tensor:
        """F_ms for queries ``f_s`` (Q,B,C,H,W) over keys ``f_m[k]`` (B,C,H,W) with ``logits[k]``
        (Q,B,C,H,W) per key; keys where ``valid`` is False are left out."""
        f_m_hat = attend(logits, f_m, valid)
        q = f_s.shape[0]
        mixed = layout.cat([f_s, f_m_hat], dim=2).flatten(0, 1)
        return self.reduce(mixed).unflatten(0, (q, -1))


class PlainBitFusion(nn.Module):
    """"Without XBA" ablation: F_ms(q) = 1x1 conv of the concatenation (F_s(q), F_m(q))."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.reduce = nn.Conv2d(2 * channels, channels, 1)

    def forward(self, f_s: torch.Tensor, f_m: torch.Tensor) -> torch.Tensor:
        return self.reduce(torch.cat([f_s, f_m], dim=1))


class CrossTimeAttention(nn.Module):
    """XTA: masks from pairs (F_ms(q), F_ms(k)) and the window bias B(i), SoftMax over k,
    weighted sum of F_ms(k), then the mean over q -> F_bar_ms(i).

    Eqn. 12 adds B(i) (the temporal mean of F_ms) to every logit of the SoftMax over k, where it
    would cancel exactly; we feed B(i) into the projection's first layer as a third input instead,
    so the window context modulates the masks.
    """

    def __init__(self, channels: int, hidden: int, kernel: int) -> None:
        super().__init__()
        self.proj = PairProjection((channels, channels, channels), hidden, channels, kernel)

    def forward(self, f_ms: torch.Tensor, valid: Sequence[bool] | None = None) -> torch.Tensor:
        """F_bar_ms over the window (K,B,C,H,W); positions where ``valid`` is False are neither
        keys, queries nor part of the bias."""
        k = f_ms.shape[0]
        flat = f_ms.flatten(0, 1)
        bias = masked_mean(f_ms, valid)
        q_part = self.proj.part(0, flat).unflatten(0, (k, -1))
        k_part = self.proj.part(1, flat).unflatten(0, (k, -1))
        b_part = self.proj.part(2, bias)
        logits = self.proj.combine(q_part[:, None] + k_part[None] + b_part)
        return masked_mean(attend(logits.unbind(1), f_ms.unbind(0), valid), valid)


class TemporalMean(nn.Module):
    """"Without XTA" ablation: F_bar_ms(i) is the plain temporal mean of F_ms over the window."""

    def forward(self, f_ms: torch.Tensor, valid: Sequence[bool] | None = None) -> torch.Tensor:
        return masked_mean(f_ms, valid)
