"""Safe weight files for RMB-Net and the detail stage: ``name.safetensors`` (tensors only) + ``name.json``
(model card).

Loading never executes code from a file: no ``torch.load``, no pickle. The safetensors header is
checked before anything else, so a pickle, a ``.pt`` checkpoint or random bytes are refused with a
``ModelError``; so is a card that does not describe a network this code can build, or weights that
do not fit it.
"""

from __future__ import annotations

import json
import logging
import math
import os
import struct
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import torch
from safetensors import safe_open
from safetensors.torch import save_file

from rmbvideo import __version__
from rmbvideo.errors import ModelError
from rmbvideo.io.atomic import atomic_path, atomic_write_text, outputs_together
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.detail import DetailConfig, DetailNet
from rmbvideo.net.model import RmbNet
from rmbvideo.net.raw_gate import RawGate, RawGateConfig
from rmbvideo.shipped import MODELS_DIR

log = logging.getLogger(__name__)

CARD_FORMAT = "rmbvideo-rmbnet"
DETAIL_CARD_FORMAT = "rmbvideo-detail"
RAW_GATE_CARD_FORMAT = "rmbvideo-raw-gate"
CARD_FORMAT_VERSION = 1
#: card format -> (what it is, its config class, its network class)
_KINDS: dict[str, tuple[str, Any, Any]] = {
    CARD_FORMAT: ("an RMB-Net model card", RmbNetConfig, RmbNet),
    DETAIL_CARD_FORMAT: ("a detail-stage model card", DetailConfig, DetailNet),
    RAW_GATE_CARD_FORMAT: ("a raw-gate model card", RawGateConfig, RawGate),
}
MAX_HEADER_BYTES = 100 * 1024 * 1024
DEFAULT_MODELS = {"binned": "rmbnet-binned", "native": "rmbnet-native"}
#: The shipped detail stage of ``--resolution full`` (``rmbvideo.net.detail``).
DEFAULT_DETAIL = "detail-binned"
#: The shipped raw-interval gate of 1-bit captures (``rmbvideo.net.raw_gate``).
DEFAULT_RAW_GATE = "raw-gate"


def bundled_path(path: Path) -> Path:
    """``path`` as given, or where a relative one does not exist from the current folder, the same path beside the
    shipped models' folder (the repository root): a bundled recipe names its ``init`` weights from there
    ("models/training/..."), so it runs from any folder."""
    path = Path(path)
    if path.is_absolute() or path.exists():
        return path
    beside = MODELS_DIR.resolve().parent / path
    return beside if beside.exists() else path


def default_detail_path() -> Path:
    """Where the shipped detail stage lives (it may be absent: then full resolution is classical)."""
    return MODELS_DIR / f"{DEFAULT_DETAIL}.safetensors"


def default_raw_gate_path() -> Path:
    """Where the shipped raw-interval gate lives (it may be absent: then RMB-Net's binned frame is kept)."""
    return MODELS_DIR / f"{DEFAULT_RAW_GATE}.safetensors"


def default_model_path(input_mode: str = "binned", readout: str | None = None) -> Path:
    """The shipped weights for ``input_mode`` ("binned" for real cameras, "native" RMB sensors); with
    ``readout``, the shipped model trained on that readout design (``rmbnet-binned-<readout>``) when the
    default one was trained on another (else the default, with a warning)."""
    if input_mode not in DEFAULT_MODELS:
        raise ModelError(f"no shipped model for input mode {input_mode!r} (known: {sorted(DEFAULT_MODELS)})")
    path = MODELS_DIR / f"{DEFAULT_MODELS[input_mode]}.safetensors"
    if readout is not None and input_mode == "binned" and model_readout(path) != readout:
        specific = MODELS_DIR / f"{DEFAULT_MODELS[input_mode]}-{readout}.safetensors"
        if specific.is_file():
            return specific
        log.warning("no shipped model for the %s readout; the default model was trained on %s", readout,
                    model_readout(path))
    if not path.is_file():
        raise ModelError(f"{path}: shipped model not found; reinstall rmbvideo or pass --model")
    return path


def model_readout(weights: Path) -> str:
    """The readout design the model at ``weights`` was trained on, from its card ("rmb" if unsaid)."""
    try:
        card = json.loads(Path(weights).with_suffix(".json").read_text())
        return str(card.get("architecture", {}).get("readout", "rmb"))
    except (OSError, ValueError, AttributeError):
        return "rmb"


