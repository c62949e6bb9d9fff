"""``rmbvideo bench``: what accuracy costs in time, on the held-out synthetic scenes; ``rmbvideo bench
decode``: decode+bin speed; ``sizes`` and ``network``: RMB-Net by frame size, in the engine and alone."""

from __future__ import annotations

import json
import logging
import tempfile
from pathlib import Path

import click

from rmbvideo.allocator import keep_freed_memory
from rmbvideo.bench.configs import DEFAULT_WIDTH, precision_label
from rmbvideo.cli import quiet_logging_option, verbose_option
from rmbvideo.sensor.compiled import COMPILED

log = logging.getLogger(__name__)


def _devices(choice: str) -> tuple[str, ...]:
    if choice != "auto":
        return (choice,)
    import torch

    return ("cpu", "cuda") if torch.cuda.is_available() else ("cpu",)


def _stage_table(stages: dict[str, float]) -> str:
    lines = [f"Per-stage time of RMB-Net (w = 3, width {DEFAULT_WIDTH:g}, no alignment, precision "
             f"{precision_label('auto', 'cpu')}, CPU) at {stages.pop('size')}, "
             f"ms per output frame over {int(stages.pop('frames'))} frames:", "",
             "| stage | ms/frame |", "|---|---|"]
    lines += [f"| {k} | {v:.2f} |" for k, v in stages.items()]
    return "\n".join(lines) + "\n"


@click.group(invoke_without_command=True)
@verbose_option
@quiet_logging_option
@click.option("--quick", is_flag=True, help="Small held-out set (2 scenes, 112x64), short timing captures, "
              "no TV-L1 row: a few minutes.")
@click.option("-o", "--output", "outdir", type=click.Path(path_type=Path), default=Path("bench-results"),
              show_default=True, help="Folder for bench.md, bench.csv and bench.png.")
@click.option("--json", "as_json", is_flag=True, help="Print the records as JSON on stdout.")
@click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True,
              help="Devices for RMB-Net rows (auto: CPU, plus CUDA when available).")
@click.option("--full-grid", is_flag=True,
              help="Every combination of w, alignment, width and precision (default: one knob at a time).")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="Torch threads for the network [default: the thread policy of every command, rmbvideo.threads].")
@click.option("--models", "models_dir", type=click.Path(path_type=Path), default=None,
              help="Folder of trained weights (with ablations/) [default: the shipped models].")
@click.option("--cache", type=click.Path(path_type=Path), default=None,
              help="Held-out scene cache folder [default: ~/.cache/rmbvideo/heldout].")
@click.option("--no-tvl1", is_flag=True,
              help="Leave out the TV-L1 alignment row (seconds per flow field on a CPU; --quick does).")
@click.option("--no-baselines", is_flag=True, help="Only RMB-Net rows.")
@click.option("--no-extras", is_flag=True,
              help="Skip the per-stage breakdown, the real-time tfp check and the memory-scaling runs.")
