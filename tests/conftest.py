"""Fixtures every layer's tests may use (helpers to import are in ``tests.support``)."""

from __future__ import annotations

import pytest

from tests.support import unique_run_name


@pytest.fixture
def run_name() -> str:
    """A fresh run name (key prefix ``ddvi/<run>/``) for one test."""
    return unique_run_name()


@pytest.fixture
def free_port() -> int:
    """A loopback TCP port nobody listens on right now."""
    from services.ground.launch.launcher import (
        free_port as find_free_port,  # only tests that need it
    )

    return find_free_port()