def shipped_model_with_window(input_mode: str, w: int) -> Path:
    """A shipped full model (XBA and XTA on; the default model's readout or RMB's, and reconstruct reads
    through the one it was trained on) for ``input_mode`` whose window half-width is ``w``: the default
    model first, then the ablation models in ``models/ablations``."""
    candidates = [default_model_path(input_mode)] + sorted((MODELS_DIR / "ablations").glob("*.safetensors"))
    for weights in candidates:
        try:
            card = json.loads(weights.with_suffix(".json").read_text())
        except (OSError, ValueError):
            continue
        arch = card.get("architecture", {}) if isinstance(card, dict) else {}
        if (arch.get("w") == w and arch.get("input_mode") == input_mode and arch.get("use_xba")
                and arch.get("use_xta") and arch.get("readout", "rmb") in ("rmb", model_readout(candidates[0]))):
            return weights
    raise ModelError(f"no shipped {input_mode} model with w = {w}; train one (rmbvideo train) and pass --model")


@dataclass
class ModelCard:
    """What a weight file is: how it was trained, on what, how well it does, by which code.

    The architecture (including input mode, N and w) is written from the model's own config.
    """

    name: str
    description: str = ""
    training: dict[str, Any] = field(default_factory=dict)  # recipe: loss, epochs, optimiser, ...
    data: dict[str, Any] = field(default_factory=dict)      # training data and its licence
    metrics: dict[str, float] = field(default_factory=dict)
    code_version: str = __version__


def model_paths(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """The weights file (``.safetensors`` added if missing) and the JSON card beside it that ``path`` names."""
    weights = Path(path)
    if weights.suffix != ".safetensors":
        weights = weights.with_name(weights.name + ".safetensors")
    return weights, weights.with_suffix(".json")


def save_model(path: str | os.PathLike[str], model: RmbNet | DetailNet | RawGate, card: ModelCard) -> Path:
    """Write ``path`` (.safetensors added if missing) and its JSON card; returns the weights path."""
    weights, card_path = model_paths(path)
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in model.state_dict().items()}
    card_format = next(name for name, (_, _, kind) in _KINDS.items() if isinstance(model, kind))
    document = {
        "format": card_format,
        "format_version": CARD_FORMAT_VERSION,
        "architecture": model.config.to_dict(),
        **asdict(card),
    }
    with outputs_together(weights.parent, (weights.name, card_path.name)):  # a card always of its own weights
        with atomic_path(weights) as temp:
            save_file(tensors, str(temp), metadata={"format": card_format,
                                                    "architecture": _architecture_text(model.config)})
        atomic_write_text(card_path, json.dumps(document, indent=2) + "\n")
    return weights


def _read_card(card_path: Path, card_format: str = CARD_FORMAT) -> tuple[Any, ModelCard]:
    try:
        document = json.loads(card_path.read_text())
    except OSError as exc:
        raise ModelError(f"{card_path}: cannot read the model card ({exc.strerror})") from None
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise ModelError(f"{card_path}: model card is not valid JSON") from None
    what, config_class, _ = _KINDS[card_format]
    if not isinstance(document, dict) or document.get("format") != card_format:
        raise ModelError(f"{card_path}: not {what} (format must be {card_format!r})")
    if document.get("format_version") != CARD_FORMAT_VERSION:
        raise ModelError(f"{card_path}: card format version {document.get('format_version')!r} "
                         f"is not supported (expected {CARD_FORMAT_VERSION})")
    card_keys = {f.name for f in fields(ModelCard)}
    unknown = sorted(set(document) - card_keys - {"format", "format_version", "architecture"})
    if unknown:
        raise ModelError(f"{card_path}: unknown model card keys {unknown}")
    try:
        config = config_class.from_dict(document["architecture"])
        card = ModelCard(**{k: document[k] for k in card_keys if k in document})
    except KeyError as exc:
        raise ModelError(f"{card_path}: architecture does not match this code: {exc.args[0]}") from None
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{card_path}: invalid architecture: {exc}") from None
    return config, card


def _architecture_text(config: RmbNetConfig | DetailConfig | RawGateConfig) -> str:
    """The architecture as stored inside the weights, so a card that contradicts them is caught."""
    return json.dumps(config.to_dict(), sort_keys=True)


def _check_safetensors_header(weights: Path) -> None:
    """Refuse anything whose first bytes are not a safetensors JSON header."""
    try:
        size = weights.stat().st_size
        with weights.open("rb") as fh:
            head = fh.read(8)
            if len(head) < 8:
                raise ValueError
            (length,) = struct.unpack("<Q", head)
            if not 2 <= length <= min(MAX_HEADER_BYTES, size - 8):
                raise ValueError
            header = json.loads(fh.read(length).decode("utf-8"))
            if not isinstance(header, dict):
                raise ValueError
    except OSError as exc:
        raise ModelError(f"{weights}: cannot read ({exc.strerror})") from None
    except (ValueError, UnicodeDecodeError):
        raise ModelError(f"{weights}: refused: not a safetensors file") from None


