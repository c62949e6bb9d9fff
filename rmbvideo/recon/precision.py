"""One precision policy for the network: bf16 where it is measured faster, fp32 elsewhere.

bf16 halves the bytes every convolution moves and doubles the multiply rate where the CPU has bf16
instructions (AVX512-BF16 or AMX): on this project's AMD EPYC (Zen 4) it runs RMB-Net 1.3x faster
than fp32 at the same accuracy (``rmbvideo bench``: 38.05 dB both). The encoders' first convolution
still reads the inputs in fp32 (``rmbvideo.net.encoder``). Elsewhere oneDNN emulates bf16 through
fp32 and it is slower, so "auto" keeps fp32 there. On CUDA the engine's frame-at-a-time kernels are
too small for bf16 to pay: autocast's casts are extra launches, and an H100 ran the network at
0.67-0.97x (200x125) and 0.72-0.87x (500x500) of its fp32 rate in two runs, so "auto" is fp32 on CUDA.
"""

from __future__ import annotations

import functools
from pathlib import Path

import torch

PRECISIONS = ("auto", "fp32", "bf16")
#: /proc/cpuinfo flags of x86 instructions that compute in bf16 natively.
NATIVE_BF16_FLAGS = ("avx512_bf16", "amx_bf16")


@functools.cache
def cpu_has_native_bf16(cpuinfo: Path = Path("/proc/cpuinfo")) -> bool:
    """Whether this CPU has bf16 arithmetic instructions (False where /proc/cpuinfo cannot be read)."""
    try:
        text = cpuinfo.read_text(errors="replace")
    except OSError:
        return False
    flags = set()
    for line in text.splitlines():
        if line.startswith("flags"):
            flags.update(line.partition(":")[2].split())
    return any(flag in flags for flag in NATIVE_BF16_FLAGS)


def uses_bf16(precision: str, device: torch.device) -> bool:
    """Whether the network runs under bf16 autocast: "bf16", or "auto" on a native-bf16 CPU."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if precision != "auto":
        return precision == "bf16"
    return device.type == "cpu" and cpu_has_native_bf16()
