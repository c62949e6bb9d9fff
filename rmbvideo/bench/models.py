"""Which RMB-Net weights a benchmark row runs: trained ones from ``models/`` or ``models/ablations/``
when a card matches the row's architecture, else a seeded random-init network of that config
(timed, but its accuracy is not reported)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

RANDOM_SEED = 0


@dataclass(frozen=True)
class ModelChoice:
    """The weights of one row: ``path`` of a trained model, or None for random init."""

    path: Path | None

    @property
    def trained(self) -> bool:
        """Whether accuracy of this model means anything."""
        return self.path is not None

    @property
    def label(self) -> str:
        """Short description for tables: the weight file's name or "random-init"."""
        return self.path.name if self.path is not None else "random-init"


def _card_matches(card: Path, w: int, width: float, input_mode: str) -> bool:
    try:
        arch = json.loads(card.read_text()).get("architecture", {})
    except (OSError, ValueError, AttributeError):
        return False
    return (arch.get("w") == w and float(arch.get("width", -1)) == float(width)
            and arch.get("input_mode") == input_mode and arch.get("use_xba", True) and arch.get("use_xta", True))


def find_model(w: int, width: float, models_dir: Path, input_mode: str = "binned") -> ModelChoice:
    """The first trained full model (XBA and XTA on) for ``w``/``width`` under ``models_dir``
    (the default model first, then ``ablations/``, by name), or random init."""
    default = models_dir / f"rmbnet-{input_mode}.safetensors"
    candidates = [default] + sorted((models_dir / "ablations").glob("*.safetensors"))
    for weights in candidates:
        if weights.is_file() and _card_matches(weights.with_suffix(".json"), w, width, input_mode):
            return ModelChoice(weights)
    return ModelChoice(None)


def build_network(w: int, width: float, choice: ModelChoice):
    """The ``RmbNet`` of ``choice`` (loaded safely) or a random-init one seeded with ``RANDOM_SEED``."""
    import torch

    from rmbvideo.net.config import RmbNetConfig
    from rmbvideo.net.model import RmbNet
    from rmbvideo.net.weights import load_model

    if choice.path is not None:
        model, _card = load_model(choice.path, expect_input_mode="binned", device="cpu")
        return model
    generator_state = torch.random.get_rng_state()
    torch.manual_seed(RANDOM_SEED)
    try:
        return RmbNet(RmbNetConfig(w=w, width=width)).eval()
    finally:
        torch.random.set_rng_state(generator_state)
