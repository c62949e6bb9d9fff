"""Convolutional LSTM cell (Shi et al. 2015), the recurrent layer that carries state S_p(i-1)
from step i-1 to step i for flicker-free video (paper Sec. 4.2)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from rmbvideo.net import layout
from rmbvideo.net.cuda_graph import GraphCache

LstmState = tuple[torch.Tensor, torch.Tensor]


def _tanh(x: torch.Tensor) -> torch.Tensor:
    """tanh(x) = 2 sigmoid(2x) - 1 (the same function to within float rounding): PyTorch's CPU tanh is
    about 5x slower than its sigmoid on the AVX-512 machines measured."""
    s = torch.sigmoid(2.0 * x)
    return s * 2.0 - 1.0 if s.requires_grad else s.mul_(2.0).sub_(1.0)  # autograd needs s unchanged


class ConvLSTMCell(nn.Module):
    """One ConvLSTM layer; the state is (h, c), zeros when ``None``.

    The forget-gate bias starts at 1 so the state neither explodes nor is forgotten at once. ``decay`` scales the
    cell state before each step (``RmbNetConfig.cell_decay``; 1: none).
    """

    def __init__(self, in_channels: int, hidden: int, kernel: int, decay: float = 1.0) -> None:
        super().__init__()
        self.hidden = hidden
        self.decay = decay
        self.gates = nn.Conv2d(in_channels + hidden, 4 * hidden, kernel, padding=kernel // 2)
        with torch.no_grad():
            self.gates.bias.zero_()
            self.gates.bias[hidden : 2 * hidden].fill_(1.0)

    def forward(self, x: torch.Tensor, state: LstmState | None) -> tuple[torch.Tensor, LstmState]:
        if state is None:
            zeros = x.new_zeros(x.shape[0], self.hidden, *x.shape[-2:])
            state = (zeros, zeros)
        h, c = state
        return self._update(self.gates(layout.cat([x, h.to(x.dtype)], dim=1)), c)

    def run(self, x: torch.Tensor, state: LstmState | None, graphed: bool = False) -> tuple[torch.Tensor, LstmState]:
        """``forward`` over a sequence x (K,C,H,W) of batch size 1, one step per item -> h (K,hidden,H,W) and the
        last state: the gates' input part (a convolution of a concatenation is the sum of its parts' convolutions)
        runs on all K at once, and only the hidden part steps through them in order. ``graphed``: on a GPU without
        autograd, the steps replay as one CUDA graph per run shape seen twice (``GraphCache``; the same values)."""
        weight = self.gates.weight
        gates_x = F.conv2d(x, weight[:, : x.shape[1]], self.gates.bias, padding=self.gates.padding)
        if graphed and gates_x.is_cuda:
            if state is None:  # a zero state is the same as none: its convolution adds exact zeros
                h = gates_x.new_zeros((1, self.hidden, *gates_x.shape[-2:]))
                layout = torch.channels_last if gates_x.is_contiguous(memory_format=torch.channels_last) else None
                state = (h if layout is None else h.contiguous(memory_format=layout), h)
            if "_graphs" not in self.__dict__:
                self._graphs = GraphCache(self._recurrence)
            outputs, h, c = self._graphs(gates_x, state[0].to(x.dtype), state[1])
            return outputs, (h, c)
        hidden_weight = weight[:, x.shape[1] :].contiguous(memory_format=torch.channels_last)
        outputs = []
        for k in range(x.shape[0]):
            gates = gates_x[k : k + 1]
            if state is None:
                c = torch.zeros_like(gates[:, : self.hidden], memory_format=torch.contiguous_format)
            else:
                h, c = state
                gates = gates + F.conv2d(h.to(x.dtype), hidden_weight, padding=self.gates.padding)
            h, state = self._update(gates, c)
            outputs.append(h)
        return torch.cat(outputs), state

    def _recurrence(self, gates_x: torch.Tensor, h: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The hidden part of ``run`` from the state (h, c), as a pure function of tensors for a CUDA graph: every
        step's h (K,hidden,H,W) and the last h and c."""
        weight = self.gates.weight
        hidden_weight = weight[:, weight.shape[1] - self.hidden :].contiguous(memory_format=torch.channels_last)
        outputs = []
        for k in range(gates_x.shape[0]):
            gates = gates_x[k : k + 1] + F.conv2d(h.to(gates_x.dtype), hidden_weight, padding=self.gates.padding)
            h, (_, c) = self._update(gates, c)
            outputs.append(h)
        return torch.cat(outputs), h, c

    def _update(self, gates: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, LstmState]:
        """The gate arithmetic: the 4*hidden gate pre-activations and the cell state -> h and the new (h, c)."""
        # On a channels-last tensor each gate is a strided channel slice (inner loops of ``hidden``
        # elements): the gate arithmetic runs 3-5x faster on a contiguous copy, and only h goes back.
        channels_last = not gates.is_contiguous() and gates.is_contiguous(memory_format=torch.channels_last)
        i, f, o, g = gates.contiguous().chunk(4, dim=1)
        if self.decay != 1.0:
            c = c * self.decay
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * _tanh(g)
        h = torch.sigmoid(o) * _tanh(c)
        if channels_last:
            h = h.contiguous(memory_format=torch.channels_last)
        return h, (h, c)
