"""An edge model of its own, on the development video clips only: the edge check (``edge_report``'s figures) of the
shipped model with ``--edges off`` (its own edge frames) and with an edge model making the clip's first and last w
frames as the engine does (``rmbvideo.recon.clip_edges``: each edge a clip of its own of 2w frames). The edge model is
the shipped one (``models/rmbnet-binned-edges.safetensors``), or EDGE: a copy of the shipped model with EDGE beside it
as its edge model. Run from the repository root (about two minutes a model, one core):

    python models/experiments/edge-candidates/edge_model.py [EDGE.safetensors]
"""

import shutil
import sys
import tempfile
from pathlib import Path

from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.video_checks import edge_report
from rmbvideo.net.weights import default_model_path


def with_edge_model(edge: str, folder: Path) -> Path:
    """A copy of the shipped model in ``folder`` with ``edge`` beside it as its edge model."""
    shipped = default_model_path()
    for suffix in (".safetensors", ".json"):
        shutil.copy(shipped.with_suffix(suffix), folder / f"model{suffix}")
        shutil.copy(Path(edge).with_suffix(suffix), folder / f"model-edges{suffix}")
    return folder / "model.safetensors"


def main(edge: str | None = None) -> None:
    options = {"threads": 1, "input_mode": "binned", "precision": "fp32"}
    with tempfile.TemporaryDirectory() as folder:
        model = default_model_path() if edge is None else with_edge_model(edge, Path(folder))
        print("| clip | edge frames by | first below median (dB) | last below median | first offset (ms) | "
              "last offset | edge cost, first (dB) | edge cost, last |")
        print("|---|---|" + "---:|" * 6)
        for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
            for label, edges in (("the model", "off"), ("edge model", "auto")):
                r = edge_report(seq, "rmbnet", {**options, "model": str(model), "edges": edges})
                values = (r.first_drop_db, r.last_drop_db, r.first_offset_ms, r.last_offset_ms, r.first_edge_cost_db,
                          r.last_edge_cost_db)
                print(f"| {seq.name} | {label} | " + " | ".join(f"{v:+.2f}" for v in values) + " |", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
