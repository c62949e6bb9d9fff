#!/usr/bin/env bash
# One GPU stop's work in one device call (the real-motion issue's next run, models/README "After stage 17"; the
# speed issue's GPU table, README "On a GPU"): train stage 17's decoder with the temporal term at a GPU's batch
# (recipe video-temporal-decoder-gpu, its 6 minutes), then time the engine on CUDA, and bring everything back in
# $OUT/all.tar. Scoring the run needs ../shared, which does not travel: do it here afterwards,
#   rmbvideo evaluate --development --candidate DIR/rmbnet-binned.safetensors --real-video ../shared/data/spikezoo-base -o D
#
# Before the call, here (the device image lacks OpenEXR; everything else rmbvideo needs is there):
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#       --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 -d .whl OpenEXR==3.5.3
# The call: command "bash models/experiments/gpu-session/run.sh", carry [".whl"], timeout_s 590.
# MINUTES, DEVICE and FRAMES override the budget, the device and the bench length (a dry run on a CPU:
#   OUT=/tmp/gpu-dry DEVICE=cpu MINUTES=0.2 FRAMES=10 bash models/experiments/gpu-session/run.sh).
set -uo pipefail
MINUTES=${MINUTES:-6}
DEVICE=${DEVICE:-cuda}
FRAMES=${FRAMES:-480}
if compgen -G ".whl/*.whl" > /dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        || exit 1
    export PYTHONPATH=/tmp/site:$PWD
else
    export PYTHONPATH=$PWD
fi
export PYTHONUNBUFFERED=1
work=$OUT/stop
mkdir -p "$work"
{ nvidia-smi --query-gpu=name,memory.total --format=csv 2>/dev/null; python3 -c "import torch; print(torch.__version__)"; } \
    > "$work/device.txt"
workers=$(( $(nproc) > 3 ? $(nproc) - 2 : 1 ))
python3 -m rmbvideo train video-temporal-decoder-gpu --device "$DEVICE" --workers "$workers" \
    --minutes "$MINUTES" -o "$work/train" --quiet 2>&1 | tail -20 > "$work/train.log"
rm -rf "$work/train/cache"  # simulated samples: large, and made again from the seed
python3 -m rmbvideo bench sizes --device "$DEVICE" --size 400x250 --frames "$FRAMES" --precision fp32 --precision bf16 \
    > "$work/bench-sizes.txt" 2>&1
cat "$work/device.txt" "$work/train.log" "$work/bench-sizes.txt"
tar -cf "$OUT/all.tar" -C "$work" .
rm -rf "$work"
tar -tvf "$OUT/all.tar"
