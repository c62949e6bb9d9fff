"""The average of stage 17 and the edge planes' GPU run (``avg`` here; the stop of 2026-11-27 (d)). Run from the
repository root after ``rmbvideo train video-edge-input-gpu --device cuda -o DIR`` wrote DIR/rmbnet-binned.safetensors:

    python models/training/rmbnet-binned-edge-input/make_avg.py DIR/rmbnet-binned.safetensors

Stage 17 is widened to the run's network first (zero weights on the edge planes), then the two are averaged half and
half, as stage 17 was made from its own GPU run: every GPU continuation of every weight has read the dark end too dark
alone (this one −9.6 %). The run's weights are 2 × avg − stage 17 to float rounding; they are not kept, nor its
checkpoint (the tracked tree stays under the GPU machine's 64 MiB). ``video-edge-input-avg-head-cpu`` trains the
head of ``avg``.
"""

import sys

from rmbvideo.net.weights import average_models, load_model, save_model, widen_model

HERE = "models/training/rmbnet-binned-edge-input"
STAGE17 = "models/training/rmbnet-binned/stage17.safetensors"


def main(gpu_run_path: str) -> None:
    stage17, _ = load_model(STAGE17)
    gpu_run, card = load_model(gpu_run_path)
    save_model(f"{HERE}/avg.safetensors", average_models(widen_model(stage17, gpu_run.config), gpu_run, 0.5), card)


if __name__ == "__main__":
    main(sys.argv[1])
