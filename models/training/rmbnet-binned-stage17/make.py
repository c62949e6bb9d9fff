"""Stage 17 from stage 16 and two GPU runs; run from the repository root:

    python models/training/rmbnet-binned-stage17/make.py avg                      # after rmbvideo train video-pan-gpu
    python models/training/rmbnet-binned-stage17/make.py final DIR/rmbnet-binned.safetensors   # after
        # rmbvideo train video-pan-temporal-head-gpu --device cuda -o DIR

- ``avg``: stage 16 and its GPU continuation (``video-pan-gpu``: every weight on stage 16's data, 708 steps of batch 8
  in 6.5 minutes on an H100; ``gpu-run`` here, its checkpoint with the Adam state in the history at 45c3b78)
  averaged half and half (``avg`` here). The run gained on moving pans and real video but read the dark end 12 %
  too dark; the average 7 %.
- ``final``: the head of that average (both convolutions) trained on a GPU with the temporal term and 30 % flat
  fields (``video-pan-temporal-head-gpu``, 653 steps of batch 8 in 4.5 minutes on an H100; ``loss.csv`` in
  ``head/``, its checkpoint there in the history at 45c3b78), written as the default (``models/rmbnet-binned.*``)
  with its lineage in the card.
  Chosen on the development sets against the CPU calibration of the same average (``video-pan-gpu-head-cpu``) and
  the run's own average with stage 16.
"""

import dataclasses
import sys

from rmbvideo.net.weights import average_models, load_model, save_model

HERE = "models/training/rmbnet-binned-stage17"
STAGE16 = "models/training/rmbnet-binned/stage16.safetensors"


def main(step: str, head_run: str | None = None) -> None:
    if step not in ("avg", "final") or (step == "final") != (head_run is not None):
        raise SystemExit("usage: make.py avg | make.py final HEAD_RUN.safetensors")
    stage16, _ = load_model(STAGE16)
    if step == "avg":
        gpu_run, card = load_model(f"{HERE}/gpu-run.safetensors")
        save_model(f"{HERE}/avg.safetensors", average_models(stage16, gpu_run, 0.5), card)
        return
    final, card = load_model(head_run)
    training = dict(card.training)
    training["initialised_from"] = (
        f"{HERE}/avg.safetensors: stage 16 ({STAGE16}: video-pan-decoder-cpu, the whole decoder on rigid pans) "
        "averaged half and half with video-pan-gpu from it (every weight, 708 steps of batch 8, 6.5 minutes on an "
        f"H100; {HERE}/gpu-run and its checkpoint)")
    training["schedule_note"] = (
        "stage 17: stage 16 averaged half and half with its GPU continuation video-pan-gpu, then this recipe (the head, "
        "both convolutions, with the temporal loss term and 30 % flat fields, 4.5 minutes on an H100); chosen on the "
        "development sets (rmbvideo evaluate --development; models/experiments/blend-hedging/probe.py models FILE), "
        "never on the held-out tables, against the CPU calibration of the same average (video-pan-gpu-head-cpu, the "
        f"last head convolution, 20 minutes on one core) and this run averaged with stage 16 ({HERE}/make.py)")
    training["resume"] = (
        f"rmbvideo train video-pan-temporal-head-gpu --resume --device cuda --output DIR, with DIR holding a copy of "
        f"{HERE}/head/ (checkpoint with Adam state and loss.csv); the body's run: video-pan-gpu with {HERE}/checkpoint.*")
    training["evaluation_command"] = ("rmbvideo evaluate --real-video ../shared/data/spikezoo-base --full-resolution "
                                      "--texture-pans -o models/figures")
    save_model("models/rmbnet-binned.safetensors", final, dataclasses.replace(card, training=training))


if __name__ == "__main__":
    main(*sys.argv[1:])
