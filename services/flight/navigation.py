"""Navigation service, one per deputy: what an on-board relative navigation filter publishes.

Inputs:  truth/chief, truth/<deputy> (truth); clock; fault/bias (fault: target = deputy,
         params px py pz (m) vx vy vz (m/s), the new bias) and the deployment's scheduled
         [[fault]] biases.
Outputs: nav/<deputy>/state (nav): the deputy's state relative to the chief,
         [x, y, z, xdot, ydot, zdot], in the frame navigation.frame names (ddvi_core.relnav:
         against the chief's path by default, or curvilinear Hill), at the configured rate:
         the relative navigation filter's estimate (navigation.filter = "kalman",
         ddvi_core.navfilter: HCW kinematics, no drag model) of the measurement, truth with
         white noise and bias, or the measurement itself ("none"); with its covariance;
         stats/nav-<deputy>.
"""

from __future__ import annotations

import queue
import sys
import zlib

import numpy as np

from ddvi_core.constants import R_EARTH
from ddvi_core.navfilter import RelativeNavFilter
from services.bus import queue_handler
from services.config import Deployment, DeploymentError, Deputy, Fault, check_fault
from services.flight.runtime import ServiceContext, run_service
from services.flight.streams import FaultQueue, FinalClock, SamplePairs
from services.interface import CLOCK, Message, fault_topic, nav_state_topic, truth_topic
from services.model import mean_motion, navigation_state, on_grid, orbit_period

BIAS_KEYS = ("px", "py", "pz", "vx", "vy", "vz")
"""The params of a bias fault: position (m) and velocity (m/s) bias, in navigation's frame."""


def noise_generator(dep: Deployment, deputy: Deputy) -> np.random.Generator:
    """The deputy's navigation noise draws: seeded by run.seed, navigation.seed and its name
    (its CRC-32: names of the same letters differ), so each deputy's noise is its own,
    whichever other deputies fly (and the one-process baseline draws what the navigation
    service does)."""
    name = zlib.crc32(deputy.name.encode())
    return np.random.default_rng([dep.run.seed, deputy.navigation.seed, name])


def navigation_filter(dep: Deployment, deputy: Deputy) -> RelativeNavFilter | None:
    """The deputy's relative navigation filter as its deployment sets it (HCW at the chief's
    mean motion, the measurement's sigmas, the unmodelled acceleration), or None for
    ``navigation.filter = "none"``."""
    nav = deputy.navigation
    if nav.filter == "none":
        return None
    sigma = [nav.position_noise] * 3 + [nav.velocity_noise] * 3
    return RelativeNavFilter(mean_motion(dep), sigma, nav.acceleration_noise, nav.period)


def main(ctx: ServiceContext) -> int:
    return NavigationService(ctx).run()


