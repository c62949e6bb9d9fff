"""``rmbvideo batch``: convert many captures, unattended and resumable (see :mod:`rmbvideo.batch`).

It takes every option of ``reconstruct`` (copied from that command, so options added there are
accepted here too) and passes them to ``run_reconstruction``: its own keywords by name, the
geometry options as ``capture``, and every other option that is set as ``extra_options`` (the
method takes those it declares, as in ``reconstruct``).
"""

from __future__ import annotations

import importlib.util
import inspect
from pathlib import Path
from typing import Any

import click

from rmbvideo.batch import REPORT_NAME, plan_jobs, run_batch, summary_table
from rmbvideo.cli import progress_enabled, quiet_option, verbose_option
from rmbvideo.cli.reconstruct import reconstruct
from rmbvideo.recon.methods import get_method
from rmbvideo.recon.resume import check_resumable_format, check_resumable_step
from rmbvideo.recon.run import PER_CAPTURE_OPTIONS, run_reconstruction

CAPTURE_KEYS = ("width", "height", "flip", "header_cols", "rate_hz")
# parameters of reconstruct that batch replaces with its own
_OWN_PARAMS = {"input_path", "outdir", "quiet", "verbose_"}
_RECON_KEYWORDS = set(inspect.signature(run_reconstruction).parameters) - {"input_path", "outdir", "capture",
                                                                           "extra_options", "progress"}


def reconstruction_options(params: dict[str, Any]) -> dict[str, Any]:
    """Map reconstruct's command-line values onto ``run_reconstruction`` keywords (None extras dropped)."""
    options: dict[str, Any] = {k: v for k, v in params.items() if k in _RECON_KEYWORDS}
    options["capture"] = {k: params.get(k) for k in CAPTURE_KEYS}
    extra = {k: v for k, v in params.items() if v is not None and k not in _RECON_KEYWORDS
             and k not in CAPTURE_KEYS}
    if extra:
        options["extra_options"] = extra
    return options


def check_method(options: dict[str, Any]) -> None:
    """Build the reconstructor once, so bad method options (or a bad model) stop the batch before it starts, as does
    ``--resume`` with a format that cannot be resumed (each capture would fail)."""
    method = get_method(options["method"])
    step = options.get("step") or 20
    if options.get("resume"):
        check_resumable_format(options["fmt"])
        check_resumable_step(method.name, step, method.frame_every(step))
    keywords = method.options(options.get("window"), step)
    keywords.update(method.select_extra(options.get("extra_options") or {}))
    # "auto" choices are made per capture, from its sidecar and spikes (``prepare_run``)
    method.build(**{k: v for k, v in keywords.items() if not (k in PER_CAPTURE_OPTIONS and v == "auto")})


@click.command()
@click.argument("inputs", metavar="INPUTS...", nargs=-1, required=True)
@click.option("-o", "--output", "outdir", required=True, type=click.Path(path_type=Path),
              help="Batch folder: one output folder per capture, plus batch-report.json.")
@click.option("--jobs", type=click.IntRange(min=1), default=None,
              help="Parallel worker processes [default: one per core].")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run on an existing Dask cluster (e.g. tcp://host:8786); needs rmbvideo[cluster].")
@quiet_option
@verbose_option
def batch(inputs: tuple[str, ...], outdir: Path, jobs: int | None, scheduler: str | None, quiet: bool,
          **params: Any) -> None:
    """Convert captures INPUTS (files, folders searched for .dat, or quoted globs) into OUTDIR.

    A capture whose output is complete is skipped; one that fails does not stop the others. Exit
    status 1 when any capture failed.
    """
    if scheduler is not None and importlib.util.find_spec("distributed") is None:
        raise click.UsageError("--scheduler needs Dask: pip install 'rmbvideo[cluster]'")
    options = reconstruction_options(params)
    check_method(options)
    plan = plan_jobs(inputs, outdir, options)
    results = run_batch(plan, outdir, workers=jobs, scheduler=scheduler, progress=progress_enabled(quiet))
    click.echo(summary_table(results))
    click.echo(f"report: {outdir / REPORT_NAME}")
    if any(r.status == "failed" for r in results):
        click.get_current_context().exit(1)


batch.params[2:2] = [p for p in reconstruct.params if p.name not in _OWN_PARAMS]
