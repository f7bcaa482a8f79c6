"""When a controller's flight-software step may fly, and on what: the gate between the inputs a
controller has accounted for and its steps (``services.flight.controller``).

A step at T flies on the newest navigation sample measured by T - delay (the links' nominal
delay), once the clock has reached T and that sample, and its exostate, are accounted for:
delivered, or held or lost by their links.  While navigation is away (its liveliness token gone
for ``NAV_AWAY_GRACE``, until it is back) a step does not wait for its sample.  Health
(docs/health.md): in lock-step a step whose sample does not come is said after
run.command_deadline and given up past run.hang_timeout (``HangError`` naming the silent
service); in either mode a step whose newest sample is older than run.nav_stale_limit flies the
safe attitude.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from services.flight.control_loop import stale_limit
from services.flight.health import HangError, Waiting

NAV_AWAY_GRACE = 1.0
"""Wall seconds after navigation's token goes before steps fly without its samples: a token's
undeclaration can overtake the samples the service put just before it left."""


class StepGate:
    """What a controller's steps wait for.

    Parameters
    ----------
    run : the deployment's ``[run]`` (mode, fsw_period, command_deadline, hang_timeout,
        nav_stale_limit).
    sc : the deputy's name (its navigation service is ``nav-<sc>``).
    expected_sample : the measurement time of the newest sample a step at T can have
        (``ControlLoop.expected_sample``: its inputs' delay behind it).
    """

    def __init__(self, run: Any, sc: str, expected_sample: Callable[[float], float]) -> None:
        self.sc, self.expected_sample = sc, expected_sample
        # the clock's time reached, and the nav and exo samples accounted for up to
        self.reached = {"now": -math.inf, "nav": -math.inf, "exo": -math.inf}
        # while navigation is away (its token gone NAV_AWAY_GRACE ago, until the token is
        # back), steps fly on the newest sample there is instead of waiting for one that will
        # not come.  Not until its next sample: a late or replayed one would end the absence
        # for good.
        self.nav_gone: float | None = None  # when its token went (monotonic s)
        self.lockstep = run.mode == "lockstep"
        self.patience = (run.command_deadline, run.hang_timeout)
        self.waiting: tuple[float, Waiting] | None = None  # the step waited for, and how long
        self.stale_limit = stale_limit(run)

    # -- what has been accounted for ----------------------------------------------------------

    def clock(self, t: float) -> None:
        self.reached["now"] = max(self.reached["now"], t)

    def accounted(self, key: str, t: float) -> None:
        """A ``key`` ("nav" or "exo") sample measured at t delivered, held or lost by its link."""
        self.reached[key] = max(self.reached[key], t)

    def flooded(self, key: str, T: float) -> None:
        """``key``'s messages dropped unread by the rate budget: the sample the step at T
        flies on counts as lost."""
        if not math.isinf(T):
            self.accounted(key, self.expected_sample(T))

    def presence(self, up: bool) -> None:
        """Navigation's liveliness token came (``up``) or went."""
        if up:  # back: a restarted navigation is alive once it publishes
            self.nav_gone = None
        elif self.nav_gone is None:  # gone: from the first notice
            self.nav_gone = time.monotonic()

    # -- the steps ----------------------------------------------------------------------------

    def nav_away(self) -> bool:
        return self.nav_gone is not None and time.monotonic() - self.nav_gone >= NAV_AWAY_GRACE

    def ready(self, T: float) -> bool:
        """The clock has reached T and the sample the step flies on is accounted for
        (delivered, or held or lost by its link)."""
        if math.isinf(T):  # restarted, no sample yet: no step to fly
            return False
        want, reached = self.expected_sample(T), self.reached
        if not self.lockstep and reached["now"] >= T + self.stale_limit - 1e-6:
            return True  # real time does not wait past the limit: the step flies safe
        return reached["now"] >= T - 1e-6 and (
            want < -1e-6
            or (
                (reached["nav"] >= want - 1e-6 or self.nav_away()) and reached["exo"] >= want - 1e-6
            )
        )

    def check(self, T: float, say: Callable[[str], None]) -> None:
        """Lock-step: the step at T whose clock has come but not its sample waits; ``say``s
        so once it has waited run.command_deadline, and raises ``HangError`` naming the
        silent service past run.hang_timeout."""
        reached = self.reached
        if not self.lockstep or math.isinf(T) or reached["now"] < T - 1e-6 or self.ready(T):
            self.waiting = None
            return
        if self.waiting is None or self.waiting[0] != T:
            self.waiting = (T, Waiting(*self.patience))
        waiting, want = self.waiting[1], self.expected_sample(T)
        who = f"nav-{self.sc}" if reached["nav"] < want - 1e-6 else "environment"
        now = time.monotonic()
        if waiting.said_at(now):
            say(
                f"lock-step paused at t = {T:.0f} s: no sample for t = {want:.0f} s from {who} "
                f"for {waiting.said:g} s"
            )
        if waiting.over(now):
            raise HangError(who, f"sample for t = {want:.0f} s", T, waiting.hang)
