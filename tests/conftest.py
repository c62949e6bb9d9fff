"""Shared fixtures. Development data lives in ``../shared/data`` beside the checkout; tests that
need it skip cleanly where it is absent (as on a user's machine)."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    """Path to ``../shared/data``; skips the test when it is not there."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present (development data only)")
    return SHARED_DATA


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--soak", type=int, default=0, metavar="N",
                     help="also run N random signal injections per fault-matrix cell (long; off in CI)")


@pytest.fixture
def soak(request: pytest.FixtureRequest) -> int:
    """Extra random trials asked for with ``--soak N`` (0 by default)."""
    return request.config.getoption("--soak")
