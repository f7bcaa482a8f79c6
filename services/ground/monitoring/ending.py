"""When the monitor's recording loop ends (``services.ground.monitoring.monitor``): after the final
clock, once every other service has finished and what each said it published has come (or a bounded
wait passed); on a stop request, once what is queued has been recorded (bounded)."""

from __future__ import annotations

import logging
from typing import Protocol

from services.ground.analysis.rundata import RunData

log = logging.getLogger("ddvi.monitor")

FINAL_WAIT = 5.0  # s to wait for the other services' final stats after the final clock
FINAL_GRACE = 0.25  # s to keep recording once every service has finished
STOP_DRAIN = 1.0  # s to keep recording what is already queued after SIGTERM


class Recording(Protocol):
    """What the ending looks at of the recording loop (the monitor's)."""

    data: RunData

    def pending(self) -> list[str]:
        """The services still to finish."""
        ...


class Ending:
    """When the recording loop ends: after the final clock, once every other service has
    finished (plus ``FINAL_GRACE``) or ``FINAL_WAIT`` passed; on a stop request, once nothing
    more is queued or ``STOP_DRAIN`` passed."""

    def __init__(self) -> None:
        self.final_deadline: float | None = None
        self.grace_deadline: float | None = None
        self.stop_deadline: float | None = None
        self.waited_for: dict[str, int] = {}  # unrecorded messages the ending waited for

    def check(self, mon: Recording, stop: bool, idle: bool, now: float) -> bool | None:
        """None to go on recording; else whether the mission completed."""
        if mon.data.final_seen:
            if self.final_deadline is None:
                self.final_deadline = now + FINAL_WAIT
                log.info("final clock at t = %.0f s; waiting for final stats", mon.data.sim_t)
            if not mon.pending() and self.grace_deadline is None:
                self.grace_deadline = now + FINAL_GRACE  # stragglers racing the token drops
            graced = self.grace_deadline is not None and now >= self.grace_deadline
            if graced and (unrecorded := mon.data.unrecorded()):
                graced = False  # published and not here yet: wait for it, up to FINAL_WAIT
                if not self.waited_for:
                    log.info(
                        "waiting for what was published and has not come: %s",
                        _by_publisher(unrecorded),
                    )
                self.waited_for = unrecorded
            elif graced and self.waited_for:
                log.info(
                    "what was awaited came %.2f s after the last token went",
                    now - (self.grace_deadline or now) + FINAL_GRACE,
                )
            if graced or now >= self.final_deadline:
                if missing := mon.pending():
                    log.warning("no final stats from %s after %.0f s", missing, FINAL_WAIT)
                if unrecorded := mon.data.unrecorded():
                    log.warning("published but never recorded: %s", _by_publisher(unrecorded))
                return True
        if stop:
            # Record what has already arrived (bounded), then stop.
            if self.stop_deadline is None:
                self.stop_deadline = now + STOP_DRAIN
                log.info("stop requested at t = %.0f s", mon.data.sim_t)
            if idle or now >= self.stop_deadline:
                return mon.data.final_seen
        return None


def _by_publisher(counts: dict[str, int]) -> str:
    """``{"nav-ddvi": 6}`` as "6 from nav-ddvi", publishers in order."""
    return ", ".join(f"{n} from {s}" for s, n in sorted(counts.items()))
