"""``rmbvideo dynamic-range``: the theoretical dynamic range of a readout design (paper Table 1)."""

from __future__ import annotations

import json
import logging
import math
from dataclasses import replace
from pathlib import Path

import click

from tqdm import tqdm

from rmbvideo.cli import progress_enabled, quiet_option, verbose_option
from rmbvideo.cli.options import AliasOption
from rmbvideo.errors import InputError
from rmbvideo.sensor.params import SensorParams

#: The largest nominal threshold (electrons) the exact law is computed for: its tables and the loops over the
#: threshold's values both grow with Q_r (on one core: the default table 1.5 s at 105; a level 12-18 s at 800,
#: 75-132 s at 2,000; 1e9 was killed for memory; ``models/experiments/dynamic-range-speed/measure.py scaling``).
MAX_Q_R = 10_000.0
#: The longest exact-variance table computed (estimated before any work by ``exact_variance_seconds``: the default
#: L = 1 row 4.7 minutes on one core; L = 1 at Q_r = 400, about 68, is refused in one line).
MAX_EXACT_SECONDS = 3600.0

logger = logging.getLogger(__name__)


def _int_list(ctx: click.Context, param: click.Parameter, value: str) -> list[int]:
    try:
        items = [int(v) for v in value.split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated integers, got {value!r}") from None
    if not items or min(items) < 1:
        raise click.BadParameter("values must be positive integers")
    return items


@click.command("dynamic-range")
@verbose_option
@click.option("--levels", "--L", "levels", cls=AliasOption, aliases=("--L",), default="1,3,7", show_default=True, callback=_int_list,
              help="Quantisation levels L = 2^B - 1, comma separated.")
@click.option("--readouts", "--N", "n_values", cls=AliasOption, aliases=("--N",), default="1,10,30,70,1000,10000,20000", show_default=True,
              callback=_int_list, help="Numbers of summed readouts N, comma separated.")
@click.option("--q-r", type=click.FloatRange(min=1.0, max=MAX_Q_R), default=None,
              help="Nominal threshold Q_r = C*V in electrons (C kept, V = Q_r/C) [default: 105]. The exact law's work "
                   f"grows about as Q_r^2 (the default table takes seconds at 105; a level 12-18 s at 800, 75-132 "
                   f"s at 2,000), so at most {MAX_Q_R:g}.")
@click.option("--dark-mean", type=click.FloatRange(min=0.0), default=None,
              help="Mean dark electrons per readout mu_d [default: 0.05].")
@click.option("--noise-var", type=click.FloatRange(min=0.0), default=None,
              help="Variance of every noise source (C^S, V^S, V^T0, dark) [default: 0.005].")
@click.option("--variance", type=click.Choice(["independent", "exact"]), default="independent",
              show_default=True,
              help="Var(S_N) as N*Var(S) (the paper's Table 1) or with the exact interval correlation (at the default "
                   "Q_r on one core: L = 1 about 5 minutes, L = 3 and 7 seconds; a table estimated at more than "
                   f"{MAX_EXACT_SECONDS / 60:.0f} minutes is refused before any work).")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Write fig2_expectation_std.png and fig3_snr.png into this folder.")
@click.option("--json", "as_json", is_flag=True, help="Print {\"table\": [...]} on stdout.")
@quiet_option
def dynamic_range(levels: list[int], n_values: list[int], q_r: float | None, dark_mean: float | None,
                  noise_var: float | None, variance: str, plots_dir: Path | None,
                  as_json: bool, quiet: bool) -> None:
    """Print the dynamic range (dB) of S_N^L for each L (rows) and N (columns)."""
    from rmbvideo.sensor.theory import PAPER_TABLE1, PAPER_TABLE1_N
    from rmbvideo.sensor.theory import dynamic_range as compute

    params = SensorParams()
    if q_r is not None:
        params = replace(params, voltage=q_r / params.capacitance)
    if dark_mean is not None:
        params = replace(params, dark_mean=dark_mean)
    if noise_var is not None:
        std = math.sqrt(noise_var)
        params = replace(params, cap_std=std, reset_v_std=std, temp_v_std=std, dark_std=std)
    if max(levels) > 4095:
        raise InputError(f"--L {max(levels)}: levels above 4095 are not supported")
    if variance == "exact":
        from rmbvideo.sensor.theory import exact_variance_seconds

        seconds = sum(exact_variance_seconds(replace(params, level=level), n_values) for level in levels)
        if seconds > MAX_EXACT_SECONDS:
            raise InputError(f"--variance exact: this table would take about {seconds / 60:.0f} minutes on one core "
                             f"(at most {MAX_EXACT_SECONDS / 60:.0f}; the work grows about as Q_r^2 N at L = 1); use "
                             "--variance independent, fewer or smaller --readouts, a larger L or a smaller --q-r")
        logger.info("--variance exact: about %.0f s on one core", seconds)
    defaults = q_r is None and dark_mean is None and noise_var is None and variance == "independent"

    table = {}
    with tqdm(levels, unit="level", desc="dynamic range", disable=not progress_enabled(quiet)) as bar:
        for level in bar:
            bar.set_postfix_str(f"L = {level}")
            for res in compute(replace(params, level=level), n_values, exact=variance == "exact"):
                table[(level, res.n)] = res.dr_db

    if plots_dir is not None:
        from rmbvideo.io.atomic import output_folder, outputs_together
        from rmbvideo.io.png import write_figure
        from rmbvideo.sensor.plots import expectation_std_figure, snr_figure

        with output_folder(plots_dir), outputs_together(plots_dir, ("fig*.png",)):  # both figures, or neither
            write_figure(expectation_std_figure(params), plots_dir / "fig2_expectation_std.png", dpi=120)
            write_figure(snr_figure(params, exact=variance == "exact"), plots_dir / "fig3_snr.png", dpi=120)

    if as_json:
        rows = [{"L": lv, "N": n, "dr_db": round(table[(lv, n)], 2)} for lv in levels for n in n_values]
        click.echo(json.dumps({"table": rows}))
        return

    def paper(level: int, n: int) -> float | None:
        if not defaults or level not in PAPER_TABLE1 or n not in PAPER_TABLE1_N:
            return None
        return PAPER_TABLE1[level][PAPER_TABLE1_N.index(n)]

    click.echo(f"Dynamic range (dB), Var(S_N) {variance}; rows L, columns N")
    header = "L \\ N".ljust(8) + "".join(f"{n:>10d}" for n in n_values)
    click.echo(header)
    for level in levels:
        click.echo(f"{level:<8d}" + "".join(f"{table[(level, n)]:10.2f}" for n in n_values))
    if any(paper(lv, n) is not None for lv in levels for n in n_values):
        click.echo("paper (Table 1) and difference (this - paper):")
        for level in levels:
            cells = []
            for n in n_values:
                ref = paper(level, n)
                cells.append(" " * 16 if ref is None else f"{ref:8.2f}{table[(level, n)] - ref:+8.2f}")
            click.echo(f"{level:<8d}" + "".join(f"{c:>18s}" for c in cells))
