"""Session script: where the two aligned candidates' blend logits sit on training scenes (not evaluation data):
l_s - l_a, weighted by the pair's joint softmax weight."""
import numpy as np, torch, tempfile
torch.set_num_threads(1)
from rmbvideo.train.config import load_recipe, bundled_recipe
from rmbvideo.train.loop import Trainer
from rmbvideo.train.batch import Batch
from rmbvideo.net.weights import load_model
def main():
    cfg = load_recipe(bundled_recipe("video-aligned-sharp-floor-cpu"))
    net, _ = load_model("models/training/rmbnet-binned/stage10.safetensors")
    rows = []
    orig = net.decoder.forward
    def hooked(*a, **k):
        z, s = orig(*a, **k)
        logits = z[:, 1:].float(); p = torch.softmax(logits, 1)
        rows.append(((logits[:, -1] - logits[:, -2]).flatten().numpy(), (p[:, -1] + p[:, -2]).flatten().numpy()))
        return z, s
    net.decoder.forward = hooked
    with tempfile.TemporaryDirectory() as d:
        tr = Trainer(cfg, d)
        for step in range(100000, 100008):
            samples = tr.batch_samples(step)
            b = Batch.from_samples(samples, torch.device("cpu"), None, cfg.model.centre_windows, cfg.model.n, cfg.model)
            with torch.no_grad():
                net.forward_sequence(b.i_s, b.i_m, convention=b.convention, i_c=b.i_c, i_a=b.i_a)
        tr._prefetcher.close()
    d = np.concatenate([r[0] for r in rows]); w = np.concatenate([r[1] for r in rows])
    m = np.average(d, weights=w)
    print("d mean", d.mean(), "weighted", m, "weighted std", np.sqrt(np.average((d - m) ** 2, weights=w)), "pct", np.percentile(d, [5, 50, 95]))

if __name__ == '__main__':
    main()
