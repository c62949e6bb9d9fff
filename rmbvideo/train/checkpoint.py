"""Resumable training checkpoints without pickle: ``checkpoint.safetensors`` holds the model
weights (``model.*``) and Adam's moment tensors (``adam.<param index>.exp_avg`` / ``.exp_avg_sq``);
the step, elapsed wall time and Adam's per-parameter step counts are in its header, so that one rename commits a
checkpoint whole; ``checkpoint.json`` repeats them for people and scripts. A crash, kill or power cut between the
two writes leaves a checkpoint that resumes from the tensors' own step. A checkpoint from before its header held them
(the step alone) resumes only when the JSON agrees with it.

``checkpointed_on_stop`` saves the last whole step when a run is stopped (Ctrl-C, SIGTERM, SIGHUP), so that no
training is lost to a stop and ``--resume`` continues where it stood.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file

from rmbvideo.errors import InputError, OutputError
from rmbvideo.io.atomic import atomic_path, atomic_write_text, signals_deferred

CHECKPOINT_FORMAT = "rmbvideo-train-checkpoint"
ADAM_MOMENTS = ("exp_avg", "exp_avg_sq")


@dataclass(frozen=True)
class CheckpointState:
    """Where a run stands: optimisation steps done and training wall time so far (seconds)."""

    step: int
    elapsed_s: float


def checkpoint_paths(out_dir: Path) -> tuple[Path, Path]:
    """(tensors, metadata) paths of the checkpoint in ``out_dir``."""
    return out_dir / "checkpoint.safetensors", out_dir / "checkpoint.json"


def refuse_to_restart_over(out_dir: Path) -> None:
    """An ``OutputError`` if ``out_dir`` holds a checkpoint: a run started without --resume would replace it, and
    with it the days of training it may hold, at its first save."""
    tensor_path, meta_path = checkpoint_paths(out_dir)
    if not tensor_path.exists() and not meta_path.exists():
        return
    try:
        meta = json.loads(meta_path.read_text())
        where = f" at step {int(meta['step'])}, {float(meta['elapsed_s']) / 60:.1f} min trained"
    except (OSError, ValueError, KeyError, TypeError):
        where = ""
    raise OutputError(f"{out_dir}: holds the checkpoint of an earlier run{where}; --resume continues it, "
                      "--overwrite starts afresh over it")


def save_checkpoint(out_dir: Path, model: torch.nn.Module, optimizer: torch.optim.Adam,
                    state: CheckpointState) -> None:
    """Write the checkpoint atomically, signals held until it is written: the tensors with the whole state in their
    header (the commit), then the JSON copy of that state."""
    with signals_deferred():
        _save(out_dir, model, optimizer, state)


def _save(out_dir: Path, model: torch.nn.Module, optimizer: torch.optim.Adam, state: CheckpointState) -> None:
    tensor_path, meta_path = checkpoint_paths(out_dir)
    tensors = {f"model.{k}": v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    adam_steps: dict[str, float] = {}
    params = [p for group in optimizer.param_groups for p in group["params"]]
    for index, param in enumerate(params):
        moments = optimizer.state.get(param)
        if not moments:
            continue
        adam_steps[str(index)] = float(moments["step"])
        for name in ADAM_MOMENTS:
            tensors[f"adam.{index}.{name}"] = moments[name].detach().cpu().contiguous()
    meta = {"format": CHECKPOINT_FORMAT, "step": state.step, "elapsed_s": state.elapsed_s,
            "adam_steps": adam_steps}
    header = {"format": CHECKPOINT_FORMAT, "step": str(state.step), "elapsed_s": repr(state.elapsed_s),
              "adam_steps": json.dumps(adam_steps)}
    with atomic_path(tensor_path) as temp:
        save_file(tensors, str(temp), metadata=header)
    atomic_write_text(meta_path, json.dumps(meta, indent=2) + "\n")


@contextmanager
def checkpointed_on_stop(out_dir: Path, model: torch.nn.Module, optimizer: torch.optim.Adam,
                         state: Callable[[], CheckpointState]) -> Iterator[None]:
    """Around a training loop: a stop (Ctrl-C, SIGTERM, SIGHUP) saves the checkpoint of ``state()``, the last whole
    step, before the run ends, and the stop's one line (``left_behind``) says so; a second stop waits for the save."""
    try:
        yield
    except KeyboardInterrupt as stop:
        current = state()
        try:
            save_checkpoint(out_dir, model, optimizer, current)
        except KeyboardInterrupt as again:  # held while the checkpoint was written: it is whole
            stop = again
        stop.left_behind = (f"the checkpoint of step {current.step} is saved in {out_dir}; --resume continues from "
                            "it")
        raise stop


