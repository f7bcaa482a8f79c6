"""Watching a run's services while the mission flies (the launcher's ``_fly``): a ``kill`` fault
(``ddvi fault RUN kill SERVICE``) SIGKILLs the named service, as a crash would; a service that
dies before the mission ends is started again into the running mission (``--join``) when its
[[restart]] policy says so, up to its ``max_restarts``, else the run ends; a service that gave
up a lock-step wait (``HANG_STATUS``) ends the run naming the hung one; an environment that
stops talking (no clock for run.hang_timeout + ``CLOCK_MARGIN`` while its process lives, longer
than any wait of its own lasts) ends it naming the environment.  Each event is said on the
terminal, logged on ``log/launcher`` and counted on ``stats/launcher`` (restarts,
restarts.<service>, kills)."""

from __future__ import annotations

import queue
import time
from collections.abc import Callable

import zenoh

from services.bus import Bus
from services.config import Deployment, DeploymentError, check_kill
from services.flight.health import HANG_MARGIN, HANG_STATUS
from services.ground.launch import lifecycle
from services.ground.launch.processes import ServiceProcesses
from services.interface import MessageError, decode, unpack_batch
from services.interface.topics import CLOCK, log_topic, stats_topic

POLL = 0.2
"""Wall seconds between two looks at the services and the fault queue."""
CLOCK_MARGIN = 2 * HANG_MARGIN
"""Wall seconds past run.hang_timeout without a clock before the environment is taken for hung:
its own waits end by run.hang_timeout + ``HANG_MARGIN`` and it then exits naming what it waited
for."""
SELF_FROZEN = 2.0
"""Wall seconds between two looks that say this process was itself stopped: a silence it slept
through says nothing of the others."""


class ClockWatch:
    """When the environment's clock was last heard, looked at once a poll: zenoh keeps the
    newest clock in a ring of one (a clock a step is the busiest key; no Python runs per
    sample), and only the environment may put it (the router's access control), so nothing is
    decoded until a silence is to be said."""

    def __init__(self, bus: Bus) -> None:
        self.heard: float | None = None  # monotonic s of the newest clock (None: none yet)
        self.payload: bytes = b""
        self._newest = bus.session.declare_subscriber(
            bus.prefix + CLOCK, zenoh.handlers.RingChannel(1)
        )

    def look(self, now: float) -> None:
        """Take a clock that came since the last look as heard ``now``."""
        sample = self._newest.try_recv()
        if sample is not None:
            self.payload, self.heard = sample.payload.to_bytes(), now

    def forgive(self, now: float) -> None:
        """The watcher itself was stopped: count the silence from ``now``."""
        if self.heard is not None:
            self.heard = now

    def silence(self, now: float) -> float:
        """Seconds since the newest clock (0 before the first)."""
        return 0.0 if self.heard is None else now - self.heard

    def close(self) -> None:
        self._newest.undeclare()

    def t(self) -> float:
        """The simulation time of the newest clock (0 when it does not decode)."""
        try:
            parts = unpack_batch(self.payload) or [self.payload]
            return max(decode(part, "clock").t for part in parts)
        except (MessageError, ValueError):
            return 0.0


