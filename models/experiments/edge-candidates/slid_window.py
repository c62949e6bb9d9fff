"""A clip's edge frames with the network's window slid inwards (``RmbNetConfig.edge_slide``), on the development video
clips only: where the window of frame i reaches past the clip's start (or end), its missing positions hold the next
frames beyond the window's other end (i + w + 1, ...; at the end i - w - 1, ...), real evidence for both attentions
(which read their keys as a set), while the pooled means and the edge planes still read the window as the edge cuts it.
So an edge frame's own estimate reads 2w + 1 frames, all from its one side, as its aligned mean already does
(``aligned_shift``). Prints, per clip, the edge check (``edge_report``) of the shipped model and of each given model
(default: the shipped weights with the slide and no training). Run from the repository root (about a minute a model,
one core):

    python models/experiments/edge-candidates/slid_window.py [MODEL.safetensors ...]
"""

import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.video_checks import edge_report
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import default_model_path, load_model, save_model


def main(*paths: str) -> None:
    with tempfile.TemporaryDirectory() as folder:
        if not paths:
            shipped, card = load_model(default_model_path())
            slid = RmbNet(replace(shipped.config, edge_slide=True))
            slid.load_state_dict(shipped.state_dict())
            paths = (str(save_model(Path(folder) / "slid-untrained.safetensors", slid, card)),)
        models = {"cut (shipped)": str(default_model_path()), **{Path(p).stem if "untrained" in p else
                                                                 f"{Path(p).parent.name}/{Path(p).stem}": p
                                                                 for p in paths}}
        print("| clip | model | first below median (dB) | last below median | first offset (ms) | last offset "
              "| edge cost, first (dB) | edge cost, last |")
        print("|---|---|" + "---:|" * 6)
        for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
            for label, path in models.items():
                r = edge_report(seq, "rmbnet", {"threads": 1, "input_mode": "binned", "precision": "fp32",
                                                "model": path})
                print(f"| {seq.name} | {label} | {r.first_drop_db:+.2f} | {r.last_drop_db:+.2f} "
                      f"| {r.first_offset_ms:+.2f} | {r.last_offset_ms:+.2f} | {r.first_edge_cost_db:+.2f} "
                      f"| {r.last_edge_cost_db:+.2f} |", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
