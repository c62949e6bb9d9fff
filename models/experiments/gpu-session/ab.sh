#!/usr/bin/env bash
# An A/B of two versions of some source files on one GPU machine in one device call: the engine benchmark run for each
# version in turn (new, old, new, old), so the ratio is measured on one card under one drift. How README "On a GPU"
# measured the aligned means kept on the device (2026-11-27 (d)). Prepare here, from the repository root:
#   echo /.ab/ >> .git/info/exclude; mkdir -p .ab/old .ab/new
#   for f in rmbvideo/recon/aligned_batched.py rmbvideo/recon/rmbnet.py; do
#       git show OLD_COMMIT:$f > .ab/old/$(basename $f); cp $f .ab/new/; done
# The call: command "DIR=rmbvideo/recon bash models/experiments/gpu-session/ab.sh", carry [".ab"], timeout_s 200.
# DIR is the folder the files go back into (one folder); BENCH overrides the benchmark command.
set -uo pipefail
DIR=${DIR:?the folder of the swapped files}
BENCH=${BENCH:-"python3 -m rmbvideo bench sizes --device cuda --size 400x250 --frames 480 --precision fp32 --no-cli"}
export PYTHONPATH=$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name --format=csv,noheader
for version in new old new old; do
    cp .ab/"$version"/*.py "$DIR"/
    echo "== $version"
    $BENCH 2>&1 | grep '^|'
done
cp .ab/new/*.py "$DIR"/
