"""``rmbvideo evaluate`` with the network in fp32 on a CPU where ``--precision auto`` would pick bf16 (AVX512-BF16 or
AMX): the committed tables were made in fp32 on an AVX2 host, and bf16 moves the binned scores by up to 0.02 dB, so a
rerun on such a host that should match them turns bf16 off first. Every argument goes to ``rmbvideo evaluate``; from
the repository root:

    python models/experiments/temporal-consistency/evaluate_fp32.py --real-video ../shared/data/spikezoo-base \\
        --full-resolution --texture-pans -o OUT
"""

import sys

import rmbvideo.recon.precision as precision
from rmbvideo.cli import main

precision.cpu_has_native_bf16 = lambda *args: False  # "auto" then resolves to fp32, as on a CPU without bf16

if __name__ == "__main__":
    main(["evaluate", *sys.argv[1:]])