def widen_model(old: RmbNet, config: RmbNetConfig, new_logit: float | None = None) -> RmbNet:
    """``old``'s weights in a network of ``config`` that may have gained head inputs and blend candidates:
    tensors of the same shape are copied; a conv that gained input channels keeps the old ones and starts
    the new ones at zero; a last head conv that gained outputs (blend logits) keeps the old outputs and the
    new ones' initialisation (their bias at ``new_logit`` when given), so the result computes (close to)
    ``old``'s function. How a training stage warm-starts from the previous one."""
    widened = RmbNet(config)
    new_state = widened.state_dict()
    for name, tensor in old.state_dict().items():
        target = new_state.get(name)
        if target is None:
            continue
        if target.shape == tensor.shape:
            target.copy_(tensor)
        elif target.dim() == 4 and target.shape[0] == tensor.shape[0] and target.shape[1] > tensor.shape[1]:
            target.zero_()
            target[:, : tensor.shape[1]] = tensor
        elif target.shape[0] > tensor.shape[0] and target.shape[1:] == tensor.shape[1:]:
            target[: tensor.shape[0]] = tensor
            if target.dim() == 1 and new_logit is not None:
                target[tensor.shape[0]:] = new_logit
        else:  # a narrower network: nothing of old's would be kept in this tensor, so say so rather than start it anew
            raise ValueError(f"cannot widen {name} from {tuple(tensor.shape)} to {tuple(target.shape)}: the new network "
                             "lacks inputs or outputs the old one has")
    widened.load_state_dict(new_state)
    return widened.eval()


def without_window(old: RmbNet) -> RmbNet:
    """``old`` at w = 0, to train a model without the window from everything ``old`` learned: every weight kept but
    the head's inputs from the pooled windows' means and the edge planes, and the pooled windows' blend logits, which
    a network without a window lacks (the attention then reads the reference frame alone). Where those weights are
    zero (the logits' far below the rest) it computes what ``old`` does on a window whose other frames are all
    missing."""
    cfg = old.config
    narrow = RmbNet(replace(cfg, w=0, pooled_windows=(), edge_input=False))
    state = old.state_dict()
    first, last = "decoder.head.0.0", f"decoder.head.{len(old.decoder.head) - 1}"
    features, inputs = state[f"{first}.weight"].shape[:2]
    # the head reads the decoder's features (as many as it makes), then ``RmbNet._head_inputs``: the reference's 2,
    # 2 per pooled window, ..., the 2 edge planes last
    pooled = range(features + 2, features + 2 + 2 * len(cfg.pooled_windows))
    edge = range(inputs - 2 * int(cfg.edge_input), inputs)
    state[f"{first}.weight"] = state[f"{first}.weight"][:, [c for c in range(inputs) if c not in pooled and c not in edge]]
    if cfg.blend:  # outputs: t, then the logits of (own estimate, reference box, each pooled window, ...)
        logits = [c for c in range(state[f"{last}.bias"].shape[0]) if c not in range(3, 3 + len(cfg.pooled_windows))]
        for name in ("weight", "bias"):
            state[f"{last}.{name}"] = state[f"{last}.{name}"][logits]
    narrow.load_state_dict(state)
    return narrow.eval()


def merge_aligned_candidates(old: RmbNet, difference: float) -> RmbNet:
    """``old`` without its second aligned mean (``aligned_centre`` -> 0: the central readouts' mean, whose flows
    and warps cost a third of the aligned means' time), as if that input were the whole frames' mean: its
    head-input weights join the whole-frame mean's (exact), and its blend logit l_s joins the whole-frame
    one's l_a as log(e^l_a + e^l_s) = l_a + softplus(l_s - l_a), linearised at l_s - l_a = ``difference``
    (exact where the logits differ by that; a short fine-tuning of the last head conv does the rest)."""
    cfg = old.config
    if not cfg.aligned_centre:
        raise ValueError("the model has no second aligned mean to merge")
    merged = RmbNet(replace(cfg, aligned_centre=0))
    state = old.state_dict()
    first, last = (f"decoder.head.{k}" for k in (0, len(old.decoder.head) - 1))
    # head inputs end with (whole-frame mean, central readouts' mean); blend logits likewise
    weight = state[f"{first}.0.weight"].clone()
    weight[:, -2] += weight[:, -1]
    state[f"{first}.0.weight"] = weight[:, :-1]
    slope = 0.5 * (1.0 + math.tanh(0.5 * difference))  # sigmoid, finite for any difference
    softplus = max(difference, 0.0) + math.log1p(math.exp(-abs(difference)))  # no overflow for large differences
    offset = softplus - slope * difference
    for name in ("weight", "bias"):
        logits = state[f"{last}.{name}"].clone()
        logits[-2] = (1.0 - slope) * logits[-2] + slope * logits[-1]
        if name == "bias":
            logits[-2] += offset
        state[f"{last}.{name}"] = logits[:-1]
    merged.load_state_dict(state)
    return merged.eval()


