"""The edge frames as a mix of the model's and its edge model's, (1 - a) x model + a x edge model, on the 40 clips no
evaluation uses (index 8-15 of each video kind, as ``edge-timing/spread.py``): the clip-edge check's figures
(``edge_report``'s) for a = 0 (the model alone), 0.5 and 1 (the engine's edge model), each written beside
``spread.json`` as ``spread-TAG-A.json`` for ``spread.py --compare`` (the model alone is scored afresh: ``spread.json``
was made on another host). MODEL is a weight file with its edge model beside it (``NAME-edges.safetensors``). Run
from the repository root (about 25 minutes on one core):

    python models/experiments/edge-candidates/edge_mix.py MODEL.safetensors TAG [KIND ...]
"""

import json
import sys
from pathlib import Path

import numpy as np
import torch

from rmbvideo.evaluate.heldout import FRAME_STEP, load_video_heldout
from rmbvideo.evaluate.metrics import mu_law_psnr
from rmbvideo.evaluate.video_checks import best_time_offset_ms, clip_frames, run_rmb, video_scene_of

MIXES = (0.0, 0.5, 1.0)
KINDS = ("fast", "dark", "fast-dark", "spikezoo-fast", "low-contrast")
SPREAD = Path(__file__).resolve().parents[1] / "edge-timing"


def both(model: str, seq) -> tuple[dict, dict]:
    """The frames of ``seq`` by the model alone and with its edge model."""
    options = {"threads": 1, "input_mode": "binned", "model": model}
    return run_rmb("rmbnet", {**options, "edges": "off"}, seq), run_rmb("rmbnet", {**options, "edges": "auto"}, seq)


def mixed(pair: tuple[dict, dict], a: float) -> dict:
    """The model's frames with the edge model's mixed in by ``a`` (the two differ only at the edge frames)."""
    return {i: (1 - a) * pair[0][i] + a * pair[1][i] for i in pair[0]}


def figures(seq, frames: dict, as_first: np.ndarray, as_last: np.ndarray) -> dict[str, float]:
    """``edge_report``'s figures of a clip's frames and of its middle frame made as a first and as a last frame."""
    count, mid = len(seq.gt), len(seq.gt) // 2
    psnr = [mu_law_psnr(frames[i], np.minimum(seq.gt[i], 1.0)) for i in range(count)]
    median = float(np.median(psnr))
    scene = video_scene_of(seq)
    centre = lambda i: 2 * FRAME_STEP * i + FRAME_STEP  # noqa: E731  raw plane at frame i's centre
    middle = best_time_offset_ms(frames[mid], scene, centre(mid))
    truth = np.minimum(seq.gt[mid], 1.0)
    return {"last_offset_ms": best_time_offset_ms(frames[count - 1], scene, centre(count - 1)) - middle,
            "first_offset_ms": best_time_offset_ms(frames[0], scene, centre(0)) - middle,
            "middle_offset_ms": middle, "first_drop_db": median - psnr[0], "last_drop_db": median - psnr[-1],
            "first_edge_cost_db": psnr[mid] - mu_law_psnr(as_first, truth),
            "last_edge_cost_db": psnr[mid] - mu_law_psnr(as_last, truth)}


def main(model: str, tag: str, *kinds: str) -> None:
    torch.set_num_threads(1)
    outs = {a: SPREAD / f"spread-{tag}-{a:g}.json" for a in MIXES}
    results = {a: json.loads(path.read_text()) if path.is_file() else {} for a, path in outs.items()}
    for kind in kinds or KINDS:
        for seq in load_video_heldout(False, per_kind=8, first=8, kinds={kind}):
            if all(seq.name in results[a].get(kind, {}) for a in MIXES):
                continue
            count, mid = len(seq.gt), len(seq.gt) // 2
            whole, first, last = (both(model, clip) for clip in (seq, clip_frames(seq, mid, count),
                                                                  clip_frames(seq, 0, mid + 1)))
            for a in MIXES:
                row = figures(seq, mixed(whole, a), mixed(first, a)[0], mixed(last, a)[mid])
                results[a].setdefault(kind, {})[seq.name] = row
                outs[a].write_text(json.dumps(results[a], indent=1) + "\n")
            print(seq.name, {a: round(results[a][kind][seq.name]["first_edge_cost_db"], 2) for a in MIXES},
                  flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
