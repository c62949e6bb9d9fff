"""RMB-Net's heaviest convolutions on one AVX2 core, float32 (channels-last, oneDNN: what the engine runs) against
int8 (PyTorch's x86 quantized backend, weights per channel, activations per tensor; with and without quantizing the
input and dequantizing the output around it). The shapes are the five with the most time in `bench profile
--resolution binned --threads 1` (the encoders' 5x5 convolutions at scale 1/2, batched 8 frames, the head's first
3x3, a ConvLSTM gate, the deepest attention's 3x3). Medians of alternated rounds: python int8_convs.py [ROUNDS]
"""

import statistics
import sys
import time
import warnings

import torch
import torch.ao.nn.quantized as nnq

ROUNDS = int(sys.argv[1]) if len(sys.argv) > 1 else 9
SHAPES = [  # batch, in channels, height, width, out channels, kernel
    (8, 12, 128, 200, 12, 5),
    (1, 29, 128, 200, 12, 3),
    (8, 16, 64, 100, 16, 5),
    (1, 24, 64, 100, 48, 3),
    (1, 72, 16, 25, 96, 3),
]
warnings.filterwarnings("ignore", message=".*quantize.*deprecated")
torch.set_num_threads(1)
torch.backends.quantized.engine = "x86"
torch.manual_seed(0)


def once(run) -> float:
    began = time.perf_counter()
    run()
    return time.perf_counter() - began


print("| shape (B, Cin, H, W, Cout, k) | fp32 ms | int8 ms | int8 with (de)quantizing ms | int8 / fp32 |")
print("|---|---:|---:|---:|---:|")
with torch.no_grad():
    for batch, cin, height, width, cout, k in SHAPES:
        conv = torch.nn.Conv2d(cin, cout, k, padding=k // 2).to(memory_format=torch.channels_last)
        x = torch.randn(batch, cin, height, width).contiguous(memory_format=torch.channels_last)
        quantized = nnq.Conv2d(cin, cout, k, padding=k // 2)
        scales = conv.weight.abs().amax((1, 2, 3)) / 127
        quantized.set_weight_bias(torch.quantize_per_channel(conv.weight, scales, torch.zeros(cout, dtype=torch.long),
                                                             0, torch.qint8), conv.bias)
        quantized.scale, quantized.zero_point = 0.05, 128
        xq = torch.quantize_per_tensor(x, 0.03, 128, torch.quint8)
        runs = {"fp32": lambda: conv(x), "int8": lambda: quantized(xq),
                "int8+q": lambda: quantized(torch.quantize_per_tensor(x, 0.03, 128, torch.quint8)).dequantize()}
        times: dict[str, list[float]] = {name: [] for name in runs}
        for run in runs.values():
            run()
        for _ in range(ROUNDS):
            for name, run in runs.items():
                times[name].append(once(run))
        fp32, int8, both = (statistics.median(times[n]) * 1e3 for n in runs)
        print(f"| {batch, cin, height, width, cout, k} | {fp32:.2f} | {int8:.2f} | {both:.2f} | {int8 / fp32:.2f} |")