def _misfit(stored: dict[str, torch.Tensor], expected: dict[str, torch.Tensor]) -> str:
    """How the tensors ``stored`` differ from a model's ``expected`` ones, on one line ("" when they fit)."""
    parts = []
    missing, unexpected = sorted(set(expected) - set(stored)), sorted(set(stored) - set(expected))
    reshaped = [k for k in stored if k in expected and stored[k].shape != expected[k].shape]
    if reshaped:
        k = reshaped[0]
        parts.append(f"{len(reshaped)} tensors of another shape, e.g. {k}: {list(stored[k].shape)} stored, "
                     f"{list(expected[k].shape)} in the model")
    if missing:
        parts.append(f"{len(missing)} missing, e.g. {missing[0]}")
    if unexpected:
        parts.append(f"{len(unexpected)} not in the model, e.g. {unexpected[0]}")
    return "; ".join(parts)


def _header_state(header: dict[str, str]) -> dict | None:
    """The state a checkpoint's tensor header holds whole (None for one that holds only its step)."""
    if "adam_steps" not in header or "elapsed_s" not in header:
        return None
    return {"format": header.get("format"), "step": header.get("step"), "elapsed_s": float(header["elapsed_s"]),
            "adam_steps": json.loads(header["adam_steps"])}


def load_checkpoint(out_dir: Path, model: torch.nn.Module, optimizer: torch.optim.Adam) -> CheckpointState:
    """Restore model and optimizer from ``out_dir``; ``InputError`` if missing or inconsistent."""
    tensor_path, meta_path = checkpoint_paths(out_dir)
    if not tensor_path.is_file():
        raise InputError(f"{out_dir}: no checkpoint to resume from (expected {tensor_path.name} and {meta_path.name})")
    try:
        with safe_open(str(tensor_path), framework="pt", device="cpu") as fh:
            header = fh.metadata() or {}
            tensors = {key: fh.get_tensor(key) for key in fh.keys()}
        meta = _header_state(header) or json.loads(meta_path.read_text())
    except FileNotFoundError:
        raise InputError(f"{out_dir}: no checkpoint to resume from (expected {tensor_path.name} and "
                         f"{meta_path.name})") from None
    except Exception as exc:  # corrupt JSON or safetensors payloads raise their own error types
        raise InputError(f"{out_dir}: unreadable checkpoint ({exc})") from None
    if meta.get("format") != CHECKPOINT_FORMAT or header.get("step") != str(meta.get("step")):
        raise InputError(f"{out_dir}: checkpoint files disagree or are not rmbvideo checkpoints")
    device = next(model.parameters()).device
    model_state = {k[len("model."):]: v for k, v in tensors.items() if k.startswith("model.")}
    misfit = _misfit(model_state, model.state_dict())
    if misfit:
        raise InputError(f"{tensor_path}: checkpoint does not fit this recipe's model ({misfit})")
    model.load_state_dict(model_state)
    params = [p for group in optimizer.param_groups for p in group["params"]]
    optimizer_state = optimizer.state_dict()
    optimizer_state["state"] = {
        int(index): {"step": torch.tensor(step),
                     **{name: tensors[f"adam.{index}.{name}"].to(device) for name in ADAM_MOMENTS}}
        for index, step in meta["adam_steps"].items() if int(index) < len(params)
    }
    optimizer.load_state_dict(optimizer_state)
    return CheckpointState(step=int(meta["step"]), elapsed_s=float(meta["elapsed_s"]))
