"""The strided-view area means give ``F.avg_pool2d``'s values bit for bit, every size and channel count."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from rmbvideo.net.pooling import mean_2x2, mean_3x3


@pytest.mark.parametrize("shape", [(1, 1, 250, 400), (2, 5, 9, 13), (1, 3, 4, 4), (1, 1, 3, 3)])
def test_means_are_avg_pool_bit_for_bit(shape: tuple[int, ...]) -> None:
    generator = torch.Generator().manual_seed(sum(shape))
    x = torch.rand(shape, generator=generator) ** 6 * 1e3  # a wide range of magnitudes: rounding shows
    assert torch.equal(mean_2x2(x), F.avg_pool2d(x, 2))
    assert torch.equal(mean_3x3(x), F.avg_pool2d(x, 3, stride=1))
    channels_last = x.contiguous(memory_format=torch.channels_last)
    assert torch.equal(mean_2x2(channels_last), F.avg_pool2d(x, 2))
