"""Time every Conv2d of the shipped RMB-Net, frame by frame as bench network runs it: python conv_prof.py fp32|bf16 (findings.md)."""
import sys, time, torch, collections
from rmbvideo.bench.network import _inputs, _frame_by_frame
from rmbvideo.net.weights import load_model, default_model_path
from rmbvideo.recon.rmbnet import inference_copy
torch.set_num_threads(1)
bf16 = sys.argv[1] == "bf16"
model = load_model(default_model_path())[0].eval()
net = inference_copy(model, bf16=bf16)
inputs = _inputs(model, 200, 125, 48, torch.device("cpu"))
stats = collections.defaultdict(lambda: [0, 0.0, None])
starts = {}
def pre(m, a):
    starts[id(m)] = time.perf_counter()
def post_factory(name):
    def post(m, a, r):
        s = stats[name]; s[0] += 1; s[1] += time.perf_counter() - starts[id(m)]
        x = a[0]
        s[2] = (tuple(x.shape), m.kernel_size, m.groups, x.dtype, x.is_contiguous(memory_format=torch.channels_last), m.weight.is_contiguous(memory_format=torch.channels_last))
    return post
with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
    _frame_by_frame(net, inputs, 48)
    for name, m in net.named_modules():
        if isinstance(m, torch.nn.Conv2d):
            m.register_forward_pre_hook(pre); m.register_forward_hook(post_factory(name))
    enc, step = _frame_by_frame(net, inputs, 48)
print("encode %.2f step %.2f ms/frame" % (enc*1e3/48, step*1e3/48))
tot = 0
for k, v in sorted(stats.items(), key=lambda kv: -kv[1][1])[:40]:
    tot += v[1]
    print("%-40s %5d %6.2f ms/frame %s" % (k, v[0], 1e3 * v[1] / 48, v[2]))
print("conv total %.2f" % (1e3*sum(v[1] for v in stats.values())/48))
