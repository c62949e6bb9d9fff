"""Stage 18 from stage 17 and two GPU runs; run from the repository root:

    python models/training/rmbnet-binned-stage18/make.py avg          # after rmbvideo train video-temporal-gpu
    python models/training/rmbnet-binned-stage18/make.py final DIR/rmbnet-binned.safetensors   # after
        # rmbvideo train video-temporal-head-gpu --device cuda -o DIR

- ``avg``: stage 17 and its GPU continuation with the temporal term (``video-temporal-gpu``: every weight, 365 steps of
  batch 8 in 5 minutes on an H100, copied to ``gpu-run`` here by the device call) averaged half and half (``avg``
  here), as stage 17 was made from stage 16, because every GPU continuation of every weight has read the dark end
  too dark alone. The run's own weights and checkpoint did not come back from the device (at most 8 files a call);
  ``avg`` did, and the run is 2 x avg - stage 17 to float rounding.
- ``final``: the head of that average trained on a GPU with the temporal term and 30 % flat fields
  (``video-temporal-head-gpu``; its checkpoint and ``loss.csv`` in ``head/``), written as the default
  (``models/rmbnet-binned.*``) with its lineage in the card. Not run: on the development sets the result matched stage
  17 (models/README, stage 18), so stage 17 stays the default.
"""

import dataclasses
import sys

from rmbvideo.net.weights import average_models, load_model, save_model

HERE = "models/training/rmbnet-binned-stage18"
STAGE17 = "models/training/rmbnet-binned/stage17.safetensors"


def main(step: str, head_run: str | None = None) -> None:
    if step not in ("avg", "final") or (step == "final") != (head_run is not None):
        raise SystemExit("usage: make.py avg | make.py final HEAD_RUN.safetensors")
    stage17, _ = load_model(STAGE17)
    if step == "avg":
        gpu_run, card = load_model(f"{HERE}/gpu-run.safetensors")
        save_model(f"{HERE}/avg.safetensors", average_models(stage17, gpu_run, 0.5), card)
        return
    final, card = load_model(head_run)
    training = dict(card.training)
    training["initialised_from"] = (
        f"{HERE}/avg.safetensors: stage 17 ({STAGE17}) averaged half and half with video-temporal-gpu from it (every "
        f"weight with the temporal term, on an H100; {HERE}/gpu-run and its checkpoint)")
    training["schedule_note"] = (
        "stage 18: stage 17 averaged half and half with its GPU continuation video-temporal-gpu, then this recipe (the "
        "head, both convolutions, with the temporal loss term and 30 % flat fields, on an H100); chosen on the "
        "development sets (rmbvideo evaluate --development; models/experiments/blend-hedging/probe.py models FILE), "
        f"never on the held-out tables ({HERE}/make.py)")
    training["resume"] = (
        f"rmbvideo train video-temporal-head-gpu --resume --device cuda --output DIR, with DIR holding a copy of "
        f"{HERE}/head/ (checkpoint with Adam state and loss.csv); the body's run: video-temporal-gpu with "
        f"{HERE}/checkpoint.*")
    training["evaluation_command"] = ("rmbvideo evaluate --real-video ../shared/data/spikezoo-base --full-resolution "
                                      "--texture-pans -o models/figures")
    save_model("models/rmbnet-binned.safetensors", final, dataclasses.replace(card, training=training))


if __name__ == "__main__":
    main(*sys.argv[1:])
