"""``python -m rmbvideo`` runs the command-line interface."""

import sys

try:
    from rmbvideo.cli import main
except KeyboardInterrupt:  # Ctrl-C while starting up: nothing was written yet
    sys.exit(130)

main()
