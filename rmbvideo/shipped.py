"""Where the shipped weights live, in a module that imports nothing heavy: a run's fingerprint hashes them for every
method, and a classical method's run must not load torch to find them."""

from __future__ import annotations

import os
from pathlib import Path

#: ``rmbvideo/models`` links to the repository's top-level ``models/`` folder.
MODELS_DIR = Path(__file__).resolve().parent / "models"
#: When a run has an RMB-Net's edge model make a clip's edge frames: "auto" where one is beside it, "off" never
EDGE_MODEL_KINDS = ("auto", "off")


def edge_model_path(weights: str | os.PathLike[str]) -> Path | None:
    """The edge model of the RMB-Net at ``weights``: ``NAME-edges.safetensors`` beside it (a network trained on a
    clip's first and last w frames alone, ``optim.edge_only``; ``rmbvideo.recon.clip_edges``), or None."""
    main = Path(weights)
    stem = main.name.removesuffix(".safetensors")
    companion = main.with_name(f"{stem}-edges.safetensors")
    return companion if companion.is_file() else None
