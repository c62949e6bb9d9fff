"""Where the shipped weights live, in a module that imports nothing heavy: a run's fingerprint hashes them for every
method, and a classical method's run must not load torch to find them."""

from __future__ import annotations

from pathlib import Path

#: ``rmbvideo/models`` links to the repository's top-level ``models/`` folder.
MODELS_DIR = Path(__file__).resolve().parent / "models"
