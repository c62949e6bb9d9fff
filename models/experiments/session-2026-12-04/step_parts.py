"""Time the shipped RMB-Net's step, frame by frame as `bench network` runs it, by part: every Conv2d (conv) or
every torch.cat/torch.stack called from Python (cat). python step_parts.py conv|cat fp32|bf16 (findings.md)."""
import sys, time, torch, traceback, collections
from rmbvideo.bench.network import _inputs, _frame_by_frame
from rmbvideo.net.weights import load_model, default_model_path
from rmbvideo.recon.rmbnet import inference_copy
torch.set_num_threads(1)
mode, bf16 = sys.argv[1], sys.argv[2] == "bf16"
model = load_model(default_model_path())[0].eval()
net = inference_copy(model, bf16=bf16)
inputs = _inputs(model, 200, 125, 48, torch.device("cpu"))
stats = collections.defaultdict(lambda: [0, 0.0, None])
if mode == "cat":
    orig = {"cat": torch.cat, "stack": torch.stack}
    def wrap(name):
        f = orig[name]
        def g(*a, **k):
            t = time.perf_counter(); r = f(*a, **k); dt = time.perf_counter() - t
            fr = traceback.extract_stack(limit=3)[-2]
            key = (name, fr.filename.split("/")[-1], fr.lineno)
            s = stats[key]; s[0] += 1; s[1] += dt; s[2] = (tuple(r.shape), r.dtype, r.is_contiguous(), r.is_contiguous(memory_format=torch.channels_last) if r.dim()==4 else None)
            return r
        return g
    with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        _frame_by_frame(net, inputs, 48)
        torch.cat = wrap("cat"); torch.stack = wrap("stack")
        _frame_by_frame(net, inputs, 48)
    for k, v in sorted(stats.items(), key=lambda kv: -kv[1][1])[:25]:
        print(k, v[0], "%.2f ms/frame" % (1e3 * v[1] / 48), v[2])
else:
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
