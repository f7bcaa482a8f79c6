"""How far lock-step may run ahead of the recorder: the environment's side of the monitor's
acknowledgements (``recorded``, docs/health.md).

The monitor says, at every ``RECORDER_ACK_STEPS``-th flight-software step's clock it has
recorded, that it has recorded it.  In lock-step the environment flies at most
``RECORDER_LEAD_STEPS`` steps past the newest clock so acknowledged: a monitor that is frozen
(stopped, swapped out) or behind pauses the mission as a silent controller does, instead of the
bus dropping what the monitor could not take, and past run.hang_timeout the run ends naming the
monitor.  A monitor whose liveliness token is gone is not waited for: it died, and the launcher
ends the run and recovers the report from its recording.
"""

from __future__ import annotations

from services.flight.health import RECORDER_LEAD_STEPS

RECORDER = "monitor"
"""The service whose acknowledgements lock-step waits for."""


class RecorderLead:
    """The newest clock the recorder has acknowledged, and whether a step must wait for it.

    Parameters
    ----------
    fsw_period : the flight-software step, s.
    present : the recorder's liveliness token is alive (it is waited for only then).
    """

    def __init__(self, fsw_period: float, present: bool) -> None:
        self.lead = RECORDER_LEAD_STEPS * fsw_period
        self.present = present
        self.recorded_t = 0.0  # the first lead's steps fly before any acknowledgement

    def acknowledged(self, t: float) -> None:
        """The recorder has recorded the clock at ``t`` s and what came before it."""
        self.recorded_t = max(self.recorded_t, t)

    def presence(self, up: bool) -> None:
        """The recorder's liveliness token came (``up``) or went."""
        self.present = up

    def behind(self, t_k: float) -> bool:
        """The step at ``t_k`` waits: the recorder is there and more than the lead behind."""
        return self.present and t_k - self.recorded_t > self.lead + 1e-6