@click.pass_context
def bench(ctx: click.Context, quick: bool, outdir: Path, as_json: bool, device: str, full_grid: bool,
          threads: int, models_dir: Path | None, cache: Path | None, no_tvl1: bool, no_baselines: bool,
          no_extras: bool) -> None:
    """Benchmark every method on the held-out synthetic scenes: accuracy against time.

    Rows: TFW-S, TFW-L, TFI, GC20, MG20 and RMB-Net with w in {0,1,2,3}, alignment none/DIS/TV-L1,
    width x0.5/x1, fp32/bf16, per device. Each row reports mu-law PSNR and SSIM, output frames per
    second end to end (decode to sink) and for the network alone, the real-time factor (capture
    seconds per wall second) and the peak memory of a process running the row alone. RMB-Net
    configurations without trained weights in the models folder are timed with a random-init
    network and their accuracy is n/a.

    Writes bench.md (table, per-stage breakdown, real-time and memory checks), bench.csv and
    bench.png (PSNR against time, Pareto front marked). `rmbvideo bench decode` measures decoding.
    """
    if ctx.invoked_subcommand is not None:
        return
    from rmbvideo.recon.full_resolution import finish_beside_by_default
    from rmbvideo.threads import default_threads, work_beside

    resolved = threads or default_threads()  # None (the policy) stays None for the rows
    beside = work_beside(threads)
    finish = finish_beside_by_default("cpu", threads)  # the full-resolution stages beside the network
    from rmbvideo.bench.configs import ALIGNMENTS, default_configs
    from rmbvideo.bench.models import build_network
    from rmbvideo.bench.report import mark_pareto, markdown_table, write_csv, write_plot
    from rmbvideo.bench.runner import TIMING_RUNS, run_config
    from rmbvideo.evaluate.heldout import load_heldout
    from rmbvideo.io.atomic import atomic_write_text, check_folder_creatable, output_folder, outputs_together
    from rmbvideo.net.weights import MODELS_DIR

    models_dir = models_dir or MODELS_DIR
    check_folder_creatable(outdir)
    sequences = load_heldout(quick, cache)
    alignments = tuple(a for a in ALIGNMENTS if not ((quick or no_tvl1) and a == "tvl1"))
    configs = default_configs(_devices(device), full_grid=full_grid, baselines=not no_baselines,
                              alignments=alignments, beside=beside)
    records = []
    with tempfile.TemporaryDirectory(prefix="rmbvideo-bench-") as work:
        for config in configs:
            record = run_config(config, sequences, Path(work), models_dir, threads=threads)
            log.info("%-32s %6.1f frames/s  PSNR %s", record.name, record.fps,
                     "n/a" if record.psnr is None else f"{record.psnr:.2f}")
            records.append(record)
    mark_pareto(records)
    document = ["# rmbvideo bench", "",
                f"{len(sequences)} held-out scenes at {sequences[0].shape[1]}x{sequences[0].shape[0]}, "
                f"{resolved} thread(s) for the network per row unless the row names its own "
                f"({'--threads' if threads else 'the thread policy of every command, rmbvideo.threads: one on a busy or 2-core machine'}); "
                f"the aligned window means {'in a thread of their own beside the network' if beside else 'inline'}"
                f"{' and at full resolution the raw rates, gate and detail stage in another, a chunk behind it' if finish else ''} "
                f"({'two or more threads' if beside and threads else 'a second idle core' if beside else 'no second thread or idle core'}). "
                f"Each scene runs {TIMING_RUNS} times per row, the fastest timed; a row's peak RSS is that of a fresh "
                "process running it once on the largest scene (Python included, and torch and the model where the row's method needs them: a classical row, as its `reconstruct` run, never loads torch). "
                f"Freed memory {'kept for reuse (glibc thresholds raised, rmbvideo.allocator)' if keep_freed_memory() else 'as the C allocator is set (no glibc, or its thresholds set in the environment)'}; "
                f"decode+bin by the {'compiled' if COMPILED else 'numpy'} kernel. "
                "'*' = Pareto front of (time per frame, PSNR) among rows with "
                "accuracy; 'n/a' = untrained (random-init) network, timed only.", "", markdown_table(records)]
    extras: dict = {}
    if not no_extras:
        from rmbvideo.bench.memory import memory_scaling
        from rmbvideo.bench.realtime import bench_realtime
        from rmbvideo.bench.stages import stage_breakdown

        stages = stage_breakdown(build_network(3, DEFAULT_WIDTH, _choice(models_dir)), planes=600 if quick else 2000,
                                 threads=resolved)
        extras["stages_ms_per_frame"] = dict(stages)
        stages["size"] = "200x125"  # type: ignore[assignment]
        document += [_stage_table(stages)]
        realtime = bench_realtime(0.5 if quick else 5.0).to_dict()
        extras["realtime_tfp"] = realtime
        document += [f"tfp --format null on {realtime['capture_s']:.1f} s of 400x250 capture "
                     f"({realtime['planes']} planes): {realtime['reconstruct_s']:.2f} s "
                     f"(real-time factor {realtime['realtime_factor']:.2f}; reading alone {realtime['read_s']:.2f} s).", ""]
        # TFW at its binned size: its own memory (at full size the detail stage, whose memory is the RMB-Net rows',
        # made most of the time: 69 of --quick's 130 s)
        planes = 2048 if quick else 8192
        memory = [memory_scaling("tfp", planes), memory_scaling("tfw", planes, extra=("--resolution", "binned"))]
        extras["memory_scaling"] = memory
        document += [f"Peak anonymous RSS, {' '.join([m['method'], *m['options']])}: {m['peak_anon_mib'][0]:.0f} MiB for {m['planes']} "
                     f"planes, {m['peak_anon_mib'][1]:.0f} MiB for {m['factor']}x as many ({100 * m['growth']:+.1f} %; "
                     f"total RSS with mapped file pages {m['peak_rss_mib'][0]:.0f} -> {m['peak_rss_mib'][1]:.0f} MiB)."
                     for m in memory]
    with output_folder(outdir), outputs_together(outdir, ("bench.*",)):  # the three of one run, or none
        atomic_write_text(outdir / "bench.md", "\n".join(document) + "\n")
        write_csv(records, outdir / "bench.csv")
        write_plot(records, outdir / "bench.png")
    if as_json:
        click.echo(json.dumps({"records": [r.to_dict() for r in records], **extras}, indent=2))
    else:
        click.echo(markdown_table(records), nl=False)
        click.echo(f"wrote {outdir / 'bench.md'}, bench.csv, bench.png", err=True)


