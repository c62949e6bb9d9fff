"""The ``rmbvideo`` command: a thin click layer over the library.

Each subcommand lives in its own module and is imported only when it runs, so ``rmbvideo info``
starts without importing torch. Errors caused by input or environment (``RmbvideoError``) are
printed as one line on stderr with exit status 2, never as a traceback.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import sys

import click

from rmbvideo.errors import RmbvideoError

# name -> "module:attribute" of the click command
COMMANDS: dict[str, str] = {
    "reconstruct": "rmbvideo.cli.reconstruct:reconstruct",
    "info": "rmbvideo.cli.info:info",
    "preview": "rmbvideo.cli.preview:preview",
    "simulate": "rmbvideo.cli.simulate:simulate",
    "dynamic-range": "rmbvideo.cli.dynamic_range:dynamic_range",
    "train": "rmbvideo.cli.train:train",
    "evaluate": "rmbvideo.cli.evaluate:evaluate",
    "bench": "rmbvideo.cli.bench:bench",
    "batch": "rmbvideo.cli.batch:batch",
}


class LazyGroup(click.Group):
    """A group whose subcommands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(name for name in COMMANDS if _spec_exists(COMMANDS[name]))

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        spec = COMMANDS.get(name)
        if spec is None or not _spec_exists(spec):
            return None
        module, attr = spec.split(":")
        return getattr(importlib.import_module(module), attr)

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except RmbvideoError as exc:
            click.echo(f"rmbvideo: error: {exc}", err=True)
            ctx.exit(2)
        except KeyboardInterrupt:
            click.echo("rmbvideo: interrupted", err=True)
            ctx.exit(130)


def _spec_exists(spec: str) -> bool:
    return importlib.util.find_spec(spec.split(":")[0]) is not None


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", is_flag=True, help="Log debug messages.")
@click.version_option(package_name="rmbvideo")
def main(verbose: bool) -> None:
    """Turn spiking-camera captures (.dat) into HDR, high-frame-rate video."""
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="rmbvideo: %(levelname)s: %(message)s" if verbose else "rmbvideo: %(message)s",
        stream=sys.stderr,
    )


def progress_enabled(quiet: bool) -> bool:
    """Show a progress bar only on a terminal and when not ``--quiet``."""
    return not quiet and sys.stderr.isatty()