class Supervisor:
    """The services of one run while the environment flies.

    Parameters
    ----------
    dep : the deployment (its restart policies).
    services : the run's processes (and its folder, ``services.out``: their logs).
    say : how the launcher says a line on the terminal (``error``: even with --quiet).
    stopping : whether a stop signal has come.
    rate : the pace lock-step flies at (``ddvi run --rate``; 0: none), which spaces its clocks.
    """

    def __init__(
        self,
        dep: Deployment,
        services: ServiceProcesses,
        say: Callable[..., None],
        stopping: Callable[[], bool],
        rate: float = 0.0,
    ) -> None:
        self.dep, self.services = dep, services
        self.say, self.stopping = say, stopping
        self.restarts: dict[str, int] = {}
        self.kills = 0
        self.monitor_died = False  # then the report is recovered from its recording
        run = dep.run
        if run.mode == "realtime":
            paced = run.nav_period / run.rate
        else:  # a paced lock-step's clocks are a step's worth of wall time apart
            paced = run.fsw_period / rate if rate > 0 else 0.0
        self.clock_silence = run.hang_timeout + CLOCK_MARGIN + paced

    def watch(self, bus: Bus, faults: queue.SimpleQueue) -> int | None:
        """Until the environment ends: None when it completed the mission, else the run's
        exit status (a stop signal, a hung or failed service, an environment that failed)."""
        env = self.services["environment"].popen
        sim_t = 0.0
        clock = ClockWatch(bus)
        try:
            looked = time.monotonic()
            while env.poll() is None:
                if self.stopping():
                    return lifecycle.EXIT_FAILED  # the launcher makes it 128 + N
                now = time.monotonic()
                if now - looked > SELF_FROZEN:
                    clock.forgive(now)  # this process was stopped: the silence is its own
                looked = now
                while not faults.empty():
                    _, msg = faults.get_nowait()
                    sim_t = max(sim_t, msg.t)
                    if msg.body["kind"] == "kill":
                        self.kill(bus, msg.body["target"], msg.t)
                if (status := self._look(bus, sim_t)) is not None:
                    return status
                clock.look(now)
                silence = clock.silence(now)
                if silence > self.clock_silence and env.poll() is None:
                    return self.silent_environment(bus, max(sim_t, clock.t()), silence)
                time.sleep(POLL)
        finally:
            clock.close()
        if env.returncode == HANG_STATUS:
            return self.hung("environment", bus, sim_t)
        if env.returncode != 0:
            log = self.services.out / "logs" / "environment.log"
            self.say(
                f"environment exited with status {env.returncode}: "
                f"{lifecycle.log_reason(log)} (log: {log})",
                error=True,
            )
            return 1
        return None

    def _look(self, bus: Bus, sim_t: float) -> int | None:
        """Restart by policy a service that has died; the run's status when one ends it."""
        for p in self.services:
            name, rc = p.name, p.popen.poll()
            if rc == HANG_STATUS:
                return self.hung(name, bus, sim_t)
            if rc in (None, 0) or name == "environment":
                continue
            policy = self.dep.restart_policy(name)
            done = self.restarts.get(name, 0)
            if policy.policy == "on-failure" and done < policy.max_restarts:
                self.restarts[name] = done + 1
                self.services.start(name, join=True)
                self.event(
                    bus,
                    "warning",
                    f"{name} exited with status {rc}; restarted "
                    f"({done + 1} of {policy.max_restarts})",
                    sim_t,
                )
                continue
            log = self.services.out / "logs" / f"{name}.log"
            tail = "".join(f"\n    {line}" for line in lifecycle.last_lines(log))
            self.say(
                f"{name} exited with status {rc} before the mission ended; last "
                f"lines of {log}:{tail or ' (empty)'}",
                error=True,
            )
            self.monitor_died = name == "monitor"
            return 1
        return None

    def event(self, bus: Bus, level: str, text: str, t: float) -> None:
        """Say it, log it on the bus, and publish the launcher's counters."""
        self.say(text, error=level == "error")
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
        """A ``kill`` fault: SIGKILL the named service, as a crash would, if the deployment
        allows it (``check_kill``, as ``ddvi fault`` checks it)."""
        p = self.services.get(target)
        try:
            check_kill(self.dep, target)
            why = "it is not running" if p is None or p.popen.poll() is not None else ""
        except DeploymentError as exc:
            why = str(exc)
        if why:
            self.event(bus, "warning", f"fault kill {target}: ignored ({why})", t)
            return
        p.popen.kill()
        self.kills += 1
        self.event(bus, "warning", f"fault kill {target}: killed (SIGKILL) at t = {t:.0f} s", t)

    def hung(self, name: str, bus: Bus, t: float) -> int:
        """``name`` gave up a lock-step wait (run.hang_timeout): end the run, with its word on
        which part is hung (docs/health.md), said and logged for the report."""
        log = self.services.out / "logs" / f"{name}.log"
        said = [line for line in lifecycle.last_lines(log) if " is hung" in line]
        why = said[-1].split(" ERROR ", 1)[-1] if said else f"see {log}"
        text = f"{why}; {name} gave up waiting (run.hang_timeout): the run is ended"
        self.event(bus, "error", text, t)
        return lifecycle.EXIT_FAILED

    def silent_environment(self, bus: Bus, t: float, silence: float) -> int:
        """The environment's process lives but no clock came for ``silence`` s: the time
        master is frozen (no wait of its own lasts that long); end the run naming it."""
        text = f"lock-step stalled at t = {t:.0f} s: no clock from environment in {silence:.0f} s"
        text += f" (run.hang_timeout + {CLOCK_MARGIN:g} s): environment is hung; the run is ended"
        self.event(bus, "error", text, t)
        return lifecycle.EXIT_FAILED
