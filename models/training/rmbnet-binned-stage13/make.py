"""Stage 13: stage 12's weights with each ConvLSTM's cell state scaled by 0.95 before every step
(``RmbNetConfig.cell_decay``); run from the repository root after stage 12's ``make.py final``, which writes stage 12
as ``models/rmbnet-binned.*``. ``make.py [DECAY [OUT]]`` writes the shipped weights with another decay to OUT (the
models/README table's other rows, scored with ``rmbvideo evaluate --development --candidate OUT``).

Stage 12 loses quality as its recurrent state ages on a long still capture (the development's still clips read
1.10 dB (physical) and 2.21 dB (spikezoo) lower in their second half than in frames 3-8). Training on aged states
(``video-aged-cpu``, ``video-aged-gpu``) traded motion for it; this decay was chosen on the development sets among
0.97, 0.95, 0.9 and 0.8 (models/README): it halves that loss, leaves long moving clips level or better, and costs
the short sequences and real video 0.02 dB.
"""

import dataclasses
import sys
import tempfile

import torch

from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import load_model, save_model
from rmbvideo.train.config import bundled_recipe, load_recipe
from rmbvideo.train.loop import Trainer
from rmbvideo.train.validation import validate

DECAY = 0.95
DEFAULT = "models/rmbnet-binned.safetensors"


def main(decay: float = DECAY, out: str = DEFAULT) -> None:
    stage12, card = load_model(DEFAULT)  # the same weights whatever decay the shipped card names
    stage13 = RmbNet(dataclasses.replace(stage12.config, cell_decay=decay)).eval()
    stage13.load_state_dict(stage12.state_dict())
    cfg = load_recipe(bundled_recipe("video-aligned-gpu-head-cpu"))
    with tempfile.TemporaryDirectory() as folder:  # the recipe's held-out validation, as a training run writes it
        trainer = Trainer(cfg, folder)
        metrics = validate(stage13, trainer.validation_samples(), trainer.cache.spec.quanta, cfg.loss.saturation,
                           torch.device("cpu"), cfg.optim.edges > 0)
        if trainer._prefetcher is not None:
            trainer._prefetcher.close()
    training = dict(card.training)
    note = training["schedule_note"].split("; stage 13:")[0]
    training["schedule_note"] = note + (f"; stage 13: stage 12's weights with the ConvLSTM cell state scaled by "
                                        f"{decay} before every step (cell_decay; "
                                        "models/training/rmbnet-binned-stage13/make.py)")
    metrics = {**{k: round(v, 4) for k, v in metrics.items()}, "val_samples": card.metrics["val_samples"]}
    save_model(out, stage13, dataclasses.replace(card, training=training, metrics=metrics))


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else DECAY, sys.argv[2] if len(sys.argv) > 2 else DEFAULT)
