"""Click options shared by the commands that read captures (geometry, rate, time range)."""

from __future__ import annotations

from typing import Callable

import click

from rmbvideo.io.capture import DEFAULT_HEIGHT, DEFAULT_RATE_HZ, DEFAULT_WIDTH


def capture_options(func: Callable) -> Callable:
    """Geometry and rate of the input capture; ``None`` defaults so a sidecar can fill them."""
    options = [
        click.option("--width", type=click.IntRange(min=8), default=None,
                     help=f"Stored plane width in pixels, header columns included [default: {DEFAULT_WIDTH}]."),
        click.option("--height", type=click.IntRange(min=2), default=None,
                     help=f"Plane height in pixels [default: {DEFAULT_HEIGHT}]."),
        click.option("--flip/--no-flip", default=None,
                     help="Flip stored rows upside down, as the camera stores them [default: flip]."),
        click.option("--header-cols", type=click.IntRange(min=0), default=None,
                     help="Columns at the end of each stored row that are a header to drop [default: 0]."),
        click.option("--rate", "rate_hz", type=click.FloatRange(min=0, min_open=True), default=None,
                     help=f"Readout rate of the capture in Hz [default: {DEFAULT_RATE_HZ:g}]."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


class AliasOption(click.Option):
    """An option whose old spellings (``aliases``) still work but are left out of ``--help``."""

    def __init__(self, *args, aliases: tuple[str, ...] = (), **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.aliases = aliases

    def get_help_record(self, ctx: click.Context):
        shown, self.opts = self.opts, [o for o in self.opts if o not in self.aliases]
        try:
            return super().get_help_record(ctx)
        finally:
            self.opts = shown


#: ``--device`` as every command spells it.
DEVICE_CHOICE = click.Choice(["auto", "cpu", "cuda"])
