"""Session script: stage 11's first step, stage 10 with its central readouts' aligned mean merged into the whole
frames' (models/training/rmbnet-binned/stage11-merged.*); stage 11 is that with its last head conv retrained
(rmbvideo train video-aligned-merged-head-cpu)."""
import dataclasses, tempfile, torch
from rmbvideo.net.weights import load_model, merge_aligned_candidates, save_model
from rmbvideo.train.config import load_recipe, bundled_recipe
from rmbvideo.train.loop import Trainer
from rmbvideo.train.validation import validate
DIFFERENCE = -4.1  # l_s - l_a weighted by the pair's softmax weight on training scenes (train_logits.py: -4.096)
def main():
    torch.set_num_threads(2)
    old, card = load_model("models/training/rmbnet-binned/stage10.safetensors")
    merged = merge_aligned_candidates(old, DIFFERENCE)
    cfg = load_recipe(bundled_recipe("video-aligned-sharp-floor-cpu"))
    with tempfile.TemporaryDirectory() as d:
        tr = Trainer(dataclasses.replace(cfg, model=merged.config), d)
        metrics = validate(merged, tr.validation_samples(), tr.cache.spec.quanta, cfg.loss.saturation, torch.device("cpu"), cfg.optim.edges > 0)
        old_metrics = validate(old, tr.validation_samples(), tr.cache.spec.quanta, cfg.loss.saturation, torch.device("cpu"), cfg.optim.edges > 0)
        tr._prefetcher.close()
    print("stage 10", old_metrics, "stage 11", metrics)
    metrics = {k: round(v, 4) for k, v in metrics.items()}
    metrics["val_samples"] = card.metrics["val_samples"]
    training = dict(card.training)
    training["schedule_note"] += (
        "; stage 11: stage 10 without the second aligned mean (rmbvideo.net.weights.merge_aligned_candidates("
        "stage 10, -4.1): its head-input weights joined the whole frames' mean's, its blend logit joined that one's "
        "by log-sum-exp linearised at the pair's mean logit difference on training scenes, -4.1), no further "
        "training: development sets within 0.01 dB, the aligned means' time -22 %")
    description = card.description.replace(", of whole frames and of their central 2 readouts", "")
    new_card = dataclasses.replace(card, description=description, training=training, metrics=metrics)
    save_model("models/training/rmbnet-binned/stage11-merged.safetensors", merged, new_card)
if __name__ == "__main__":
    main()
