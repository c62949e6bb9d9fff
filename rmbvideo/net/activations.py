"""ReLU for inference: bf16 through its bit pattern, since PyTorch's CPU kernel for bf16 ReLU runs at about a fifth
of the speed of an int16 clamp over the same bytes (measured on this project's AVX512-BF16 host)."""

from __future__ import annotations

import torch
from torch import nn


def relu_(x: torch.Tensor) -> torch.Tensor:
    """ReLU of ``x`` in place. A bf16 tensor that needs no gradient is clamped as int16: a bf16 value is negative
    exactly when its sign bit is set, which makes its int16 negative, and +0 is all zero bits, so every value but a
    NaN with its sign bit set (which reads 0) comes out as ``torch.relu_`` makes it."""
    if x.dtype == torch.bfloat16 and not (x.requires_grad and torch.is_grad_enabled()):
        x.view(torch.int16).clamp_min_(0)
        return x
    return torch.relu_(x)


class InplaceReLU(nn.Module):
    """``nn.ReLU(inplace=True)`` through ``relu_``: what the inference copy runs."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return relu_(x)
