"""Controller service, one per deputy: the flight software under test.

Inputs:  nav/<deputy>/state (nav), exo/state (exo).
Outputs: cmd/<deputy>/att (cmd) every flight-software step; ctrl/<deputy>/gains (gains), beaconed
         every step while learning and published whenever the gains change; ctrl/<deputy>/status
         (status); stats/ctrl-<deputy>.

Modes: ``lqr`` flies u = -K x + L v with gains from the nominal linear model.  ``ddvi`` flies
u = -K0 x + eta(t) (K0 need not stabilise; eta a multi-sine inside the attitude limit), feeds
every navigation sample to ddvi_core's IntervalCollector, runs data-driven value iteration at
the configured time and switches to the learned K, L.  Every command goes through
ddvi_core.models.drag_allocation, scheduled on the deputy's altitude (its nav message), which
makes the facet's drag linear in u and the same at every altitude.  The learner gets
what a flight computer knows: Q, R, the output map and reference (C, F), the exosystem E and
the orbit rate; never A, B or D.  Control input u = sigma3, the relative MRP about the orbit
normal; sigma1 = sigma2 = 0.
"""

from __future__ import annotations

import math
import queue
import sys
import time
from dataclasses import dataclass

import numpy as np

from ddvi_core.constants import R_EARTH
from ddvi_core.learning import IntervalCollector, LearningError, learn_from_data
from ddvi_core.models import drag_allocation
from ddvi_core.simulate import Exploration
from ddvi_core.value_iteration import BoundSchedule, StepSequence
from services.bus import queue_handler
from services.deployment import Deployment
from services.mission import (
    IN_PLANE,
    lqr_gains,
    mean_motion,
    nominal_problem,
    on_grid,
    orbit_period,
)
from services.service import ServiceContext, run_service


@dataclass
class SampleOutcome:
    """What one navigation sample did: a flight-software step (a new command in
    ``Controller.u``), a learning attempt (its log line), a sample the collector refused."""

    fsw: bool
    learn_log: str | None = None
    rejected: str | None = None


class Controller:
    """The control law and the learner's state; no I/O (the service loop does that)."""

    def __init__(self, dep: Deployment, sc: str) -> None:
        self.dep, self.sc = dep, sc
        self.deputy = dep.deputy_named(sc)
        self.problem = nominal_problem(dep, self.deputy)  # Q, R, C, E, F used by the learner
        self.n_rate = mean_motion(dep)
        self.fsw = dep.run.fsw_period
        self.limit = self.deputy.attitude_limit
        lrn = self.deputy.learning
        self.mode = self.deputy.controller
        if self.mode == "lqr":
            self.K, self.L = lqr_gains(dep, self.deputy)
            self.phase, self.source = "lqr", "lqr"
        else:
            self.K = np.array([lrn.K0], dtype=float)
            self.L = np.zeros((1, self.problem.q))
            self.phase, self.source = "exploring", "initial"
            freqs = tuple(lrn.exploration_frequencies) or tuple(
                np.geomspace(0.3 * self.n_rate, 30 * self.n_rate, 6)
            )
            self.exploration = Exploration(lrn.exploration_amplitude, freqs, lrn.seed)
            self.collector = IntervalCollector(
                4, 1, self.problem.q, lrn.interval, max_gap=3 * self.deputy.navigation.period
            )
            self.learn_at = lrn.learn_at_orbits * orbit_period(dep)
            self.next_attempt = self.learn_at
        self.normal_angle = math.radians(dep.spacecraft.normal_angle)
        self.h_model = dep.chief.a - R_EARTH
        self.scale_height = dep.atmosphere.scale_height
        self.u = 0.0  # the attitude command in force, sigma3
        self.u_applied = 0.0  # the linear-model input it realises (drag_allocation)
        self.iteration = 0
        self.converged = self.mode == "lqr"
        self.learn_info: dict = {}
        self.rank = self.rank_needed = 0

    def density_ratio(self, altitude: float) -> float:
        """rho(h) / rho(h_0) of the nominal exponential atmosphere: how much more drag the
        facet makes at altitude h (m) than the linear model's reference altitude h_0 (the
        chief's initial orbit).  The pair decays about 1.4 km in 15 orbits, and the drag, hence
        B, rises about 19% with it."""
        return math.exp(-(altitude - self.h_model) / self.scale_height)

    def command(self, t: float, x: np.ndarray, v: np.ndarray, altitude: float) -> float:
        """The attitude command sigma3 for a flight-software step at t, from state x (4,) and
        exostate v; ``u_applied`` is the linear-model input it realises (what the learner
        records)."""
        u = float((-self.K @ x + self.L @ v)[0])
        if self.phase == "exploring":
            u += float(self.exploration(t, 1)[0])
        # schedule on the measured altitude: the drag the linear model's u stands for is the
        # same at every altitude, so the learner sees one B (and the LQR its design B)
        ratio = self.density_ratio(altitude)
        self.u, u_area = drag_allocation(u / ratio, self.normal_angle, self.limit)
        self.u_applied = u_area * ratio
        return self.u

    def on_sample(self, t: float, x: np.ndarray, v: np.ndarray, altitude: float) -> SampleOutcome:
        """One navigation sample, in time order: on a flight-software step, learn if it is
        time to, then compute the command (``self.u``); while exploring, feed the collector
        with the input in force from t on.  The service publishes; the in-process baseline
        does not: both run exactly this."""
        outcome = SampleOutcome(fsw=on_grid(t, self.fsw))
        if outcome.fsw:
            if self.phase == "exploring" and t >= self.next_attempt - 1e-6:
                outcome.learn_log = self.learn(t)
            self.command(t, x, v, altitude)
        if self.phase == "exploring":
            try:
                self.collector.add(t, x, [self.u_applied], v)
            except LearningError as exc:
                outcome.rejected = f"sample at t = {t} rejected: {exc}"
        return outcome

    def learn(self, t: float) -> str:
        """Run data-driven value iteration on the data so far; switch gains on success."""
        lrn, pr = self.deputy.learning, self.problem
        n = self.n_rate
        t0 = time.perf_counter()
        try:
            data = self.collector.data()
            if lrn.window_orbits > 0:
                data = data.since(t - lrn.window_orbits * orbit_period(self.dep))
            r = learn_from_data(
                data,
                pr.Q,
                pr.R,
                time_unit=n,
                C=pr.C,
                E=pr.E,
                F=pr.F,
                steps=StepSequence(lrn.step, lrn.step_size),
                bounds=BoundSchedule(lrn.bounds, lrn.bound_base),
                tol=lrn.tol,
                max_iterations=lrn.max_iterations,
                state_scale=[1.0, 1.0, n, n],
                translation=[0.0, 1.0, 0.0, 0.0] if lrn.along_track_reference else None,
            )
        except LearningError as exc:
            self.next_attempt = t + lrn.retry_orbits * orbit_period(self.dep)
            return f"learning at t = {t:.0f} s failed, exploring on: {exc}"
        self.rank, self.rank_needed = r.rank, r.rank_needed
        if not r.converged:
            self.next_attempt = t + lrn.retry_orbits * orbit_period(self.dep)
            return f"learning at t = {t:.0f} s did not converge ({r.message}), exploring on"
        self.K, self.L = r.K, r.L
        self.phase, self.source = "learned", "ddvi"
        self.iteration, self.converged = r.iterations, True
        self.learn_info = {
            "wall_s": time.perf_counter() - t0,
            "condition": r.condition,
            "residual": r.residual,
            "intervals": r.intervals,
        }
        return (
            f"learned at t = {t:.0f} s from {r.intervals} intervals in {r.iterations} "
            f"iterations ({self.learn_info['wall_s']:.2f} s): K = {r.K.ravel().tolist()}, "
            f"L = {r.L.ravel().tolist()}"
        )


