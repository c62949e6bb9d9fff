"""How much of an edge frame's drop below its clip's median is the frame's content: the same figures for methods
with no recurrent state (MG20, TFW-L) beside RMB-Net, on the held-out video clips (a diagnostic, never used to choose).
Run from the repository root (about 10 minutes, one core): python models/experiments/edge-candidates/content.py"""
import numpy as np
from rmbvideo.evaluate.heldout import load_video_heldout
from rmbvideo.evaluate.video_checks import edge_report
for seq in load_video_heldout(False):
    for method, options in (("rmbnet", {"threads": 1}), ("mg20", {}), ("tfw", {"window": 70, "step": 10})):
        try:
            r = edge_report(seq, method, options)
        except TypeError as exc:
            print(seq.name, method, exc); continue
        p = np.asarray(r.psnr)
        print(f"| {seq.name} | {method} | {r.first_drop_db:.2f} | {r.last_drop_db:.2f} | {r.first_edge_cost_db:.2f} | "
              f"{r.last_edge_cost_db:.2f} | {np.median(p):.2f} | " + " ".join(f"{v:.1f}" for v in p[:4]) + " .. "
              + " ".join(f"{v:.1f}" for v in p[-3:]) + " |", flush=True)
