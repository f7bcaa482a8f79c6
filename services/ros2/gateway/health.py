"""The run's services' health as ROS 2 diagnostics: one ``DiagnosticStatus`` a service, from
what the bus says of it (its liveliness token, its ``stats``, a controller's ``status``, its
newest ``log`` line), for ``/diagnostics``.

A status is named ``ddvi/<service>``, with the deputy a navigation or controller serves as its
``hardware_id``.  Its level:

- STALE: not alive during the mission (its token gone, or not there yet);
- ERROR or WARN: its newest log line is an error or a warning (the line is the message);
- OK otherwise: "up" (a controller: its mode and phase), "finished" once it has left after the
  mission's final clock.

Its values: the counters of its newest stats (``stats/<service>``) and, for a controller, its
newest status (mode, phase, samples, intervals, rank, rank needed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from services.interface import Message
from services.ros2.conversions import Level, Status

_LOG_LEVELS = {"warning": Level.WARN, "error": Level.ERROR}
_STATUS_FIELDS = ("mode", "phase", "samples", "intervals", "rank", "rank_needed")


@dataclass
class _Service:
    """What the bus has said of one service."""

    alive: bool = False
    seen: bool = False  # ever alive
    counters: dict[str, int] = field(default_factory=dict)
    status: dict[str, Any] = field(default_factory=dict)
    log: tuple[str, str] = ("", "")  # its newest line: (level, text)


def _deputy_of(service: str) -> str:
    kind, _, rest = service.partition("-")
    return rest if kind in ("nav", "ctrl") else ""


class Health:
    """The health of ``services`` (a deployment's, in its order), as the bus says it.

    Parameters
    ----------
    services : the run's service names.
    """

    def __init__(self, services: list[str]) -> None:
        self.services: dict[str, _Service] = {s: _Service() for s in services}
        self.final = False  # the mission's final clock has come: a service that leaves is done

    def presence(self, service: str, up: bool) -> bool:
        """A service's token came (``up``) or went; whether it is one of the run's."""
        if (entry := self.services.get(service)) is None:
            return False
        entry.alive = up
        entry.seen = entry.seen or up
        return True

    def take(self, msg: Message) -> bool:
        """A ``stats``, ``status`` or ``log`` message (its topic's publisher's: the bus checks
        who may say what); whether it changed a status."""
        body = msg.body
        name = body.get("service", msg.src)
        if msg.schema == "status":
            name = f"ctrl-{body['sc']}"
        if (entry := self.services.get(name)) is None:
            return False
        if msg.schema == "stats":
            entry.counters = dict(body["counters"])
        elif msg.schema == "status":
            entry.status = {k: body[k] for k in _STATUS_FIELDS}
        elif msg.schema == "log":
            entry.log = (body["level"], body["text"])
        else:
            return False
        return True

    def own(self, service: str, counters: dict[str, int]) -> None:
        """The counters of the service that reports (the gateway itself)."""
        if (entry := self.services.get(service)) is not None:
            entry.counters = dict(counters)
            entry.alive = entry.seen = True

    def statuses(self) -> list[Status]:
        """Every service's status now."""
        return [self._status(name, entry) for name, entry in self.services.items()]

    def headlines(self) -> tuple[tuple[Level, str], ...]:
        """Every service's level and message now (its status without the values)."""
        return tuple(self._headline(entry) for entry in self.services.values())

    def _headline(self, entry: _Service) -> tuple[Level, str]:
        level, text = entry.log
        if not entry.alive and self.final and entry.seen:
            return Level.OK, "finished"
        if not entry.alive:
            return Level.STALE, (
                "not alive (its liveliness token is gone)" if entry.seen else "not alive yet"
            )
        if level in _LOG_LEVELS:
            return _LOG_LEVELS[level], text
        if entry.status:
            return Level.OK, f"{entry.status['mode']}, {entry.status['phase']}"
        return Level.OK, "up"

    def _status(self, name: str, entry: _Service) -> Status:
        values = [(k, str(v)) for k, v in entry.status.items()]
        values += [(k, str(v)) for k, v in sorted(entry.counters.items())]
        level, message = self._headline(entry)
        return Status(f"ddvi/{name}", level, message, _deputy_of(name), tuple(values))
