"""Training in bf16 (``optim.precision``), measured. Run from the repository root:

    python models/experiments/bf16-training/measure.py loss [RECIPE]    # a minute
    python models/experiments/bf16-training/measure.py speed [RECIPE]   # two minutes
    python models/experiments/bf16-training/measure.py compare FP32_DIR BF16_DIR

``loss``: the recipe's model (its ``init``, stage 19 for ``window-worth-w3-cpu``, the default) on its first three
training batches, the loss in fp32, with the forward under bf16 autocast and the losses in fp32 (what training in bf16
does), and with the losses under autocast too (what it must not do). ``speed``: one training step (forward and
backward) of the first batch in fp32 and in bf16, alternated ABBA in one process on one thread, the median of each and
their ratio. ``compare``: two runs of one recipe (``rmbvideo train RECIPE --steps N -o FP32_DIR`` and the same with
``--precision bf16 -o BF16_DIR``): their mean training loss, each step's relative difference and validation.
"""

import csv
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

import rmbvideo.train.loop as loop
from rmbvideo.train.batch import Batch
from rmbvideo.train.config import bundled_recipe, load_recipe


def _trainer(recipe: str) -> tuple[loop.Trainer, list[Batch]]:
    config = load_recipe(bundled_recipe(recipe))
    trainer = loop.Trainer(config, Path("/tmp") / "bf16-training-measure")
    batches = []
    for step in range(3):
        samples = trainer.batch_samples(step)
        batches.append(Batch.from_samples(samples, trainer.device, [False] * len(samples), config.model.centre_windows,
                                          config.model.n, config.model))
    return trainer, batches


def _loss(trainer: loop.Trainer, batch: Batch, bf16: bool, loss_in_autocast: bool = False) -> float:
    cfg = trainer.config
    with torch.no_grad(), torch.autocast("cpu", torch.bfloat16, enabled=loss_in_autocast):
        return sum(float(s.loss) for s in loop.segment_losses(trainer.model.eval(), batch, cfg.optim.tbptt, cfg.loss,
                                                               True, 0, cfg.optim.prime, bf16 or loss_in_autocast))


def measure_loss(recipe: str) -> None:
    trainer, batches = _trainer(recipe)
    for k, batch in enumerate(batches):
        fp32, bf16, wrong = _loss(trainer, batch, False), _loss(trainer, batch, True), _loss(trainer, batch, True, True)
        print(f"batch {k}: fp32 {fp32:.4f}; bf16 forward, fp32 losses {bf16:.4f} ({bf16 / fp32 - 1:+.1%}); "
              f"losses under autocast too {wrong:.4f} ({wrong / fp32:.2f}x)")
    trainer._prefetcher.close()


def measure_speed(recipe: str, rounds: int = 4) -> None:
    torch.set_num_threads(1)
    trainer, batches = _trainer(recipe)
    cfg, model = trainer.config, trainer.model

    def step(bf16: bool) -> float:
        model.zero_grad(set_to_none=True)
        began = time.perf_counter()
        loop.train_batch(model, batches[0], cfg.optim.tbptt, cfg.loss, True, 0, cfg.optim.prime, bf16=bf16)
        return time.perf_counter() - began

    step(False), step(True)
    times: dict[bool, list[float]] = {False: [], True: []}
    for r in range(rounds):
        for bf16 in ((False, True) if r % 2 == 0 else (True, False)):
            times[bf16].append(step(bf16))
    fp32, bf16 = (float(np.median(times[b])) for b in (False, True))
    print(f"{recipe}: one step {fp32:.2f} s in fp32, {bf16:.2f} s in bf16 (median of {rounds}): {fp32 / bf16:.2f}x")
    trainer._prefetcher.close()


def compare(fp32_dir: str, bf16_dir: str) -> None:
    def read(folder: str) -> np.ndarray:
        with open(Path(folder) / "loss.csv", newline="") as handle:
            return np.array([float(row["loss"]) for row in csv.DictReader(handle)])

    a, b = read(fp32_dir), read(bf16_dir)
    n = min(len(a), len(b))
    print(f"{n} steps: mean loss fp32 {a[:n].mean():.4f}, bf16 {b[:n].mean():.4f}; last 50 {a[n - 50:n].mean():.4f} / "
          f"{b[n - 50:n].mean():.4f}; each step's relative difference, median {np.median(np.abs(b[:n] / a[:n] - 1)):.1%}")
    for folder in (fp32_dir, bf16_dir):  # the model card beside the checkpoint's
        for path in sorted(p for p in Path(folder).glob("*.json") if p.name != "checkpoint.json"):
            print(f"{folder}: validation {json.loads(path.read_text())['metrics']['val_mu_psnr']:.2f} dB")


if __name__ == "__main__":
    command, args = sys.argv[1], sys.argv[2:]
    if command == "compare":
        compare(*args)
    else:
        {"loss": measure_loss, "speed": measure_speed}[command](*(args or ["window-worth-w3-cpu"]))