def average_models(first: RmbNet, second: RmbNet, alpha: float) -> RmbNet:
    """A copy of ``first`` with weights ``alpha * first + (1 - alpha) * second`` (integer buffers from
    ``first``): a point on the straight path between two fine-tunings of one model (how stage 5 of the
    shipped default was made). Models of different architectures are refused."""
    if first.config != second.config:
        raise ModelError("cannot average models of different architectures")
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    mixed = RmbNet(first.config)
    a, b = first.state_dict(), second.state_dict()
    mixed.load_state_dict({k: (alpha * a[k].float() + (1 - alpha) * b[k].float()).to(a[k].dtype)
                           if a[k].is_floating_point() else a[k] for k in a})
    return mixed.eval()


def load_model(
    path: str | os.PathLike[str],
    expect_input_mode: str | None = None,
    device: str | torch.device = "cpu",
) -> tuple[RmbNet, ModelCard]:
    """Load a weight file and its card into an eval-mode ``RmbNet`` on ``device``.

    Raises ``ModelError`` for a missing, foreign or corrupt file, a card that does not match the
    code, tensors that do not match the card, or an input mode other than ``expect_input_mode``.
    """
    model, card = _load(path, CARD_FORMAT, device, expect_input_mode)
    return model, card


def load_detail_model(path: str | os.PathLike[str], device: str | torch.device = "cpu") -> tuple[DetailNet, ModelCard]:
    """Load a detail-stage weight file and its card (``rmbvideo.net.detail``), with ``load_model``'s checks."""
    model, card = _load(path, DETAIL_CARD_FORMAT, device)
    return model, card


def load_raw_gate(path: str | os.PathLike[str], device: str | torch.device = "cpu") -> tuple[RawGate, ModelCard]:
    """Load a raw-gate weight file and its card (``rmbvideo.net.raw_gate``), with ``load_model``'s checks."""
    return _load(path, RAW_GATE_CARD_FORMAT, device)


def _load(path: str | os.PathLike[str], card_format: str, device: str | torch.device,
          expect_input_mode: str | None = None) -> tuple[Any, ModelCard]:
    weights, card_path = model_paths(path)
    if not weights.is_file():
        raise ModelError(f"{weights}: model file not found")
    if not card_path.is_file():
        raise ModelError(f"{card_path}: model card not found (expected beside {weights.name})")
    config, card = _read_card(card_path, card_format)
    if expect_input_mode is not None and config.input_mode != expect_input_mode:
        raise ModelError(f"{weights}: model was trained for {config.input_mode!r} input, "
                         f"this input is {expect_input_mode!r}")
    _check_safetensors_header(weights)
    try:
        with safe_open(str(weights), framework="pt", device="cpu") as fh:
            tensors = {key: fh.get_tensor(key) for key in fh.keys()}
            stored = (fh.metadata() or {}).get("architecture")
    except Exception as exc:  # safetensors raises its own error types for corrupt payloads
        raise ModelError(f"{weights}: refused: corrupt safetensors file ({exc})") from None
    bad = sorted(key for key, tensor in tensors.items() if tensor.is_floating_point() and not bool(tensor.isfinite().all()))
    if bad:
        raise ModelError(f"{weights}: refused: NaN or Inf in {len(bad)} tensors (first: {bad[0]})")
    model = _KINDS[card_format][2](config)
    expected = model.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    mismatched = sorted(k for k in set(expected) & set(tensors) if expected[k].shape != tensors[k].shape)
    problems = []
    if missing:
        problems.append(f"missing tensors {missing[:3]}{' ...' if len(missing) > 3 else ''}")
    if unexpected:
        problems.append(f"unexpected tensors {unexpected[:3]}{' ...' if len(unexpected) > 3 else ''}")
    if mismatched:
        k = mismatched[0]
        problems.append(f"shape mismatch for {k}: file {tuple(tensors[k].shape)}, "
                        f"card/code {tuple(expected[k].shape)}")
    if problems:
        raise ModelError(f"{weights}: weights do not match the model card: {'; '.join(problems)}")
    if stored is not None and stored != _architecture_text(config):
        try:
            saved = json.loads(stored)
            differs = sorted(k for k in set(saved) | set(config.to_dict()) if saved.get(k) != config.to_dict().get(k))
        except (ValueError, AttributeError):
            differs = ["(unreadable)"]
        raise ModelError(f"{weights}: refused: the card's architecture contradicts the weights' own "
                         f"({', '.join(f'{k}' for k in differs[:4])})")
    model.load_state_dict(tensors)
    log.debug("loaded %s (%s)", weights, card.name)
    return model.to(device).eval(), card
