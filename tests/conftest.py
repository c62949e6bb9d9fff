"""Shared fixtures. Development data lives in ``../shared/data`` beside the checkout; tests that
need it skip cleanly where it is absent (as on a user's machine)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
#: The environment the test session started with, before any test module's imports changed it (importing
#: OpenCV prepends its bundled libraries to LD_LIBRARY_PATH, which changes what a child process loads).
STARTUP_ENV = dict(os.environ)


@pytest.fixture
def shared_data() -> Path:
    """Path to ``../shared/data``; skips the test when it is not there."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present (development data only)")
    return SHARED_DATA


@pytest.fixture
def startup_env() -> dict[str, str]:
    """A copy of the environment as it was when the test session started."""
    return dict(STARTUP_ENV)


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C as on a terminal: a shell starts a background job (``pytest ... &``) with SIGINT ignored, which Python
    keeps and children inherit, and the tests that stop a run with Ctrl-C then waited for a stop that never came (the
    frozen-worker batch test hung the suite; a training run timed out)."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--soak", type=int, default=0, metavar="N",
                     help="also run N random signal injections per fault-matrix cell (long; off in CI)")


@pytest.fixture
def soak(request: pytest.FixtureRequest) -> int:
    """Extra random trials asked for with ``--soak N`` (0 by default)."""
    return request.config.getoption("--soak")
