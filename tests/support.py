"""What several test modules share: polling for an outcome and unique run names."""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable

TIMEOUT = 5.0
"""Seconds a test waits for something that happens within milliseconds when all is well."""

_run_numbers = itertools.count()


def wait_until(predicate: Callable[[], bool], timeout: float = TIMEOUT) -> bool:
    """Poll ``predicate`` every 10 ms; True as soon as it holds, False after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def unique_run_name(prefix: str = "test") -> str:
    """A run name no other test of this session (or another session's process) uses."""
    return f"{prefix}{os.getpid()}x{next(_run_numbers)}"
