"""The one-process executor: the mission stepped synchronously in one process, with no bus,
over the components the services run (``EnvironmentModel``, ``RelativeNavigation``,
``ControlLoop``), each message between them passed through the link its subscriber's bus would
give it (``services.bus.links.LinkModel``, seeded as the bus seeds it: ``link_seed``).  It
flies what ``ddvi run`` flies in lock-step, the scheduled faults (panel, bias, outage) and the
deployment's [[link]]s included, so a sweep or a campaign in process measures the same system;
it is also the baseline the distributed run's cost is measured against (benchmarks).

Order of one flight-software step at t_k, as lock-step orders the services: each controller
takes what its links deliver by t_k and flies its steps up to t_k; the environment takes the
commands its links deliver by t_k and propagates to t_k + fsw; each sample on the way goes to
navigation, and navigation's and the exostate's messages into the controllers' links.  Not
modelled: what only a wall clock decides (real-time mode, a service that dies or goes away, a
flood past the rate budget) and the ground's run-time faults.  A link with jitter or reordering
delivers a message at a time that, in the services, depends on which process runs first: there
the two executors agree statistically, not sample for sample.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from services.bus.links import LinkModel, link_seed
from services.config import Deployment, DeploymentError
from services.flight.control import Controller
from services.flight.control_loop import (
    ControlLoop,
    Said,
    Step,
    input_delay,
    newest_sample_time,
)
from services.flight.environment_model import EnvironmentModel
from services.flight.relative_navigation import RelativeNavigation
from services.interface import EXOSTATE, command_topic, nav_state_topic
from services.interface.links import select_rule
from services.model import IN_PLANE, duration, on_grid, open_truth


class Link:
    """What one subscription of ``subscriber`` (its topic pattern ``subscription``) receives
    from ``publisher`` on ``topic``: the deployment's first matching [[link]] rule applied by
    the model the subscriber's bus would make for it, or a perfect link."""

    def __init__(
        self, dep: Deployment, subscriber: str, subscription: str, publisher: str, topic: str
    ) -> None:
        rules = dep.links_for(subscriber)
        i = select_rule(rules, publisher, topic)
        self.model = (
            None
            if i is None
            else LinkModel(
                rules[i].spec, link_seed(dep.run.seed, subscriber, subscription, i, publisher)
            )
        )
        self.out: list[Any] = []  # delivered, not yet taken
        self.sent = 0  # identifies a message: a duplicate is taken once, as the bus's window does
        self.taken: set[int] = set()

    @property
    def counters(self) -> dict[str, int]:
        """What the link did: dropped, duplicated, reordered, delayed (``LinkModel``)."""
        if self.model is None:
            return {"dropped": 0, "duplicated": 0, "reordered": 0, "delayed": 0}
        return self.model.counters

    def send(self, item: Any, t: float) -> None:
        """``item`` published at simulation time t."""
        self.sent += 1
        if self.model is None:
            self.out.append((self.sent, item))
        else:
            self.out += self.model.offer((self.sent, item), t, sent=t)

    def receive(self, now: float) -> list[Any]:
        """What the link has delivered by ``now``, each message once, in delivery order."""
        if self.model is not None:
            self.out += self.model.release(now)
        out, self.out = self.out, []
        fresh = []
        for n, item in out:
            if n not in self.taken:
                self.taken.add(n)
                fresh.append(item)
        return fresh


