"""Decoder of RMB-Net: from F_bar_ms(i) at 1/8 scale back to the input resolution, with skip
links from the reference frame's F_ms(i) and one ConvLSTM layer per scale (three in all)."""

from __future__ import annotations

from typing import Callable

import torch
import torch.nn.functional as F
from torch import nn

from rmbvideo.net import layout
from rmbvideo.net.convlstm import ConvLSTMCell, LstmState

DecoderState = tuple[LstmState, LstmState, LstmState]


def _conv_relu(in_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(in_channels, out_channels, 3, padding=1), nn.ReLU(inplace=True))


def upsample2x(x: torch.Tensor) -> torch.Tensor:
    """Bilinear 2x upsampling computed in float32: for bf16 features the same values once the next conv's autocast
    rounds them (a bf16 value times 1/4 or 3/4 is exact in float32; tested), and PyTorch's CPU kernel for channels-last
    bf16 is 1.5-3x slower than for float32."""
    return F.interpolate(x.float(), scale_factor=2.0, mode="bilinear", align_corners=False)


class Decoder(nn.Module):
    """Upsampling decoder; ``forward`` returns the raw head output z (B,``outputs``,H,W) and the new state.

    Per scale s (1/8, then 1/4, then 1/2): fuse the upsampled coarser result with the reference
    F_ms(i) at s (at 1/8 with F_bar_ms(i)), run the ConvLSTM of s. At full resolution the
    compressed reference inputs (I_s(i), I_m(i)) are concatenated before the head, so fine detail
    lost by pooling can come back.
    """

    def __init__(self, channels: tuple[int, int, int], lstm_kernel: int, input_channels: int = 2,
                 outputs: int = 1, cell_decay: float = 1.0) -> None:
        super().__init__()
        c1, c2, c3 = channels
        self.lstm3 = ConvLSTMCell(2 * c3, c3, lstm_kernel, cell_decay)
        self.up3 = _conv_relu(c3, c2)
        self.fuse2 = _conv_relu(2 * c2, c2)
        self.lstm2 = ConvLSTMCell(c2, c2, lstm_kernel, cell_decay)
        self.up2 = _conv_relu(c2, c1)
        self.fuse1 = _conv_relu(2 * c1, c1)
        self.lstm1 = ConvLSTMCell(c1, c1, lstm_kernel, cell_decay)
        self.up1 = _conv_relu(c1, c1)
        self.head = nn.Sequential(_conv_relu(c1 + input_channels, c1), nn.Conv2d(c1, outputs, 3, padding=1))

    def forward(
        self,
        fused: torch.Tensor,
        reference: list[torch.Tensor],
        inputs: torch.Tensor | None,
        state: DecoderState | None,
        run: bool = False,
        graphed: bool = False,
    ) -> tuple[torch.Tensor | None, DecoderState]:
        """One step, or with ``run`` K consecutive steps of batch size 1 stacked along the batch (K,...): then every
        layer but the ConvLSTMs' recurrences runs on all K at once (``ConvLSTMCell.run``, ``graphed`` as there); the
        state is the last step's. ``inputs`` None: the state alone, z None (the layers after the last ConvLSTM feed
        only the output)."""
        s3, s2, s1 = state if state is not None else (None, None, None)
        def recurrent(cell: ConvLSTMCell) -> Callable[[torch.Tensor, LstmState | None], tuple[torch.Tensor, LstmState]]:
            return (lambda x, s: cell.run(x, s, graphed)) if run else cell

        lstm3, lstm2, lstm1 = (recurrent(cell) for cell in (self.lstm3, self.lstm2, self.lstm1))
        x, s3 = lstm3(layout.cat([fused, reference[2]], dim=1), s3)
        x = self.up3(upsample2x(x))
        x, s2 = lstm2(self.fuse2(layout.cat([x, reference[1]], dim=1)), s2)
        x = self.up2(upsample2x(x))
        x, s1 = lstm1(self.fuse1(layout.cat([x, reference[0]], dim=1)), s1)
        if inputs is None:
            return None, (s3, s2, s1)
        x = self.up1(upsample2x(x))
        # both parts channels-last (as x is), so the cat writes the layout the head's conv reads
        z = self.head(layout.cat([x, layout.contiguous(inputs.to(x.dtype), torch.channels_last)], dim=1))
        return z, (s3, s2, s1)