class NavigationService:
    """Pairs the chief's and the deputy's truth by time and publishes, on the navigation grid,
    the deputy's relative state: the filter's estimate of the measurement (truth with the bias
    in force and white noise) and its covariance.

    Parameters
    ----------
    ctx : the service's context; its name is ``nav-<deputy>``.
    """

    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.sc = sc = ctx.name.removeprefix("nav-")
        self.deputy = ctx.deployment.deputy_named(sc)
        cfg = self.deputy.navigation
        self.period = cfg.period
        self.rng = noise_generator(ctx.deployment, self.deputy)
        self.sigma = np.array([cfg.position_noise] * 3 + [cfg.velocity_noise] * 3)
        self.bias = np.array(cfg.position_bias + cfg.velocity_bias)
        self.filter = navigation_filter(ctx.deployment, self.deputy)  # None: publish z as is
        self.R = np.diag(self.sigma**2)  # the covariance published without a filter
        self.measured = np.zeros(6)  # the last measurement, before the filter
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        # only the two craft it needs (a swarm's other deputies would multiply the traffic); the
        # two subscriptions interleave arbitrarily, and samples are paired by time
        for craft in ("chief", sc):
            ctx.bus.subscribe(
                truth_topic(craft), queue_handler(self.inbox), expected_schema="truth"
            )
        ctx.bus.subscribe(CLOCK, queue_handler(self.inbox), expected_schema="clock")
        ctx.bus.subscribe(fault_topic("bias"), queue_handler(self.inbox), expected_schema="fault")
        # bias faults: the deployment's at their times, the ground's from the next sample on
        orbit = orbit_period(ctx.deployment)
        self.bias_faults: FaultQueue[np.ndarray] = FaultQueue(
            [
                (f.at_orbits * orbit, np.array(f.position_bias + f.velocity_bias))
                for f in ctx.deployment.fault
                if f.kind == "bias" and f.deputy == sc
            ]
        )
        if ctx.joining:
            ctx.log("warning", "restarted into the running mission: publishing from the next truth")
        else:
            ctx.ready()
        self.pairs = SamplePairs(("chief", sc))
        self.counters = {"published": 0, "unmatched": 0, "bias_faults": 0, "bad_faults": 0}
        self.final = FinalClock()
        self.last_t = -1.0  # last published sample
        self.last_pair = -1.0  # last sample for which both truths arrived

    def run(self) -> int:
        """Take messages until the final sample is paired or a stop is requested; returns 0."""
        while not self.ctx.stop.is_set():
            try:
                _, msg = self.inbox.get(timeout=0.5)
            except queue.Empty:
                if self.final.grace_over():
                    break  # the last truth never came (a lost message): nothing more will
                continue
            # what one pass over the queue publishes goes out as one zenoh sample per topic:
            # the environment's step arrives at once, so a step's samples leave together
            with self.ctx.bus.batch():
                while True:
                    self.handle(msg)
                    try:
                        _, msg = self.inbox.get_nowait()
                    except queue.Empty:
                        break
            if self.final.t is not None and self.last_pair >= self.final.t - 1e-6:
                break
        self.ctx.publish_stats(self.last_t, self.counters)
        return 0

    def handle(self, msg: Message) -> None:
        if msg.schema == "clock":
            self.final.on_clock(msg)
        elif msg.schema == "fault":
            self.on_fault(msg)
        elif msg.body["sc"] in ("chief", self.sc):
            self.on_truth(msg)

    def on_fault(self, msg: Message) -> None:
        """``fault/bias`` from the ground: queue the new bias if it is this deputy's."""
        if msg.body["target"] != self.sc:
            return  # another deputy's navigation
        p = msg.body["params"]
        values = [p.get(k, 0.0) for k in BIAS_KEYS]
        position, velocity = values[:3], values[3:]
        fault = Fault(kind="bias", deputy=self.sc, position_bias=position, velocity_bias=velocity)
        try:  # as a [[fault]] of the deployment: numbers in a navigation bias's range
            check_fault(self.ctx.deployment, "bias", fault)
        except DeploymentError as exc:
            self.counters["bad_faults"] += 1
            said = f"fault bias {self.sc}: refused ({exc}; params {BIAS_KEYS}, got {p})"
            self.ctx.log("warning", said, msg.t)
            return
        self.bias_faults.from_ground(np.array(values, dtype=float), msg.src)

    def on_truth(self, msg: Message) -> None:
        """One craft's truth: once both craft of its time are in, publish the sample if it is
        on the navigation grid and newer than the last one."""
        t = msg.t
        pair = self.pairs.add(t, msg.body["sc"], np.concatenate([msg.body["r_N"], msg.body["v_N"]]))
        if pair is not None:
            self.last_pair = max(self.last_pair, t)
            if on_grid(t, self.period) and t > self.last_t:
                self.publish(t, pair["chief"], pair[self.sc])
        # a half pair well behind the newest sample will never complete (a lost message);
        # the two subscriptions can drift apart by the steps the environment runs ahead
        # of a delayed control loop, so "well behind" is ten flight-software steps
        horizon = t - 10 * self.ctx.deployment.run.fsw_period
        self.counters["unmatched"] += len(self.pairs.forget_before(horizon))

    def publish(self, t: float, chief: np.ndarray, deputy: np.ndarray) -> None:
        """The navigation sample at t from the chief's and the deputy's inertial states (6,):
        the measurement (the bias in force from t on, white noise) through the filter."""
        sc = self.sc
        for fault in self.bias_faults.pop_due(t):
            self.bias = fault.value
            self.counters["bias_faults"] += 1
            self.ctx.log("warning", f"fault bias {sc}: navigation bias now {self.bias.tolist()} "
                         f"from t = {t:.0f} s ({fault.origin})", t)  # fmt: skip
        x = navigation_state(self.ctx.deployment, self.deputy, chief, deputy) + self.bias
        if self.sigma.any():
            x = x + self.rng.normal(0.0, 1.0, 6) * self.sigma
        self.measured, cov = x, self.R
        if self.filter is not None:
            x, cov = self.filter.update(t, x)
        altitude = float(np.linalg.norm(deputy[:3])) - R_EARTH
        body = {"sc": sc, "x_hill": x, "z_hill": self.measured, "cov": cov, "altitude": altitude,
                "valid": True}  # fmt: skip
        self.ctx.bus.publish(nav_state_topic(sc), "nav", body, t)
        self.counters["published"] += 1
        self.last_t = t
        self.ctx.ready()  # a restarted service is alive once it publishes again


if __name__ == "__main__":
    sys.exit(run_service(main, "nav"))
