"""Training recipes: a TOML file parsed into dataclasses (``TrainConfig``).

Top-level keys ``name`` (output file stem), ``seed``, ``minutes`` (wall-time budget) and
``description``; tables ``[data]`` (``DataConfig``), ``[model]`` (``RmbNetConfig`` fields: w,
width, use_xba, use_xta, ...; ``input_mode`` and ``n`` come from ``[data]``), ``[optim]``
(``OptimConfig``) and ``[loss]`` (``LossConfig``). Unknown keys are errors, so a typo never trains
the wrong model silently.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from rmbvideo.errors import InputError
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.recon.precision import PRECISIONS
from rmbvideo.train.dataset import SampleSpec
from rmbvideo.train.loss import LossConfig
from rmbvideo.scenes.random_scenes import SceneRanges
from rmbvideo.scenes.video import FLAT_MIN_RATE

RECIPES_DIR = Path(__file__).resolve().parent / "recipes"


@dataclass(frozen=True)
class DataConfig:
    """Training data: input ``mode`` (binned/native), ``readout`` design, ``count`` training
    scenes (seeds 0..count-1), square ``crop`` (output px), ``steps`` K supervised steps per sample,
    ``exposure`` range (electrons per raw readout at median radiance), ``val_count`` held-out
    scenes (seeds from 1,000,000). ``scenes``: "panorama" (pans over the bundled panoramas, ``count``
    cached scenes) or "video" (dead-leaves video scenes, simulated afresh for every step, a fraction
    ``spikezoo_fraction`` in spikezoo's rate convention, ``flat_fraction`` static, nearly flat fields and
    ``low_contrast_fraction`` backgrounds of compressed contrast (the last two training seeds only; flat
    levels log-uniform from ``flat_min_rate`` to 1: the dark end a model is checked at must lie inside it), of the
    physical scenes a fraction ``subtract_fraction`` made by a pixel reset by subtraction (a real camera's such as
    ``car.dat``'s: noisy spikes in the rate convention, the network told so), ``pan_fraction`` of the training scenes
    rigid pans (the camera at a constant 0.02-0.5 raw px/plane, no movers, shake or zoom), each
    used by ``reuse`` consecutive steps, simulated by ``workers`` processes;
    ``count`` and ``exposure`` do not apply)."""

    mode: str = "binned"
    readout: str = "rmb"
    count: int = 512
    crop: int = 64
    steps: int = 6
    n: int = 10
    warmup_frames: int = 3
    exposure: tuple[float, float] = (2.0, 60.0)
    val_count: int = 6
    scenes: str = "panorama"
    spikezoo_fraction: float = 0.0
    flat_fraction: float = 0.0
    low_contrast_fraction: float = 0.0
    flat_min_rate: float = FLAT_MIN_RATE
    subtract_fraction: float = 0.0
    pan_fraction: float = 0.0
    reuse: int = 1
    workers: int = 1


@dataclass(frozen=True)
class OptimConfig:
    """Adam with learning rate ``lr`` (cosine decay to ``lr_final`` over ``steps``), ``batch``
    samples per step, truncated back-propagation over ``tbptt`` consecutive outputs. ``trainable``:
    prefixes of the parameter names that train (empty: all); the rest is frozen, BatchNorm included."""

    lr: float = 1e-3
    lr_final: float = 1e-4
    steps: int = 20000
    batch: int = 2
    tbptt: int = 3
    grad_clip: float = 1.0
    threads: int = 0  # torch intra-op threads; 0 leaves torch's default
    val_every: int = 250
    checkpoint_every: int = 50
    edges: float = 0.0  # fraction of steps that also supervise a sample's first/last w outputs as a clip's edges
    # passes over a sample's outputs without gradients, alternately backwards and forwards and ending backwards at the
    # first, before the supervised run: its state is then as old as a long capture's (passes x outputs steps; one pass
    # is how the engine primes a clip's first frame)
    aged_passes: int = 0
    # frames a sample's state is primed over backwards when its first frame is supervised as a clip's first, as the
    # engine primes a clip (its default: w); 0: a fresh state, as the recipes before the stop of 2026-11-27 (c) had
    prime: int = 0
    # outputs whose window lies whole inside the sample are trained against the ``init`` model's outputs instead of
    # the truth, so a run on the edge frames holds the rest of a clip where that model had it (needs init and edges)
    hold_whole_windows: bool = False
    # only the edge outputs (the first and last w, windows cut by the sample's ends) are in the loss; the others are
    # still run for the recurrent state: a model of its own for a clip's edge frames (needs edges = 1)
    edge_only: bool = False
    trainable: tuple[str, ...] = ()
    # the network's forward passes under bf16 autocast ("bf16"; "auto": where the CPU computes bf16 natively, the
    # engine's policy, ``rmbvideo.recon.precision``), the losses always in fp32 (in bf16 SSIM's sums lose the
    # difference it measures); "fp32", as every recipe before the second stop of 2026-12-01 was trained
    precision: str = "fp32"


@dataclass(frozen=True)
class TrainConfig:
    """A whole recipe; ``recipe_text`` is the file as written (recorded in the model card).
    ``init``: a model file (or the name of a shipped model) whose matching weights start the run;
    ``init_new_logit``: where that model's blend head gains candidates, their logits' bias starts here
    (None: the model's own initialisation, -2, under which a new candidate's weight and gradient are ~0)."""

    name: str
    seed: int = 0
    minutes: float = 45.0
    description: str = ""
    data: DataConfig = field(default_factory=DataConfig)
    model: RmbNetConfig = field(default_factory=RmbNetConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    recipe_text: str = ""
    source: str = ""
    init: str = ""
    init_new_logit: float | None = None

    def sample_spec(self) -> SampleSpec:
        """Samples of 2w + K preliminary frames in this recipe's mode and readout."""
        d = self.data
        return SampleSpec(mode=d.mode, readout=d.readout, crop=d.crop, frames=2 * self.model.w + d.steps,
                          n=d.n, warmup_frames=d.warmup_frames, level=self.model.level,
                          ranges=SceneRanges(exposure=d.exposure), scenes=d.scenes,
                          spikezoo_fraction=d.spikezoo_fraction, flat_fraction=d.flat_fraction,
                          low_contrast_fraction=d.low_contrast_fraction, flat_min_rate=d.flat_min_rate,
                          subtract_fraction=d.subtract_fraction, pan_fraction=d.pan_fraction)

    def with_minutes(self, minutes: float) -> "TrainConfig":
        """The same recipe with another wall-time budget."""
        return replace(self, minutes=minutes)

    def with_steps(self, steps: int) -> "TrainConfig":
        """The same recipe with another step budget (the learning-rate schedule spans it)."""
        return replace(self, optim=replace(self.optim, steps=steps))

    def with_seed(self, seed: int) -> "TrainConfig":
        """The same recipe with another seed: other initial weights and other training scenes (a run's
        spread between seeds, for comparisons such as the ablations)."""
        return replace(self, seed=seed)

    def with_precision(self, precision: str) -> "TrainConfig":
        """The same recipe with the network's forward passes in another precision (``OptimConfig.precision``)."""
        return replace(self, optim=replace(self.optim, precision=precision))

    def with_workers(self, workers: int) -> "TrainConfig":
        """The same recipe simulated by another number of processes (the samples do not change)."""
        return replace(self, data=replace(self.data, workers=workers))


def _typed(cls: type, table: dict[str, Any], where: str, path: Path) -> Any:
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise InputError(f"{path}: unknown key{'s' if len(unknown) > 1 else ''} in [{where}]: {', '.join(unknown)}")
    values = {}
    defaults = cls()
    for name, value in table.items():
        default = getattr(defaults, name)
        if isinstance(default, bool):
            ok = isinstance(value, bool)
        elif isinstance(default, (int, float)):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            if ok and isinstance(default, int) and not isinstance(value, int):
                ok = False
        elif default is None:  # an optional number (e.g. model.aligned_radius: unset means w)
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif isinstance(default, tuple):
            ok = isinstance(value, list) and (len(value) == len(default) or name in ("base_channels", "pooled_windows", "centre_windows", "trainable"))
            value = tuple(value) if ok else value
        else:
            ok = isinstance(value, type(default))
        if not ok:
            raise InputError(f"{path}: [{where}] {name} = {value!r} has the wrong type "
                             f"(expected like {default!r})")
        values[name] = value
    return values


def load_recipe(path: str | Path) -> TrainConfig:
    """Parse and validate a recipe file; every problem is an ``InputError`` naming the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
        data = tomllib.loads(text)
    except FileNotFoundError:
        raise InputError(f"{path}: recipe file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read recipe ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    top = {"name", "seed", "minutes", "description", "init", "init_new_logit", "data", "model", "optim", "loss"}
    unknown = sorted(set(data) - top)
    if unknown:
        raise InputError(f"{path}: unknown top-level keys: {', '.join(unknown)}")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name or "/" in name:
        raise InputError(f"{path}: name must be a non-empty file stem, not {name!r}")
    seed, minutes = data.get("seed", 0), data.get("minutes", 45.0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InputError(f"{path}: seed must be an integer >= 0, not {seed!r}")
    if isinstance(minutes, bool) or not isinstance(minutes, (int, float)) or not minutes > 0:
        raise InputError(f"{path}: minutes must be a number > 0, not {minutes!r}")
    new_logit = data.get("init_new_logit")
    if new_logit is not None and (isinstance(new_logit, bool) or not isinstance(new_logit, (int, float))
                                  or not math.isfinite(new_logit) or "init" not in data):
        raise InputError(f"{path}: init_new_logit must be a finite number and needs init, not {new_logit!r}")
    tables = {}
    for key in ("data", "model", "optim", "loss"):
        table = data.get(key, {})
        if not isinstance(table, dict):
            raise InputError(f"{path}: {key} must be a table ([{key}])")
        tables[key] = table
    if {"input_mode", "n", "readout"} & set(tables["model"]):
        raise InputError(f"{path}: [model] input_mode, n and readout are set by [data] mode, n and readout")
    try:
        data_config = DataConfig(**_typed(DataConfig, tables["data"], "data", path))
        model_values = _typed(RmbNetConfig, tables["model"], "model", path)
        model = RmbNetConfig(**model_values, input_mode=data_config.mode, n=data_config.n,
                             readout=data_config.readout)
        optim = OptimConfig(**_typed(OptimConfig, tables["optim"], "optim", path))
        loss = LossConfig(**_typed(LossConfig, tables["loss"], "loss", path))
        config = TrainConfig(name=name, seed=seed, minutes=float(minutes),
                             description=str(data.get("description", "")), data=data_config, model=model,
                             optim=optim, loss=loss, recipe_text=text, source=recipe_source(path),
                             init=str(data.get("init", "")),
                             init_new_logit=None if new_logit is None else float(new_logit))
        config.sample_spec()  # validates mode/readout/crop
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    _check_ranges(config, path)
    return config


def _check_ranges(config: TrainConfig, path: Path) -> None:
    d, o = config.data, config.optim
    problems = []
    if d.count < 1 or d.val_count < 1 or d.steps < 1 or d.reuse < 1 or d.workers < 1:
        problems.append("data.count, data.val_count, data.steps, data.reuse and data.workers must be >= 1")
    if not 0 < d.exposure[0] <= d.exposure[1]:
        problems.append("data.exposure must be [low, high] with 0 < low <= high")
    if o.aged_passes < 0 or o.prime < 0:
        problems.append("optim.aged_passes and optim.prime must be >= 0")
    if o.hold_whole_windows and (not (config.init and o.edges > 0) or o.aged_passes):
        problems.append("optim.hold_whole_windows needs init (the model it holds to) and edges > 0, and no aged_passes "
                        "(the held outputs start from a fresh or primed state)")
    if o.edge_only and (o.edges < 1.0 or o.hold_whole_windows or o.aged_passes):
        problems.append("optim.edge_only needs edges = 1 (every step's edge frames), and no hold_whole_windows or "
                        "aged_passes")
    if o.lr <= 0 or o.lr_final <= 0 or o.steps < 1 or o.batch < 1 or o.tbptt < 1:
        problems.append("optim.lr, lr_final, steps, batch and tbptt must be positive")
    if not 0.0 <= o.edges <= 1.0:
        problems.append("optim.edges must be a fraction of steps in [0, 1]")
    if o.precision not in PRECISIONS:
        problems.append(f"optim.precision must be one of {', '.join(PRECISIONS)}")
    if o.val_every < 1 or o.checkpoint_every < 1 or o.threads < 0:
        problems.append("optim.val_every and checkpoint_every must be >= 1, threads >= 0")
    if problems:
        raise InputError(f"{path}: {'; '.join(problems)}")


def recipe_source(path: Path) -> str:
    """How a model card names its recipe: a bundled one by its path in the package (the same on every
    machine), any other file as given."""
    resolved = Path(path).resolve()
    if resolved.parent == RECIPES_DIR:
        return f"rmbvideo/train/recipes/{resolved.name}"
    return str(path)


def bundled_recipe(name: str) -> Path:
    """Path of a bundled recipe (``rmbvideo/train/recipes/NAME.toml``)."""
    return RECIPES_DIR / f"{name}.toml"


def bundled_recipes() -> dict[str, str]:
    """Every bundled recipe's name and the first line of the comment it opens with (what it is for)."""
    summaries = {}
    for path in sorted(RECIPES_DIR.glob("*.toml")):
        first = path.read_text(encoding="utf-8").lstrip().splitlines()[:1]
        summaries[path.stem] = first[0].lstrip("#").strip() if first and first[0].startswith("#") else ""
    return summaries
