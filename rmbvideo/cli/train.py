"""``rmbvideo train RECIPE``: train RMB-Net from a TOML recipe (see ``rmbvideo.train.config``);
``rmbvideo train-detail``: train the detail stage of ``--resolution full`` (``rmbvideo.train.detail``).

RECIPE is a path or the name of a bundled recipe (``cpu``, ``gpu``, ``native-cpu``, ``ablation-*``;
``rmbvideo/train/recipes/``). Output in ``--out`` (default ``train-<name>``): ``loss.csv``,
``checkpoint.safetensors``/``.json`` and, at the end, ``<name>.safetensors`` + ``<name>.json``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click

from rmbvideo.cli import progress_enabled, quiet_option, verbose_option
from rmbvideo.cli.options import DEVICE_CHOICE, AliasOption
from rmbvideo.io.atomic import output_folder


@click.command()
@click.argument("recipe", metavar="RECIPE", required=False)
@click.option("--list", "list_recipes", is_flag=True, help="List the bundled recipes, each with what it is for, and exit.")
@click.option("-o", "--output", "--out", "out_dir", cls=AliasOption, aliases=("--out",),
              type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder (default: train-<recipe name> in the current folder).")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder of cached training samples, shareable between runs (default: OUT/cache).")
@click.option("--resume", is_flag=True, help="Continue from the checkpoint in --out.")
@click.option("--overwrite", is_flag=True,
              help="Start afresh in a folder that holds an earlier run's checkpoint (refused without it or --resume).")
@click.option("--minutes", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Override the recipe's wall-time budget.")
@click.option("--steps", type=click.IntRange(min=1), default=None,
              help="Override the recipe's step budget (e.g. an ablation set at a longer equal budget).")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Override the recipe's seed (other initial weights and training scenes: a comparison's spread).")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Override the recipe's simulation processes for video scenes (e.g. on a many-core GPU "
                   "machine); the samples are the same for any count.")
@click.option("--device", type=DEVICE_CHOICE, default="auto", show_default=True,
              help="Where to train (auto: CUDA when available, else CPU).")
@click.option("--precision", type=click.Choice(["auto", "fp32", "bf16"]), default=None,
              help="Override the recipe's precision of the network's forward passes (bf16: under bf16 autocast, "
                   "the losses in fp32; auto: bf16 on CPUs with AVX512-BF16 or AMX) [default: the recipe's, fp32].")
@quiet_option
@verbose_option
def train(recipe: str | None, list_recipes: bool, out_dir: Path | None, cache_dir: Path | None, resume: bool,
          overwrite: bool, minutes: float | None, steps: int | None, seed: int | None, workers: int | None, device: str,
          precision: str | None, quiet: bool) -> None:
    """Train RMB-Net from RECIPE (a .toml file or a bundled recipe name; --list shows the bundled ones)."""
    from rmbvideo.errors import InputError
    from rmbvideo.train.config import bundled_recipe, bundled_recipes, load_recipe
    from rmbvideo.train.loop import Trainer

    if list_recipes:
        for name, summary in bundled_recipes().items():
            click.echo(f"{name:40s} {summary}")
        return
    if recipe is None:
        raise click.UsageError("Missing argument 'RECIPE' (or --list for the bundled recipes).")
    path = Path(recipe)
    if not path.exists() and bundled_recipe(recipe).is_file():
        path = bundled_recipe(recipe)
    config = load_recipe(path)
    if minutes is not None:
        config = config.with_minutes(minutes)
    if steps is not None:
        config = config.with_steps(steps)
    if seed is not None:
        config = config.with_seed(seed)
    if workers is not None:
        config = config.with_workers(workers)
    if precision is not None:
        config = config.with_precision(precision)
    import torch

    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    elif device == "cuda" and not torch.cuda.is_available():
        raise InputError(f"--device {device}: no CUDA device is available")
    out_dir = out_dir if out_dir is not None else Path(f"train-{config.name}")
    if resume and overwrite:
        raise click.UsageError("--resume and --overwrite exclude each other")
    with output_folder(out_dir):  # a run that fails before its first checkpoint leaves no empty folder
        result = Trainer(config, out_dir, cache_dir=cache_dir, resume=resume, overwrite=overwrite,
                         progress=progress_enabled(quiet), device=device).run()
    click.echo(f"{result.weights}: {result.steps} steps in {result.elapsed_s / 60:.1f} min "
               f"(stopped by {result.stopped_by}); held-out mu-law PSNR {result.metrics['val_mu_psnr']:.2f} dB, "
               f"TFW {result.metrics['val_tfw_mu_psnr']:.2f} dB")


@click.command("train-detail")
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("train-detail"),
              show_default=True, help="Output folder: loss.csv, checkpoint.*, then detail-binned.safetensors + .json.")
@click.option("--minutes", type=click.FloatRange(min=0, min_open=True), default=25.0, show_default=True,
              help="Wall-time budget (with --resume: the whole run's, including the time already spent).")
@click.option("--resume", is_flag=True, help="Continue from the checkpoint in --output.")
@click.option("--overwrite", is_flag=True,
              help="Start afresh in a folder that holds an earlier run's checkpoint (refused without it or --resume).")
@click.option("--channels", type=click.IntRange(min=1), default=None,
              help="Width of the stage's 3x3 convolutions [default: DetailConfig's, 16]; the same when resuming.")
@click.option("--layers", type=click.IntRange(min=2), default=None,
              help="Depth of the stage's 3x3 convolution stack [default: DetailConfig's, 4]; the same when resuming.")
@click.option("--init", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="Start from these detail-stage weights (a fine-tune with a fresh optimizer; e.g. the shipped "
                   "models/detail-binned.safetensors).")
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Initial learning rate, cosine to a tenth of it [default: 1e-3].")
@click.option("--mismatch", type=(click.FloatRange(min=0), click.FloatRange(min=0)), default=None,
              help="LOW HIGH: each physical capture's threshold mismatch (fixed pattern) drawn between these "
                   "multiples of the paper's [default: 1 1].")
@click.option("--interval-window", "interval_windows", type=click.IntRange(min=1), multiple=True,
              help="Also read TFI over the whole intervals covering this many central planes (repeatable; e.g. 4 "
                   "and 16, the raw gate's candidates); with --init the stage's first layer is widened with zero "
                   "weights for them.")
@quiet_option
@verbose_option
def train_detail(out_dir: Path, minutes: float, resume: bool, overwrite: bool, channels: int | None, layers: int | None,
                 init: Path | None, lr: float | None, mismatch: tuple[float, float] | None,
                 interval_windows: tuple[int, ...], quiet: bool) -> None:
    """Train the learned detail stage of --resolution full on simulated video scenes (CPU, one thread)."""
    import torch

    from rmbvideo.net.detail import DetailConfig
    from rmbvideo.train.detail import INTERVAL_REACH, DetailTrainConfig
    from rmbvideo.train.detail import train_detail as run

    torch.set_num_threads(1)
    shape = {k: v for k, v in (("channels", channels), ("layers", layers)) if v is not None}
    detail = DetailConfig(interval_reach=INTERVAL_REACH, **shape)
    if init is not None:
        from rmbvideo.net.weights import load_detail_model

        detail = load_detail_model(init)[0].config  # the stage's own shape
    if interval_windows:
        detail = replace(detail, interval_windows=detail.interval_windows + tuple(
            w for w in interval_windows if w not in detail.interval_windows))
    if mismatch is not None and mismatch[0] > mismatch[1]:
        raise click.BadParameter(f"LOW {mismatch[0]} is above HIGH {mismatch[1]}", param_hint="--mismatch")
    options = {**({"lr": lr, "lr_final": lr / 10} if lr is not None else {}),
               **({"mismatch": tuple(mismatch)} if mismatch is not None else {})}
    if resume and overwrite:
        raise click.UsageError("--resume and --overwrite exclude each other")
    with output_folder(out_dir):
        weights = run(DetailTrainConfig(detail=detail, minutes=minutes, **options), out_dir, resume=resume,
                      overwrite=overwrite, progress=progress_enabled(quiet), init=init)
    click.echo(f"{weights}: install it as models/detail-binned.safetensors (+ .json) to use it")


@click.command("train-raw-gate")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False, path_type=Path),
              default=Path("raw-gate.safetensors"), show_default=True,
              help="Weights to write (+ .json card beside them).")
@click.option("--overwrite", is_flag=True, help="Replace existing weights (and card) at -o.")
@click.option("--model", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="The binned RMB-Net the gate is fitted to (default: the shipped one).")
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Adam steps [default: the recipe's, 32000].")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Initial weights and drawn pixels [default 0].")
@click.option("--loss", type=click.Choice(["mu-law", "mu-law+display-linear"]), default=None,
              help="What the gate is fitted to [default: the recipe's, mu-law].")
@click.option("--display-videos", type=click.IntRange(min=0), default=None,
              help="Sequences of every physical video kind simulated again in spikezoo's convention [default 2].")
@click.option("--display-scenes", type=click.IntRange(min=0), default=None,
              help="Sequences of the training scenes' video ranges in spikezoo's convention [default 6].")
@click.option("--still-scenes", type=click.IntRange(min=0), default=None,
              help="Sequences of still scenes (a still camera, nothing moving) in spikezoo's convention [default 3].")
@click.option("--tfi-window", type=click.IntRange(min=0), default=None,
              help="Central raw planes of the gate's TFI (TFI-M: the whole intervals covering them; 0: one interval) "
                   "[default: the recipe's, 4].")
@click.option("--long-window", type=click.IntRange(min=0), default=None,
              help="Central raw planes of a second TFI candidate, more than --tfi-window (0: none) [default: the "
                   "recipe's, 16].")
@click.option("--frame-features/--no-frame-features", default=None,
              help="Whether the gate also reads how far its candidates disagree over the whole frame [default: the "
                   "recipe's, on].")
@click.option("--pixels", type=click.IntRange(min=1), default=None,
              help="Pixels drawn from every frame of the simulated captures, for a per-pixel gate (--kernel 1) "
                   "[default: the recipe's, 500].")
@click.option("--restarts", type=click.IntRange(min=1), default=None,
              help="Fits from different initial weights; the one of lowest loss on the drawn pixels is kept "
                   "[default: the recipe's, 2].")
@click.option("--kernel", type=click.IntRange(min=1), default=None,
              help="Size of the gate's convolutions: 1 reads each pixel's features alone, an odd k > 1 the features "
                   "around it too (fitted on crops, --batch of them a step) [default: the recipe's, 3].")
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Adam's learning rate [default: the recipe's, 3e-3].")
@click.option("--batch", type=click.IntRange(min=1), default=None,
              help="Crops a step for a gate with --kernel above 1 [default: the recipe's, 16].")
@quiet_option
@verbose_option
def train_raw_gate(out: Path, overwrite: bool, model: Path | None, steps: int | None, seed: int | None,
                   loss: str | None,
                   display_videos: int | None, display_scenes: int | None, still_scenes: int | None,
                   tfi_window: int | None, long_window: int | None, frame_features: bool | None, pixels: int | None,
                   restarts: int | None, kernel: int | None, lr: float | None, batch: int | None, quiet: bool) -> None:
    """Fit the raw-interval gate of 1-bit captures on simulated captures of training seeds (CPU, one thread)."""
    from dataclasses import replace

    import torch

    from rmbvideo.train.raw_gate import RawGateRecipe, fit_raw_gate

    torch.set_num_threads(1)
    chosen = (("steps", steps), ("seed", seed), ("loss", loss), ("display_videos", display_videos),
              ("display_scenes", display_scenes), ("still_scenes", still_scenes), ("pixels", pixels),
              ("restarts", restarts), ("lr", lr), ("batch", batch))
    recipe = RawGateRecipe(**{k: v for k, v in chosen if v is not None})
    windows = {k: v for k, v in (("tfi_window", tfi_window), ("long_window", long_window),
                                 ("frame_features", frame_features), ("kernel", kernel)) if v is not None}
    try:
        recipe = replace(recipe, gate=replace(recipe.gate, **windows))
    except ValueError as error:
        hint = "--kernel" if "kernel" in str(error) else "--long-window"
        raise click.BadParameter(str(error), param_hint=hint) from None
    weights = fit_raw_gate(recipe, out, model=model, progress=progress_enabled(quiet), overwrite=overwrite)
    click.echo(f"{weights}: install it as models/raw-gate.safetensors (+ .json) to use it")
