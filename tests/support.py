"""What several test modules share: polling for an outcome, waiting for a run to fly, and unique
run names."""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable
from typing import IO

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


FLYING = b"services alive"
"""What ``ddvi run`` (not ``--quiet``) says on stderr once every service but the environment is
alive: the environment, started with them, then flies."""


def read_until_flying(stderr: IO[bytes]) -> list[bytes]:
    """The lines of a ``ddvi run``'s stderr up to the one saying its services are alive (all of
    them if it never says so): the caller keeps them, since what follows is read elsewhere."""
    said = []
    for line in stderr:
        said.append(line)
        if FLYING in line:
            break
    return said
