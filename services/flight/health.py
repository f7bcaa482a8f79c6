"""Flight-software health and safety shared by the flight services (docs/health.md): a
lock-step wait that is said, then given up (``Waiting``, ``HangError``), and the safe attitude
a controller flies when its navigation is too old in real time (``SAFE_SIGMA``)."""

from __future__ import annotations

import time

HANG_STATUS = 4
"""A flight service's exit status when it gave up a lock-step wait (``HangError``): the launcher
ends the run (status 1) naming the silent service, whatever the restart policy."""

HANG_MARGIN = 5.0
"""Wall seconds the environment waits for a controller past run.hang_timeout: a controller
waiting on its own navigation gives up first and names it (``services.flight.controller``)."""

RECORDER_LEAD_STEPS = 32
"""Flight-software steps lock-step may run ahead of the last clock the monitor says it has
recorded: a frozen or slow recorder pauses the mission within them instead of losing what the
bus could not hold for it (a step's traffic is a few kB; the lead fits in a socket's buffer)."""
RECORDER_ACK_STEPS = 8
"""The monitor says what it has recorded at every this many flight-software steps' clock."""

SAFE_SIGMA = (0.0, 0.0, 0.0)
"""The safe attitude command (relative MRP): the deputy Hill-pointing like the chief, so the two
present the same drag and the formation drifts only as its relative orbit does, instead of being
driven, at up to the attitude limit, by feedback on a state that is no longer measured."""


ROUTER = "the run's router (the launcher's process)"
"""What a hang is blamed on when the router does not answer (``HangError.router_silent``)."""


class HangError(Exception):
    """Lock-step cannot go on: ``service`` has not given its ``what`` for the step at ``t`` in
    ``seconds`` wall seconds.  The message names the part that froze: ``service`` (or
    ``behind``, what the service relays: a ROS 2 node behind the ROS 2 gateway), or with
    ``router_silent`` the run's router, which relays them all (``hung`` is that part)."""

    def __init__(
        self,
        service: str,
        what: str,
        t: float,
        seconds: float,
        router_silent: bool = False,
        behind: str = "",
    ) -> None:
        self.service, self.what, self.t, self.seconds = service, what, t, seconds
        self.behind = behind
        self.hung = ROUTER if router_silent else (behind or service)
        said = f"lock-step stalled at t = {t:.0f} s: no {what} from {service} in {seconds:g} s"
        if router_silent:
            said += " (run.hang_timeout), and the router does not answer"
        else:
            said += " (run.hang_timeout)"
        super().__init__(f"{said}: {self.hung} is hung")

    def router_silent(self) -> HangError:
        """The same stall, blamed on the router."""
        return HangError(
            self.service, self.what, self.t, self.seconds, router_silent=True, behind=self.behind
        )


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
