"""``python -m rmbvideo`` runs the command-line interface."""

from rmbvideo.cli import main

main()