def main(ctx: ServiceContext) -> int:
    sc = ctx.name.removeprefix("ctrl-")
    ctrl = Controller(ctx.deployment, sc)
    run = ctx.deployment.run
    inbox: queue.Queue = queue.Queue()
    ctx.bus.subscribe(f"nav/{sc}/state", queue_handler(inbox), expected_schema="nav")
    ctx.bus.subscribe("exo/state", queue_handler(inbox), expected_schema="exo")
    ctx.bus.subscribe("clock", queue_handler(inbox), expected_schema="clock")
    ctx.ready()
    exo: dict[float, np.ndarray] = {}
    navs: dict[float, tuple[np.ndarray, float]] = {}  # in-plane state, altitude
    counters = {"commands": 0, "samples_rejected": 0, "learn_attempts": 0}
    steps = 0
    final_t: float | None = None
    last_t = -1.0

    def publish_gains(t: float) -> None:
        ctx.bus.publish(
            f"ctrl/{sc}/gains",
            "gains",
            {
                "sc": sc,
                "K": ctrl.K,
                "L": ctrl.L,
                "source": ctrl.source,
                "iteration": ctrl.iteration,
                "converged": ctrl.converged,
            },
            t,
        )

    def publish_status(t: float) -> None:
        c = ctrl.collector if ctrl.mode == "ddvi" else None
        ctx.bus.publish(
            f"ctrl/{sc}/status",
            "status",
            {
                "sc": sc,
                "mode": ctrl.mode,
                "phase": ctrl.phase,
                "samples": c.samples if c else 0,
                "intervals": c.intervals if c else 0,
                "rank": ctrl.rank,
                "rank_needed": ctrl.rank_needed,
                "counters": counters,
            },
            t,
        )

    publish_gains(0.0)
    while not ctx.stop.is_set():
        try:
            _, msg = inbox.get(timeout=0.5)
        except queue.Empty:
            continue
        if msg.schema == "clock":
            if msg.body["final"]:
                final_t = msg.t
        elif msg.schema == "exo":
            exo[msg.t] = msg.body["v"]
        else:
            navs[msg.t] = (msg.body["x_hill"][list(IN_PLANE)], msg.body["altitude"])
        # act on every navigation sample whose exostate has arrived, in time order
        for t in sorted(t for t in navs if t in exo):
            (x, altitude), v = navs.pop(t), exo.pop(t)
            if t <= last_t:
                counters["samples_rejected"] += 1  # stale or replayed
                continue
            last_t = t
            outcome = ctrl.on_sample(t, x, v, altitude)
            if outcome.learn_log is not None:
                counters["learn_attempts"] += 1
                ctx.log("info", outcome.learn_log, t)
                publish_gains(t)
            if outcome.fsw:
                u = ctrl.u
                ctx.bus.publish(
                    f"cmd/{sc}/att", "cmd", {"sc": sc, "sigma": [0.0, 0.0, u], "for_t": t}, t
                )
                counters["commands"] += 1
                steps += 1
                if ctrl.phase == "exploring":
                    publish_gains(t)  # beaconed during learning
                if steps % run.status_every == 0:
                    publish_status(t)
                    ctx.publish_stats(t, counters)
            if outcome.rejected is not None:
                counters["samples_rejected"] += 1
                ctx.log("warning", outcome.rejected, t)
        # forget exostates that no navigation sample will claim
        for t in [t for t in exo if t < last_t]:
            del exo[t]
        if final_t is not None and last_t >= final_t - 1e-6:
            break
    publish_gains(last_t)
    publish_status(last_t)
    ctx.publish_stats(last_t, counters)
    return 0


if __name__ == "__main__":
    sys.exit(run_service(main, "ctrl"))
