"""Fixtures every layer's tests may use (helpers to import are in ``tests.support``)."""

from __future__ import annotations

import pytest

from services.ground.launcher import free_port as _free_port
from tests.support import unique_run_name


@pytest.fixture
def run_name() -> str:
    """A fresh run name (key prefix ``ddvi/<run>/``) for one test."""
    return unique_run_name()


@pytest.fixture
def free_port() -> int:
    """A loopback TCP port nobody listens on right now."""
    return _free_port()
