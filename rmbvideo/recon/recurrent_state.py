"""RMB-Net's recurrent state as named CPU tensors and back, bit for bit: what a resumable run saves
(``rmbvideo.recon.resume``) to continue an interrupted run exactly."""

from __future__ import annotations

import torch

from rmbvideo.net.decoder import DecoderState


def state_tensors(state: DecoderState) -> dict[str, torch.Tensor]:
    """A copy of the decoder's recurrent state on the CPU, by name (``scale<k>.h``/``.c``, coarsest first), each packed
    in its own memory layout: a channels-last tensor is stored as NHWC (``.nhwc``), so it comes back with the same
    strides and the next step's arithmetic is the same to the bit."""
    out = {}
    for k, pair in enumerate(state):
        for part, tensor in zip("hc", pair):
            tensor = tensor.detach().to("cpu", copy=True)
            if tensor.is_contiguous():
                out[f"scale{k}.{part}"] = tensor
            else:
                out[f"scale{k}.{part}.nhwc"] = tensor.permute(0, 2, 3, 1).contiguous()
    return out


def state_from_tensors(tensors: dict[str, torch.Tensor], device: torch.device) -> DecoderState:
    """``state_tensors``' tensors as the decoder's state on ``device``, in their own layouts."""
    def one(name: str) -> torch.Tensor:
        if name in tensors:
            return tensors[name].to(device)
        return tensors[f"{name}.nhwc"].to(device).permute(0, 3, 1, 2)

    return tuple((one(f"scale{k}.h"), one(f"scale{k}.c")) for k in range(3))  # type: ignore[return-value]
