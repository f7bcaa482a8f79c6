"""Watching a run's services while the mission flies (the launcher's ``_fly``): a ``kill`` fault
(``ddvi fault RUN kill SERVICE``) SIGKILLs the named service, as a crash would; a service that
dies before the mission ends is started again into the running mission (``--join``) when its
[[restart]] policy says so, up to its ``max_restarts``, else the run ends; a service that gave
up a lock-step wait (``HANG_STATUS``) ends the run naming the hung one.  Each event is said on
the terminal, logged on ``log/launcher`` and counted on ``stats/launcher`` (restarts,
restarts.<service>, kills)."""

from __future__ import annotations

import queue
import time
from collections.abc import Callable

from services.bus import Bus
from services.config import Deployment
from services.flight.health import HANG_STATUS
from services.ground import lifecycle
from services.ground.processes import ServiceProcesses
from services.interface.topics import log_topic, stats_topic

POLL = 0.2
"""Wall seconds between two looks at the services and the fault queue."""


class Supervisor:
    """The services of one run while the environment flies.

    Parameters
    ----------
    dep : the deployment (its restart policies).
    services : the run's processes (and its folder, ``services.out``: their logs).
    say : how the launcher says a line on the terminal (``error``: even with --quiet).
    stopping : whether a stop signal has come.
    """

    def __init__(self, dep: Deployment, services: ServiceProcesses, say: Callable[..., None],
                 stopping: Callable[[], bool]) -> None:  # fmt: skip
        self.dep, self.services = dep, services
        self.say, self.stopping = say, stopping
        self.restarts: dict[str, int] = {}
        self.kills = 0
        self.monitor_died = False  # then the report is recovered from its recording

    def watch(self, bus: Bus, faults: queue.SimpleQueue) -> int | None:
        """Until the environment ends: None when it completed the mission, else the run's
        exit status (a stop signal, a hung or failed service, an environment that failed)."""
        env = self.services["environment"].popen
        sim_t = 0.0
        while env.poll() is None:
            if self.stopping():
                return lifecycle.EXIT_FAILED  # the launcher makes it 128 + N
            while not faults.empty():
                _, msg = faults.get_nowait()
                sim_t = max(sim_t, msg.t)
                if msg.body["kind"] == "kill":
                    self.kill(bus, msg.body["target"], msg.t)
            if (status := self._look(bus, sim_t)) is not None:
                return status
            time.sleep(POLL)
        if env.returncode == HANG_STATUS:
            return self.hung("environment")
        if env.returncode != 0:
            log = self.services.out / "logs" / "environment.log"
            self.say(f"environment exited with status {env.returncode}: "
                     f"{lifecycle.log_reason(log)} (log: {log})", error=True)  # fmt: skip
            return 1
        return None

    def _look(self, bus: Bus, sim_t: float) -> int | None:
        """Restart by policy a service that has died; the run's status when one ends it."""
        for p in self.services:
            name, rc = p.name, p.popen.poll()
            if rc == HANG_STATUS:
                return self.hung(name)
            if rc in (None, 0) or name == "environment":
                continue
            policy = self.dep.restart_policy(name)
            done = self.restarts.get(name, 0)
            if policy.policy == "on-failure" and done < policy.max_restarts:
                self.restarts[name] = done + 1
                self.services.start(name, join=True)
                self.event(bus, "warning", f"{name} exited with status {rc}; restarted "
                           f"({done + 1} of {policy.max_restarts})", sim_t)  # fmt: skip
                continue
            log = self.services.out / "logs" / f"{name}.log"
            tail = "".join(f"\n    {line}" for line in lifecycle.last_lines(log))
            self.say(f"{name} exited with status {rc} before the mission ended; last "
                     f"lines of {log}:{tail or ' (empty)'}", error=True)  # fmt: skip
            self.monitor_died = name == "monitor"
            return 1
        return None

    def event(self, bus: Bus, level: str, text: str, t: float) -> None:
        """Say it, log it on the bus, and publish the launcher's counters."""
        self.say(text)
        counters = {"restarts": sum(self.restarts.values()), "kills": self.kills}
        counters.update({f"restarts.{k}": v for k, v in self.restarts.items()})
        try:
            log = {"service": "launcher", "level": level, "text": text}
            bus.publish(log_topic("launcher"), "log", log, t)
            stats = {"service": "launcher", "counters": counters}
            bus.publish(stats_topic("launcher"), "stats", stats, t)
        except Exception as exc:  # the bus is a report channel here, never a reason to stop
            self.say(f"could not publish: {exc}")

    def kill(self, bus: Bus, target: str, t: float) -> None:
        """A ``kill`` fault: SIGKILL the named service, as a crash would."""
        p = self.services.get(target)
        if p is None:
            why = "no such service"
        elif target in ("environment", "monitor"):
            why = "the environment and the monitor are not killed by faults (they end the run)"
        elif p.popen.poll() is not None:
            why = "it is not running"
        else:
            why = ""
        if why:
            self.event(bus, "warning", f"fault kill {target}: ignored ({why})", t)
            return
        p.popen.kill()
        self.kills += 1
        self.event(bus, "warning", f"fault kill {target}: killed (SIGKILL) at t = {t:.0f} s", t)

    def hung(self, name: str) -> int:
        """``name`` gave up a lock-step wait (run.hang_timeout): end the run, with its word on
        which service is hung (docs/health.md)."""
        log = self.services.out / "logs" / f"{name}.log"
        said = [line for line in lifecycle.last_lines(log) if " is hung" in line]
        why = said[-1].split(" ERROR ", 1)[-1] if said else f"see {log}"
        self.say(f"{why}; {name} gave up waiting (run.hang_timeout): the run is ended",
                 error=True)  # fmt: skip
        return lifecycle.EXIT_FAILED
