"""Navigation service, one per deputy: what an on-board relative navigation filter publishes.

Inputs:  truth/chief, truth/<deputy> (truth); clock; fault/bias (fault: target = deputy,
         params px py pz (m) vx vy vz (m/s), the new bias), fault/outage (params
         duration_orbits) and the deployment's scheduled [[fault]] biases and outages.
Outputs: nav/<deputy>/state (nav): the deputy's state relative to the chief,
         [x, y, z, xdot, ydot, zdot], in the frame navigation.frame names (ddvi_core.relnav:
         against the chief's path by default, or curvilinear Hill), at the configured rate:
         the relative navigation filter's estimate (navigation.filter = "kalman",
         ddvi_core.navfilter: HCW kinematics, no drag model) of the measurement, truth with
         white noise and bias, or the measurement itself ("none"); with its covariance;
         stats/nav-<deputy>.
"""

from __future__ import annotations

import sys

import numpy as np

from services.config import DeploymentError, Fault, check_fault
from services.flight.host import Listen, ServiceHost
from services.flight.relative_navigation import RelativeNavigation
from services.flight.runtime import ServiceContext, run_service
from services.flight.streams import SamplePairs
from services.interface import CLOCK, Message, fault_topic, nav_state_topic, truth_topic
from services.model import on_grid, orbit_period

BIAS_KEYS = ("px", "py", "pz", "vx", "vy", "vz")
"""The params of a bias fault: position (m) and velocity (m/s) bias, in navigation's frame."""


def main(ctx: ServiceContext) -> int:
    return ServiceHost(ctx).react(NavigationService(ctx))


class NavigationService:
    """Pairs the chief's and the deputy's truth by time and publishes, on the navigation grid,
    the deputy's relative state (``RelativeNavigation``: the filter's estimate of the
    measurement, truth with the bias in force and white noise, and its covariance).

    Parameters
    ----------
    ctx : the service's context; its name is ``nav-<deputy>``.
    """

    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.sc = sc = ctx.name.removeprefix("nav-")
        self.deputy = ctx.deployment.deputy_named(sc)
        self.navigation = RelativeNavigation(ctx.deployment, self.deputy)
        self.period = self.deputy.navigation.period
        # only the two craft it needs (a swarm's other deputies would multiply the traffic); the
        # two subscriptions interleave arbitrarily, and samples are paired by time
        self.inputs = (
            Listen(truth_topic("chief"), "truth"),
            Listen(truth_topic(sc), "truth"),
            Listen(CLOCK, "clock"),
            Listen(fault_topic("bias"), "fault"),
            Listen(fault_topic("outage"), "fault"),
        )
        # restarted into the running mission, it is alive once it publishes again
        self.ready_at_start = not ctx.joining
        if ctx.joining:
            ctx.log("warning", "restarted into the running mission: publishing from the next truth")
        self.pairs = SamplePairs(("chief", sc))
        self.counters = {
            "published": 0,
            "unmatched": 0,
            "bias_faults": 0,
            "bad_faults": 0,
            "outages": 0,
            "outage_samples": 0,
        }
        self.last_t = -1.0  # last published sample
        self.last_pair = -1.0  # last sample for which both truths arrived

    # -- as the service host runs it (services.flight.host.Reactive) ---------------------------

    # the environment's step arrives at once: what one pass over the inbox publishes leaves
    # as one zenoh sample per topic, so a step's samples leave together
    batched = True

    def poll(self) -> float:
        return 0.5

    def start(self) -> None:
        pass  # nothing to publish before the first truth

    def settle(self, final_t: float | None) -> None:
        pass  # it publishes as the truths arrive

    def done(self, final_t: float | None) -> bool:
        return final_t is not None and self.last_pair >= final_t - 1e-6

    def finish(self) -> tuple[float, dict[str, int]]:
        return self.last_t, self.counters

    def take(self, topic: str, msg: Message) -> None:
        if msg.schema == "clock":
            return  # the host keeps the final clock
        if msg.schema == "fault":
            self.on_fault(topic.removeprefix("fault/"), msg)
        elif msg.body["sc"] in ("chief", self.sc):
            self.on_truth(msg)

    def on_fault(self, kind: str, msg: Message) -> None:
        """``fault/bias`` or ``fault/outage`` (``kind``: its topic's, not its body's word) from
        the ground: checked as a [[fault]] of the deployment would be, and queued if it is
        this deputy's."""
        if msg.body["target"] != self.sc:
            return  # another deputy's navigation
        p = msg.body["params"]
        try:
            if kind == "outage":
                fault = Fault(kind="outage", deputy=self.sc, duration_orbits=p["duration_orbits"])
            else:
                values = [p.get(k, 0.0) for k in BIAS_KEYS]
                fault = Fault(
                    kind="bias", deputy=self.sc, position_bias=values[:3], velocity_bias=values[3:]
                )
            check_fault(self.ctx.deployment, kind, fault)
        except (DeploymentError, KeyError, TypeError) as exc:
            self.counters["bad_faults"] += 1
            expected = "params.duration_orbits" if kind == "outage" else f"params {BIAS_KEYS}"
            said = f"fault {kind} {self.sc}: refused ({exc}; {expected}, got {p})"
            self.ctx.log("warning", said, msg.t)
            return
        if kind == "outage":
            orbits = float(fault.duration_orbits)
            self.navigation.outage_from_ground(orbits * orbit_period(self.ctx.deployment), msg.src)
        else:
            bias = np.array(fault.position_bias + fault.velocity_bias, dtype=float)
            self.navigation.bias_from_ground(bias, msg.src)

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
        """The navigation sample at t from the chief's and the deputy's inertial states (6,)."""
        sc = self.sc
        sample = self.navigation.measure(t, chief, deputy)
        for fault in sample.biased:
            self.counters["bias_faults"] += 1
            said = f"fault bias {sc}: navigation bias now {fault.value.tolist()} from t = {t:.0f} s"
            self.ctx.log("warning", f"{said} ({fault.origin})", t)
        if sample.outage is not None:
            self.counters["outages"] += 1
            until = sample.outage.value
            said = f"fault outage {sc}: no measurement from t = {t:.0f} s to {until:.0f} s"
            self.ctx.log("warning", f"{said}, the filter propagates ({sample.outage.origin})", t)
        self.counters["outage_samples"] += not sample.valid
        body = {
            "sc": sc,
            "x_hill": sample.x,
            "z_hill": sample.z,
            "cov": sample.cov,
            "altitude": sample.altitude,
            "valid": sample.valid,
        }
        self.ctx.bus.publish(nav_state_topic(sc), "nav", body, t)
        self.counters["published"] += 1
        self.last_t = t
        self.ctx.ready()  # a restarted service is alive once it publishes again


if __name__ == "__main__":
    sys.exit(run_service(main, "nav"))