class DeputyFlight:
    """One deputy's navigation and controller, and the links between them and the
    environment, as its services and their buses would have them."""

    def __init__(self, dep: Deployment, name: str) -> None:
        sc, ctrl_name = name, f"ctrl-{name}"
        self.name = sc
        self.navigation = RelativeNavigation(dep, dep.deputy_named(sc))
        self.controller = Controller(dep, sc)
        self.loop = ControlLoop(self.controller, dep.run, input_delay(dep, sc))
        nav_topic = nav_state_topic(sc)
        self.nav_link = Link(dep, ctrl_name, nav_topic, f"nav-{sc}", nav_topic)
        self.exo_link = Link(dep, ctrl_name, EXOSTATE, "environment", EXOSTATE)
        self.cmd_link = Link(dep, "environment", command_topic("*"), ctrl_name, command_topic(sc))
        self.cmd_delay = dep.link_latency(ctrl_name, "environment", command_topic(sc))
        series = ("t", "x", "z", "estimate", "cov", "valid", "step_t", "sigma", "safe")
        self.rec: dict[str, Any] = {k: [] for k in series} | {"log": [], "said": []}

    def fly(self, t_k: float, final_t: float | None) -> None:
        """Take what the links delivered by t_k and fly the steps up to t_k."""
        for t, x, altitude, z, valid in self.nav_link.receive(t_k):
            self.loop.nav(t, x, altitude, z, valid)
        for t, v in self.exo_link.receive(t_k):
            self.loop.exo(t, v)
        for item in self.loop.advance(lambda T: t_k + 1e-6 >= T, final_t):
            if isinstance(item, Said):
                self.rec["said"].append(item.text)
            else:
                self.command(item, final_t)

    def command(self, step: Step, final_t: float | None) -> None:
        """A step's command, recorded and sent to the environment; not the final step's,
        which comes after the environment's last step: nothing takes it."""
        if step.learn_log is not None:
            self.rec["log"].append(step.learn_log)
        self.rec["step_t"].append(step.T)
        self.rec["sigma"].append(step.sigma)
        self.rec["safe"].append(step.safe)
        if final_t is None or final_t - 1e-6 > step.T:
            self.cmd_link.send((step.T, step.sigma), step.T)

    def measure(self, t: float, chief: np.ndarray, deputy: np.ndarray, v: np.ndarray) -> None:
        """The sample at t: the exostate to the controller, and on navigation's grid its
        measurement."""
        self.exo_link.send((t, v), t)
        if not on_grid(t, self.navigation.period):
            return
        nav = self.navigation.measure(t, chief, deputy)
        plane = list(IN_PLANE)  # the controller's state: x, y and their rates
        self.nav_link.send((t, nav.x[plane], nav.altitude, nav.z[plane], nav.valid), t)
        rec = self.rec
        for key, value in (
            ("t", t),
            ("x", nav.truth),
            ("z", nav.z),
            ("estimate", nav.x),
            ("cov", nav.cov),
            ("valid", nav.valid),
        ):
            rec[key].append(value)

    def record(self) -> dict[str, Any]:
        """The deputy's record (see ``run_in_process``)."""
        rec = {k: np.array(v) for k, v in self.rec.items() if k not in ("log", "said")}
        rec["log"], rec["said"] = self.rec["log"], self.rec["said"]
        # the command issued for the newest step at or before each sample (0 before any)
        k = np.searchsorted(rec["step_t"], rec["t"] + 1e-6, side="right") - 1
        rec["u"] = np.zeros(len(rec["t"]))
        if len(rec["sigma"]):
            rec["u"][k >= 0] = rec["sigma"][k[k >= 0], 2]
        rec["controller"] = self.controller
        rec["counters"] = dict(self.loop.counters)
        return rec


def run_in_process(dep: Deployment, timing: dict[str, float] | None = None) -> dict[str, dict]:
    """Run ``dep`` to the end; per deputy: at its navigation samples, times ``t`` (K,), the
    truth ``x`` (K, 6) in navigation's frame, the measurement ``z`` (K, 6), the estimate
    ``estimate`` (K, 6) and its covariance ``cov`` (K, 6, 6), ``valid`` (K,) (False in an
    outage) and ``u`` (K,), the sigma3 of the newest command issued by then; every step's
    time ``step_t`` (S,), command ``sigma`` (S, 3) and whether it flew ``safe`` (S,); at
    every truth sample, ``truth_t`` (M,) and the chief's and the deputy's inertial states
    ``chief_rv`` and ``rv`` (M, 6); the ``controller`` object (final gains, phase), its
    learning ``log`` lines, what its loop ``said`` and its ``counters``; what its input
    ``links`` dropped and delayed; the ``environment``'s counters (with what its command
    links dropped and delayed).

    ``timing``, if given, gets the wall seconds of each service's share: ``environment``
    (truth, exostate), ``nav-<deputy>`` (states, bias, noise, filter), ``ctrl-<deputy>``
    (controller and learning), and ``steps``, the flight-software steps.  Raises
    ``services.model.ReentryError`` if a craft re-enters, and DeploymentError for a deputy flown
    from ROS 2 (its node is no component of this process)."""
    if flown := [d.name for d in dep.deputy if d.controller == "ros2"]:
        raise DeploymentError(
            f"deputies {flown} are flown from ROS 2 (controller = 'ros2'): the one-process "
            "executor has no ROS 2 node; fly them with ddvi run"
        )
    mission = LockStepMission(dep)
    truth = open_truth(dep)
    try:
        mission.fly(EnvironmentModel(dep, truth))
    finally:
        truth.close()
    if timing is not None:
        timing.update(mission.spent, steps=mission.env.counters["steps"])
    return mission.records()


