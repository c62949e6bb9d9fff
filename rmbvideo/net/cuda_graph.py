"""Replaying a fixed sequence of small CUDA kernels as one CUDA graph: a recurrence stepping through a run of frames
launches a few dozen tiny kernels a frame, whose launch cost (Python included) exceeds their work on a GPU."""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable

import torch

Tensors = tuple[torch.Tensor, ...]


def _signature(tensors: Tensors) -> tuple:
    return tuple((tuple(t.shape), t.stride(), t.dtype, t.device) for t in tensors)


class GraphCache:
    """Calls ``fn(*tensors) -> tuple of tensors`` through CUDA graphs, one per input signature (shapes, strides,
    dtypes) seen a second time, at most ``capacity`` of them (the least recently used is dropped). A signature seen
    once runs eagerly, so a clip's one-off last run costs no capture. Outputs are copies, never the graph's memory.

    ``fn`` must be a pure function of its tensors and of tensors that keep their address (a module's weights), free
    of host synchronisation, and run without autograd. Anything but CUDA tensors runs eagerly; a capture that fails
    raises (the caller may run ``fn`` eagerly instead)."""

    def __init__(self, fn: Callable[..., Tensors], capacity: int = 4) -> None:
        self.fn = fn
        self.capacity = capacity
        self._seen: set[tuple] = set()
        self._graphs: OrderedDict[tuple, tuple[torch.cuda.CUDAGraph, Tensors, Tensors]] = OrderedDict()

    def __call__(self, *tensors: torch.Tensor) -> Tensors:
        if not all(t.is_cuda for t in tensors) or torch.is_grad_enabled():
            return self.fn(*tensors)
        key = _signature(tensors)
        if key not in self._graphs:
            if key not in self._seen:
                self._seen.add(key)
                return self.fn(*tensors)
            self._graphs[key] = self._capture(tensors)
            while len(self._graphs) > self.capacity:
                self._graphs.popitem(last=False)
        self._graphs.move_to_end(key)
        graph, inputs, outputs = self._graphs[key]
        for static, value in zip(inputs, tensors):
            static.copy_(value)
        graph.replay()
        return tuple(t.clone() for t in outputs)

    def _capture(self, tensors: Tensors) -> tuple[torch.cuda.CUDAGraph, Tensors, Tensors]:
        """Static copies of ``tensors``, two warm-up calls on a side stream (lazy initialisation, autotuning), then
        the capture."""
        inputs = tuple(torch.empty_strided(t.shape, t.stride(), dtype=t.dtype, device=t.device).copy_(t)
                       for t in tensors)
        side = torch.cuda.Stream(device=inputs[0].device)
        side.wait_stream(torch.cuda.current_stream(inputs[0].device))
        with torch.cuda.stream(side):
            for _ in range(2):
                self.fn(*inputs)
        torch.cuda.current_stream(inputs[0].device).wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            outputs = self.fn(*inputs)
        return graph, inputs, outputs
