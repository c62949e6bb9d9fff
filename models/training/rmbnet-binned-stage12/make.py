"""Stage 12 from stage 11 and its 2-minute GPU continuation; run from the repository root (``avg`` then, after
``rmbvideo train video-aligned-gpu-head-cpu``, ``final``).

- ``avg``: stage 11 and the GPU run (``video-aligned-gpu``: every weight, 228 steps of batch 8 on an H200;
  ``models/training/rmbnet-binned-stage12-gpu/run-2min``) averaged half and half
  (``models/training/rmbnet-binned/stage12-avg.*``). The GPU run gained on the development clips and real video but
  read the dark end 22 % too dark; the average keeps about half of each.
- ``final``: stage 11 and the CPU head calibration of that average (``video-aligned-gpu-head-cpu``: the last head
  convolution, 15 minutes on one core; ``head-15min`` here) averaged half and half
  (the default, ``models/rmbnet-binned.*``; no copy is kept beside the stages, to keep the tree small), chosen on the
  development sets among the
  calibration itself and its 30/50 % averages with stage 11: the one no set scores worse by more than 0.02 dB.
"""

import dataclasses
import sys
import tempfile

import torch

from rmbvideo.net.weights import average_models, load_model, save_model
from rmbvideo.train.config import bundled_recipe, load_recipe
from rmbvideo.train.loop import Trainer
from rmbvideo.train.validation import validate

STAGE11 = "models/training/rmbnet-binned/stage11.safetensors"


def held_out_metrics(model, card) -> dict[str, float]:
    """The training recipe's held-out validation metrics of ``model`` (what a training run writes in its card)."""
    cfg = load_recipe(bundled_recipe("video-aligned-gpu-head-cpu"))
    with tempfile.TemporaryDirectory() as folder:
        trainer = Trainer(cfg, folder)
        metrics = validate(model, trainer.validation_samples(), trainer.cache.spec.quanta, cfg.loss.saturation,
                           torch.device("cpu"), cfg.optim.edges > 0)
        if trainer._prefetcher is not None:
            trainer._prefetcher.close()
    return {**{k: round(v, 4) for k, v in metrics.items()}, "val_samples": card.metrics["val_samples"]}


def main(step: str) -> None:
    stage11, card11 = load_model(STAGE11)
    if step == "avg":
        gpu_run, card = load_model("models/training/rmbnet-binned-stage12-gpu/run-2min.safetensors")
        save_model("models/training/rmbnet-binned/stage12-avg.safetensors", average_models(stage11, gpu_run, 0.5), card)
        return
    head, card = load_model("models/training/rmbnet-binned-stage12/head-15min.safetensors")
    final = average_models(stage11, head, 0.5)
    training = dict(card.training)
    earlier = card11.training["schedule_note"].replace("then this recipe: its last head", "then "
                                                       "video-aligned-merged-head-cpu: its last head")
    training["schedule_note"] = earlier + (
        "; stage 12: stage 11 averaged half and half with video-aligned-gpu from it (every weight, 228 steps of "
        "batch 8 in 2 minutes on an H200; models/training/rmbnet-binned-stage12-gpu), then this recipe (the last "
        "head convolution, 15 minutes on one CPU core; models/training/rmbnet-binned-stage12/head-15min), then "
        "that averaged half and half with stage 11 (models/training/rmbnet-binned-stage12/make.py)")
    new_card = dataclasses.replace(card, training=training, metrics=held_out_metrics(final, card))
    save_model("models/rmbnet-binned.safetensors", final, new_card)


if __name__ == "__main__":
    main(sys.argv[1])