class LockStepMission:
    """The mission's flight-software steps in the order lock-step gives the services, and
    what each service's share of the work cost (``spent``, wall seconds)."""

    def __init__(self, dep: Deployment) -> None:
        self.fsw, self.t_end = dep.run.fsw_period, duration(dep)
        self.flights = [DeputyFlight(dep, d.name) for d in dep.deputy]
        services = [
            "environment",
            *(f"{p}-{f.name}" for f in self.flights for p in ("nav", "ctrl")),
        ]
        self.spent = dict.fromkeys(services, 0.0)
        self.truth_t: list[float] = []
        self.states: list[np.ndarray] = []  # every craft's inertial state (1 + N, 6) a sample

    def fly(self, env: EnvironmentModel) -> None:
        """Fly ``env`` and the deputies to the end of the mission."""
        self.env = env
        self.publish(0.0, env.truth.state)
        t_k = 0.0
        while t_k < self.t_end - 1e-6:
            self.fly_controllers(t_k, None)
            t0 = time.perf_counter()
            self.deliver_commands(t_k)
            samples, traj, _ = env.step(t_k)
            self.spent["environment"] += time.perf_counter() - t0
            for k, t in enumerate(samples):
                self.publish(float(t), traj[k])
            t_k += self.fsw
        self.fly_controllers(t_k, t_k)  # the final clock: the last steps, on what came by then

    def publish(self, t: float, X: np.ndarray) -> None:
        """The sample at t of every craft (X (1 + N, 6)): the exostate, and each deputy's
        measurement."""
        t0 = time.perf_counter()
        v, _ = self.env.exostate(t)
        self.spent["environment"] += time.perf_counter() - t0
        self.truth_t.append(t)
        self.states.append(X)
        for i, flight in enumerate(self.flights):
            t0 = time.perf_counter()
            flight.measure(t, X[0], X[i + 1], v)
            self.spent[f"nav-{flight.name}"] += time.perf_counter() - t0

    def fly_controllers(self, t_k: float, final_t: float | None) -> None:
        """Each controller's steps up to t_k, on what its links delivered by then."""
        for flight in self.flights:
            t0 = time.perf_counter()
            flight.fly(t_k, final_t)
            self.spent[f"ctrl-{flight.name}"] += time.perf_counter() - t0

    def deliver_commands(self, t_k: float) -> None:
        """The commands the environment's links delivered by t_k, put in force, and the ones
        its step waited for and never came counted missing."""
        commands = self.env.commands
        expected = {f.name: newest_sample_time(t_k, f.cmd_delay, self.fsw) for f in self.flights}
        for flight in self.flights:
            for for_t, sigma in flight.cmd_link.receive(t_k):
                commands.deliver(flight.name, for_t, sigma, t_k, expected[flight.name])
        commands.count_missing(expected)

    def records(self) -> dict[str, dict]:
        """Each deputy's record (see ``run_in_process``)."""
        X = np.array(self.states)
        environment = dict(self.env.counters)
        for key in ("dropped", "delayed"):  # its links' from every controller, as its bus counts
            environment[key] = sum(f.cmd_link.counters[key] for f in self.flights)
        out: dict[str, dict] = {}
        for i, flight in enumerate(self.flights):
            rec = flight.record()
            rec.update(truth_t=np.array(self.truth_t), chief_rv=X[:, 0], rv=X[:, i + 1])
            rec["links"] = {
                key: flight.nav_link.counters[key] + flight.exo_link.counters[key]
                for key in ("dropped", "delayed")
            }
            rec["environment"] = environment
            out[flight.name] = rec
        return out
