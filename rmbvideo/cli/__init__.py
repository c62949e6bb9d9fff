"""The ``rmbvideo`` command: a thin click layer over the library.

Each subcommand lives in its own module and is imported only when it runs, so ``rmbvideo info``
starts without importing torch. Errors caused by input or environment (``RmbvideoError``) are
printed as one line on stderr with exit status 2, never as a traceback.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import logging
import os
import signal
import sys
from collections.abc import Callable
from typing import Any

import click

from rmbvideo.allocator import keep_freed_memory
from rmbvideo.errors import RmbvideoError
from rmbvideo.io.atomic import raise_or_defer

# name -> ("module:attribute" of the click command, one line for ``rmbvideo --help``)
COMMANDS: dict[str, tuple[str, str]] = {
    "reconstruct": ("rmbvideo.cli.reconstruct:reconstruct", "Reconstruct a capture into a video or HDR frames."),
    "info": ("rmbvideo.cli.info:info", "Planes, duration, geometry and firing rate of a capture."),
    "preview": ("rmbvideo.cli.preview:preview", "Contact sheet of a few time points of a capture."),
    "simulate": ("rmbvideo.cli.simulate:simulate", "Simulate a spiking-camera capture of a scene."),
    "dynamic-range": ("rmbvideo.cli.dynamic_range:dynamic_range", "Theoretical dynamic range of a readout design."),
    "train": ("rmbvideo.cli.train:train", "Train RMB-Net from a recipe."),
    "train-detail": ("rmbvideo.cli.train:train_detail", "Train the detail stage of --resolution full."),
    "train-raw-gate": ("rmbvideo.cli.train:train_raw_gate", "Fit the raw-interval gate of 1-bit captures."),
    "evaluate": ("rmbvideo.cli.evaluate:evaluate", "Score every method on held-out and real-video data."),
    "bench": ("rmbvideo.cli.bench:bench", "What accuracy costs in time, for every method."),
    "batch": ("rmbvideo.cli.batch:batch", "Convert many captures, unattended and resumable."),
}


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised where the process is, so every output in progress is aborted and
    removed on the way out (as for Ctrl-C)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


#: Signals received by this process, in order: an exception that a signal's own exception turned into
#: (a C extension's import fails with ImportError when the signal lands inside it) is still reported as
#: that signal.
_received: list[int] = []


def _terminate(signum: int, frame: object) -> None:
    _received.append(signum)
    raise_or_defer(Terminated(signum))


def _interrupt(signum: int, frame: object) -> None:
    _received.append(signum)
    raise_or_defer(KeyboardInterrupt())


def _redeliver_swallowed(unraisable: Any, default: Callable[[Any], None]) -> None:
    """``sys.unraisablehook`` while a command runs: a signal's exception raised where Python can only print and drop
    it (a ``__del__``, or logging's at-fork hook while a video encoder starts) is sent again a moment later, from a
    thread, so it lands once the main thread is past that place and the command stops as for any signal, without a
    traceback (sent at once it would land in this hook, which drops it too); anything else is reported as Python
    reports it."""
    import threading

    exc = unraisable.exc_value
    if isinstance(exc, KeyboardInterrupt) and _received:
        signum = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
        threading.Timer(0.01, _resend, (signum,)).start()
        return
    default(unraisable)


def _resend(signum: int) -> None:
    """The signal again, unless the command has ended meanwhile (its handlers gone, it would stop Python's exit)."""
    if getattr(sys.unraisablehook, "func", None) is _redeliver_swallowed:
        os.kill(os.getpid(), signum)


class LazyGroup(click.Group):
    """A group whose subcommands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(name for name in COMMANDS if _spec_exists(COMMANDS[name][0]))

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        entry = COMMANDS.get(name)
        if entry is None or not _spec_exists(entry[0]):
            return None
        module, attr = entry[0].split(":")
        return getattr(importlib.import_module(module), attr)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list from ``COMMANDS`` without importing any command (``--help`` stays fast)."""
        rows = [(name, COMMANDS[name][1]) for name in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def resolve_command(self, ctx: click.Context, args: list[str]):
        """Unknown commands get the closest known name as a suggestion."""
        import difflib

        name = args[0] if args else ""
        if name and not name.startswith("-") and name not in COMMANDS:
            close = difflib.get_close_matches(name, list(COMMANDS), n=1)
            hint = f" Did you mean {close[0]!r}?" if close else ""
            ctx.fail(f"No such command {name!r}.{hint}")
        return super().resolve_command(ctx, args)

    def invoke(self, ctx: click.Context):
        _received.clear()  # signals of an earlier in-process run do not count for this one
        previous: dict[int, Any] = {}
        hook = sys.unraisablehook
        # The handlers are installed and restored inside the try, so a signal that lands just after one is installed,
        # or while they are restored at the end, is reported as that signal (not as click's "Aborted!", exit 1).
        try:
            try:
                for sig in (signal.SIGTERM, signal.SIGHUP):
                    previous[sig] = signal.signal(sig, _terminate)
                if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
                    previous[signal.SIGINT] = signal.signal(signal.SIGINT, _interrupt)
                sys.unraisablehook = functools.partial(_redeliver_swallowed, default=hook)
                return super().invoke(ctx)
            except (RmbvideoError, KeyboardInterrupt, MemoryError):
                raise
            except Exception:
                if _received:  # the signal's exception was turned into another one on its way up
                    raise (KeyboardInterrupt() if _received[0] == signal.SIGINT else Terminated(_received[0])) from None
                raise
            finally:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)
                sys.unraisablehook = hook
        except RmbvideoError as exc:
            click.echo(f"rmbvideo: error: {exc}", err=True)
            ctx.exit(2)
        except Terminated as exc:
            click.echo(f"rmbvideo: stopped by {signal.Signals(exc.signum).name}; {_left_behind(exc)}", err=True)
            ctx.exit(128 + exc.signum)
        except KeyboardInterrupt as exc:
            click.echo(f"rmbvideo: interrupted; {_left_behind(exc)}", err=True)
            ctx.exit(130)
        except MemoryError:
            command = ctx.invoked_subcommand or "rmbvideo"
            click.echo(f"rmbvideo: error: {command}: out of memory with these options (a capture's size, a sensor's "
                       "parameters, or the process's memory limit); partial output removed", err=True)
            ctx.exit(2)


def _left_behind(stop: KeyboardInterrupt) -> str:
    """What a stopped command leaves: in its own words where it says (training: the checkpoint it saved), else the
    rule every output follows."""
    return getattr(stop, "left_behind", None) or "partial output removed"


def _spec_exists(spec: str) -> bool:
    return importlib.util.find_spec(spec.split(":")[0]) is not None


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", is_flag=True, help="Log debug messages.")
@click.version_option(package_name="rmbvideo")
def main(verbose: bool) -> None:
    """Turn spiking-camera captures (.dat) into HDR, high-frame-rate video."""
    configure_logging(verbose=verbose)
    keep_freed_memory()


class _TqdmHandler(logging.StreamHandler):
    """Writes log lines through ``tqdm.write`` so they never tear an active progress bar."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm import tqdm

            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # logging must never raise
            self.handleError(record)


def configure_logging(verbose: bool = False, quiet: bool = False) -> None:
    """Log to stderr through tqdm: rmbvideo's debug messages with ``verbose`` (other libraries' stay at info:
    matplotlib's font search alone wrote hundreds of debug lines into ``bench -v``), warnings only with ``quiet``
    (and OpenCV's own messages off), else info. Later calls (a subcommand's -v/-q) override earlier ones."""
    level = logging.INFO if verbose else logging.WARNING if quiet else logging.INFO
    logging.getLogger("rmbvideo").setLevel(logging.DEBUG if verbose else logging.NOTSET)
    root = logging.getLogger()
    for handler in list(root.handlers):
        if isinstance(handler, _TqdmHandler):
            root.removeHandler(handler)
    handler = _TqdmHandler()
    handler.setFormatter(logging.Formatter("rmbvideo: %(levelname)s: %(message)s" if verbose else "rmbvideo: %(message)s"))
    root.addHandler(handler)
    root.setLevel(level)
    if not verbose:
        os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")


def _set_quiet(ctx: click.Context, param: click.Parameter, value: bool) -> bool:
    if value:
        configure_logging(quiet=True)
    return value


def _set_verbose(ctx: click.Context, param: click.Parameter, value: bool) -> bool:
    if value:
        configure_logging(verbose=True)
    return value


def quiet_option(func):
    """``-q/--quiet``: no progress bar and no info lines (warnings and errors still show)."""
    return click.option("-q", "--quiet", is_flag=True, callback=_set_quiet,
                        help="No progress bar and no messages but warnings and errors.")(func)


def quiet_logging_option(func):
    """``-q/--quiet`` for commands without a progress bar: no messages but warnings and errors."""
    return click.option("-q", "--quiet", "quiet_", is_flag=True, expose_value=False, callback=_set_quiet,
                        help="No messages but warnings and errors.")(func)


def verbose_option(func):
    """``-v/--verbose`` after a subcommand, as before it: debug messages."""
    return click.option("-v", "--verbose", "verbose_", is_flag=True, expose_value=False, callback=_set_verbose,
                        help="Log debug messages.")(func)


def progress_enabled(quiet: bool) -> bool:
    """Show a progress bar only on a terminal and when not ``--quiet``."""
    return not quiet and sys.stderr.isatty()
