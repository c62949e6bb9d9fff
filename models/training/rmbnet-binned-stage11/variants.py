"""Session script: development-set scores of inference-time variants of a model's aligned means (the figures
behind stage 11 and the DIS iterations in models/README and README "What accuracy costs in time").

Run from the repository root: python models/training/rmbnet-binned-stage11/variants.py VARIANT [MODEL] (VARIANT:
base, fast, ultrafast, nosharp, vr<N>, gd<N> or combinations such as gd12vr2; writes VARIANT.md beside this file).
The variants patch the engine at run time on top of the code they run with: the figures of the closing note were
taken with the code of commit e7687a0 (DIS medium at 25/5 iterations; "fast", "nosharp" and the vr/gd variants on
stage 10) and of fe94ec1 (the merged model); check out that code to reproduce them exactly."""
import sys, dataclasses, numpy as np
from pathlib import Path
import rmbvideo.recon.aligned_box as ab
from rmbvideo.evaluate.development import score_candidate, markdown
from rmbvideo.evaluate.heldout import default_cache_dir, load_development
from rmbvideo.evaluate.real_video import find_streams
from rmbvideo.evaluate.texture_pans import texture_pan_folder
variant = sys.argv[1]
model = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("models/rmbnet-binned.safetensors")
if "fast" in variant or "ultra" in variant:
    preset = "ultrafast" if "ultra" in variant else "fast"
    orig = ab.AlignedBoxConfig.for_frames.__func__
    ab.AlignedBoxConfig.for_frames = classmethod(lambda cls, n, k=0: dataclasses.replace(orig(cls, n, k), preset=preset))
if "nosharp" in variant:
    orig_add = ab.AlignedBox.add
    ab.AlignedBox.add = lambda self, i, rate, sharp=None: orig_add(self, i, rate, None)
    orig_mean = ab.AlignedBox.mean
    ab.AlignedBox.mean = lambda self, i, nb: np.stack([orig_mean(self, i, nb)] * 2)
if variant.startswith("vr") or variant.startswith("gd"):
    orig_init = ab.AlignedBox.__init__
    def init(self, config=None):
        orig_init(self, config)
        import re
        for key, value in re.findall(r"(vr|gd)(\d+)", variant):
            (self._dis.setVariationalRefinementIterations if key == "vr" else self._dis.setGradientDescentIterations)(int(value))
    ab.AlignedBox.__init__ = init
seq = load_development(None)
clips = find_streams(texture_pan_folder(default_cache_dir()))
real = find_streams(Path("../shared/data/spikezoo-base"))
s = score_candidate(model, seq, clips, real, "cpu", name=variant)
Path(__file__).with_name(f"{variant}.md").write_text(markdown([s], [model]))
print(markdown([s], [model]))
