"""``python -m rmbvideo`` and the ``rmbvideo`` command: the command-line interface."""

import sys


def run() -> None:
    """Start the CLI; Ctrl-C while it is still importing exits 130 quietly (nothing was written yet)."""
    try:
        from rmbvideo.cli import main
    except KeyboardInterrupt:
        sys.exit(130)
    main()


if __name__ == "__main__":
    run()
