"""Area means as sums of strided views: the values of ``F.avg_pool2d`` bit for bit (the same additions in the same
order, then the same division), 2.5-4x faster on few-channel CPU tensors, where PyTorch's pooling kernel works a
channel at a time (measured on the AVX2 host, one thread: a 400x250 single-channel 2x2 mean 217 -> 78 us, a
202x127 3x3 mean 277 -> 101 us)."""

from __future__ import annotations

import torch


def mean_2x2(x: torch.Tensor) -> torch.Tensor:
    """``F.avg_pool2d(x, 2)`` of (..., H, W): 2x2 block means, an odd last row or column dropped."""
    x = x[..., : x.shape[-2] // 2 * 2, : x.shape[-1] // 2 * 2]
    return (((x[..., 0::2, 0::2] + x[..., 0::2, 1::2]) + x[..., 1::2, 0::2]) + x[..., 1::2, 1::2]) / 4


def mean_3x3(x: torch.Tensor) -> torch.Tensor:
    """``F.avg_pool2d(x, 3, stride=1)`` of (..., H, W): the mean of each 3x3 neighbourhood, (..., H - 2, W - 2)."""
    h, w = x.shape[-2] - 2, x.shape[-1] - 2
    total = x[..., :h, :w]
    for i, j in ((0, 1), (0, 2), (1, 0), (1, 1), (1, 2), (2, 0), (2, 1), (2, 2)):
        total = total + x[..., i : i + h, j : j + w]
    return total / 9
