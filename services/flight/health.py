"""Flight-software health and safety shared by the flight services (docs/health.md): a
lock-step wait that is said, then given up (``Waiting``, ``HangError``), and the safe attitude
a controller flies when its navigation is too old in real time (``SAFE_SIGMA``)."""

from __future__ import annotations

import time

HANG_STATUS = 4
"""A flight service's exit status when it gave up a lock-step wait (``HangError``): the launcher
ends the run (status 1) naming the silent service, whatever the restart policy."""

SAFE_SIGMA = (0.0, 0.0, 0.0)
"""The safe attitude command (relative MRP): the deputy Hill-pointing like the chief, so the two
present the same drag and the formation drifts only as its relative orbit does, instead of being
driven, at up to the attitude limit, by feedback on a state that is no longer measured."""


class HangError(Exception):
    """Lock-step cannot go on: ``service`` has not given its ``what`` for the step at ``t`` in
    ``seconds`` wall seconds."""

    def __init__(self, service: str, what: str, t: float, seconds: float) -> None:
        super().__init__(f"lock-step stalled at t = {t:.0f} s: no {what} from {service} in "
                         f"{seconds:g} s (run.hang_timeout): {service} is hung")  # fmt: skip
        self.service, self.t = service, t


class Waiting:
    """One lock-step wait on wall time: said once after ``said`` s, over after ``hang`` s."""

    def __init__(self, said: float, hang: float) -> None:
        self.start = time.monotonic()
        self.said, self.hang = said, hang
        self._told = False

    @property
    def until(self) -> float:
        """When the wait next has something to do (say it, or give up)."""
        return self.start + (self.hang if self._told else min(self.said, self.hang))

    def said_at(self, now: float) -> bool:
        """True once, the first time ``now`` is past ``said``."""
        if self._told or now < self.start + self.said:
            return False
        self._told = True
        return True

    def over(self, now: float) -> bool:
        return now >= self.start + self.hang
