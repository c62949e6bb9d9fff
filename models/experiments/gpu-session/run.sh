#!/usr/bin/env bash
# A GPU stop's work in one device call: the speed issue's GPU table (README "On a GPU": the engine end to end at
# 200x125 and 500x500 binned, fp32 and bf16, and the network alone), and, where RECIPE names one, a training run
# first (e.g. RECIPE=video-pan-gpu MINUTES=6). Everything comes back in $OUT/all.tar. Scoring a run needs
# ../shared, which does not travel: do it here afterwards,
#   rmbvideo evaluate --development --candidate DIR/rmbnet-binned.safetensors --real-video ../shared/data/spikezoo-base -o D
# (video-temporal-decoder-gpu, the run this script was first written for, has since been run on the CPU at its batch
# and cost what the batch-4 runs did: models/README, "After stage 17".)
#
# The call: command "bash models/experiments/gpu-session/run.sh" (with RECIPE=... MINUTES=... before it for a run),
# timeout_s 590. The device image has everything rmbvideo needs but OpenEXR, which the benches do not use; a training
# run does (its scenes read the bundled HDR light sources), so for RECIPE bring the wheel first and carry [".whl"]
# (the working tree travels too: both must stay under the device's 64 MiB; the tree was 59.0 MiB after the third stop of
# 2026-11-29 moved some ablation weights into the history, 63.3 before it; 62.4 by 2026-12-07, 58.9 once stage 17's
# checkpoints moved into the history (at 45c3b78); the wheel 1.8 MiB on 2026-11-27). Check: git ls-files -z | xargs -0 stat
# -c %s | awk '{s+=$1} END {print s/1048576}'. The bench alone (no RECIPE) needs no wheel; a RECIPE's:
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#       --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 -d .whl OpenEXR==3.5.3
# DEVICE, FRAMES, SIZES, PRECISIONS and NETWORK_RUNS override the device, the bench length, its sizes, its precisions
# and the network bench's runs (NETWORK_RUNS=skip leaves that bench out); PROFILE_FRAMES=N adds `bench profile` of N
# frames at 400x250 (`profile.md` in the tar). A dry run on a CPU, a minute: OUT=/tmp/gpu-dry DEVICE=cpu FRAMES=10
#   SIZES="--size 64x64" NETWORK_RUNS="--run 32x32x4 --precision fp32" RECIPE=video-edge-input-gpu MINUTES=0.2 bash THIS.
set -uo pipefail
RECIPE=${RECIPE:-}
MINUTES=${MINUTES:-6}
DEVICE=${DEVICE:-cuda}
FRAMES=${FRAMES:-480}
SIZES=${SIZES:-"--size 400x250 --size 1000x1000"}
PRECISIONS=${PRECISIONS:-"--precision fp32 --precision bf16"}
NETWORK_RUNS=${NETWORK_RUNS:-}
PROFILE_FRAMES=${PROFILE_FRAMES:-0}
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
if [ -n "$RECIPE" ]; then
    workers=$(( $(nproc) > 3 ? $(nproc) - 2 : 1 ))
    python3 -m rmbvideo train "$RECIPE" --device "$DEVICE" --workers "$workers" --minutes "$MINUTES" -o "$work/train" \
        --quiet 2>&1 | tail -20 > "$work/train.log"
    rm -rf "$work/train/cache"  # simulated samples: large, and made again from the seed
fi
# shellcheck disable=SC2086  # SIZES, PRECISIONS and NETWORK_RUNS are lists of options
python3 -m rmbvideo bench sizes --device "$DEVICE" $SIZES --frames "$FRAMES" $PRECISIONS > "$work/bench-sizes.txt" 2>&1
if [ "$NETWORK_RUNS" != skip ]; then
    python3 -m rmbvideo bench network --device "$DEVICE" $NETWORK_RUNS > "$work/bench-network.txt" 2>&1
fi
if [ "$PROFILE_FRAMES" -gt 0 ]; then
    python3 -m rmbvideo bench profile --device "$DEVICE" --frames "$PROFILE_FRAMES" -o "$work/profile.md" \
        > "$work/bench-profile.txt" 2>&1
fi
cat "$work"/*.txt "$work"/*.log 2>/dev/null
tar -cf "$OUT/all.tar" -C "$work" .
rm -rf "$work"
tar -tvf "$OUT/all.tar"