def _choice(models_dir: Path):
    from rmbvideo.bench.models import find_model

    return find_model(3, DEFAULT_WIDTH, models_dir)


@bench.command("decode")
@quiet_logging_option
@click.option("--planes", type=click.IntRange(min=2), default=20000, show_default=True,
              help="Raw 400x250 planes in the generated capture.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def decode(planes: int, as_json: bool) -> None:
    """Decode+bin planes/s: the fused path against plain numpy and a per-plane loop (one core)."""
    from rmbvideo.bench.decode import _summary, bench_decode

    result = bench_decode(planes)
    click.echo(json.dumps(result, indent=2) if as_json else _summary(result))


@bench.command("simulate")
@quiet_logging_option
@click.option("--scene", "scene_name", default="demo", show_default=True, help="Bundled scene name or TOML file.")
@click.option("--duration", "duration_s", type=click.FloatRange(min=0, min_open=True), default=0.02,
              show_default=True, help="Seconds of the scene to simulate.")
@click.option("--repeats", type=click.IntRange(min=1), default=3, show_default=True,
              help="Runs of each, alternated; the medians are reported.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def simulate(scene_name: str, duration_s: float, repeats: int, as_json: bool) -> None:
    """Simulator pixel-readouts/s against a numpy Poisson-per-pixel-per-readout reference (one core)."""
    from rmbvideo.bench.simulate import bench_simulate, summary

    result = bench_simulate(scene_name, duration_s, repeats)
    click.echo(json.dumps(result, indent=2) if as_json else summary(result))


def _size(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` as (width, height); both even (the 2x2 binning) and at least 16."""
    width, _, height = text.lower().partition("x")
    if not (width.isdigit() and height.isdigit()) or int(width) < 16 or int(height) < 16 or int(width) % 2 or int(height) % 2:
        raise click.BadParameter(f"{text!r}: expected an even raw size WIDTHxHEIGHT, at least 16x16 (e.g. 400x250)")
    return int(width), int(height)


@bench.command("sizes")
@quiet_logging_option
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default="cpu", show_default=True,
              help="Device of the network.")
@click.option("--size", "sizes", multiple=True, default=("400x250", "1000x1000"), show_default=True,
              help="Raw capture size WIDTHxHEIGHT (repeatable); the network sees half of each side.")
@click.option("--frames", type=click.IntRange(min=10), default=120, show_default=True,
              help="Output frames per run (20 raw planes each).")
@click.option("--frame-batch", "frame_batches", type=click.IntRange(min=1), multiple=True,
              help="Output frames per batched pass (repeatable) [default: the engine's default for the device].")
@click.option("--precision", "precisions", type=click.Choice(["fp32", "bf16"]), multiple=True,
              default=("fp32", "bf16"), show_default=True, help="Precision (repeatable).")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="The engine's threads, as `reconstruct --threads` (on a GPU: the aligned means' threads) "
                   "[default: the thread policy].")
@click.option("--cuda-graphs/--no-cuda-graphs", default=True, show_default=True,
              help="The engine's CUDA graphs on a GPU, as `reconstruct --cuda-graphs`.")
@click.option("--no-cli", is_flag=True, help="Leave out the `reconstruct` run in a fresh process.")
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON.")
def sizes(device: str, sizes: tuple[str, ...], frames: int, frame_batches: tuple[int, ...],
          precisions: tuple[str, ...], threads: int | None, cuda_graphs: bool, no_cli: bool, as_json: bool) -> None:
    """RMB-Net frames/s by frame size and precision (fp32, bf16): end to end and the network alone."""
    import torch

    from rmbvideo.bench.sizes import bench_sizes, sizes_table
    from rmbvideo.errors import InputError

    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available")
    results = bench_sizes(device, tuple(_size(s) for s in sizes), precisions=precisions, frames=frames,
                          cli=not no_cli, frame_batches=frame_batches or (None,), threads=threads,
                          cuda_graphs=cuda_graphs)
    name = torch.cuda.get_device_name(0) if device == "cuda" else "CPU"
    click.echo(json.dumps([r.to_dict() for r in results], indent=2) if as_json
               else f"RMB-Net (shipped default) on {name}:\n" + sizes_table(results))


@bench.command("profile")
@quiet_logging_option
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default="cpu", show_default=True,
              help="Device of the network.")
@click.option("--size", "size", default="400x250", show_default=True,
              help="Raw capture size WIDTHxHEIGHT; the network sees half of each side.")
@click.option("--frames", type=click.IntRange(min=10), default=240, show_default=True,
              help="Output frames per run (20 raw planes each).")
@click.option("--precision", type=click.Choice(["fp32", "bf16"]), default="fp32", show_default=True,
              help="Network precision.")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="The engine's threads, as `reconstruct --threads` [default: the thread policy].")
@click.option("--resolution", type=click.Choice(["full", "binned"]), default="full", show_default=True,
              help="As `reconstruct --resolution`: binned profiles the network's frames alone (what the speed "
                   "targets count), full adds the raw stream's detail.")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("profile.md"), show_default=True,
              help="Markdown file for the summary and the tables.")
@click.option("--overwrite", is_flag=True, help="Replace an existing file at -o.")
def profile(device: str, size: str, frames: int, precision: str, threads: int | None, resolution: str,
            output: Path, overwrite: bool) -> None:
    """Where an end-to-end RMB-Net run's time goes, by operation (torch.profiler; on a GPU kernels and copies too),
    and the main thread's Python (cProfile)."""
    import torch

    from rmbvideo.bench.profile import profile_engine
    from rmbvideo.errors import InputError
    from rmbvideo.io.atomic import atomic_write_text, check_file_writable

    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available")
    check_file_writable(output, overwrite, suffixes=(".md",))
    width, height = _size(size)
    result = profile_engine(device, width, height, frames=frames, precision=precision, threads=threads,
                            resolution=resolution)
    text = result.markdown()
    atomic_write_text(output, text)
    click.echo(text.split("\n\n## ")[0])
    click.echo(f"tables: {output}")


def _run(text: str) -> tuple[int, int, int]:
    """``WIDTHxHEIGHTxFRAMES`` (binned size, frames per batched pass) as a tuple."""
    parts = text.lower().split("x")
    if len(parts) != 3 or not all(p.isdigit() and int(p) >= 1 for p in parts) or min(map(int, parts[:2])) < 8:
        raise click.BadParameter(f"{text!r}: expected binned WIDTHxHEIGHTxFRAMES, at least 8x8x1 (e.g. 200x125x128)")
    width, height, frames = map(int, parts)
    return width, height, frames


@bench.command("network")
@quiet_logging_option
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default="cpu", show_default=True,
              help="Device of the network.")
@click.option("--run", "runs", multiple=True, default=("200x125x128", "500x500x16"), show_default=True,
              help="Binned WIDTHxHEIGHTxFRAMES: frame size and output frames per batched pass (on a CPU also made "
                   "frame by frame; repeatable).")
@click.option("--precision", "precisions", type=click.Choice(["fp32", "bf16"]), multiple=True,
              default=("fp32", "bf16"), show_default=True, help="Precision (repeatable).")
@click.option("--threads", type=click.IntRange(min=1), default=1, show_default=True, help="Torch threads.")
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON.")
def network(device: str, runs: tuple[str, ...], precisions: tuple[str, ...], threads: int, as_json: bool) -> None:
    """RMB-Net alone (encoders and batched pass on tensors on the device), with and without CUDA graphs on a GPU; on a
    CPU also frame by frame, the path the engine takes there."""
    import torch

    from rmbvideo.bench.network import bench_network, network_table
    from rmbvideo.errors import InputError
    from rmbvideo.threads import compute_threads

    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available")
    with compute_threads(threads, 1):
        results = bench_network(device, tuple(_run(r) for r in runs), precisions,
                                graphs=(False, True) if device == "cuda" else (False,))
    name = torch.cuda.get_device_name(0) if device == "cuda" else f"CPU, {threads} thread(s)"
    click.echo(json.dumps([r.to_dict() for r in results], indent=2) if as_json
               else f"RMB-Net alone (shipped default) on {name}:\n" + network_table(results))
