"""Navigation service, one per deputy: what an on-board relative navigation filter publishes.

Inputs:  truth/chief, truth/<deputy> (truth); clock; fault/bias (fault: target = deputy,
         params px py pz (m) vx vy vz (m/s), the new bias) and the deployment's scheduled
         [[fault]] biases.
Outputs: nav/<deputy>/state (nav): the deputy's state relative to the chief,
         [x, y, z, xdot, ydot, zdot], in the frame navigation.frame names (ddvi_core.relnav:
         against the chief's path by default, or curvilinear Hill), at the configured rate,
         with white noise and bias;
         stats/nav-<deputy>.
"""

from __future__ import annotations

import math
import queue
import sys
import time

import numpy as np

from ddvi_core.constants import R_EARTH
from services.bus import queue_handler
from services.flight.runtime import END_GRACE, ServiceContext, run_service
from services.interface import Message
from services.model import navigation_state, on_grid, orbit_period


def main(ctx: ServiceContext) -> int:
    sc = ctx.name.removeprefix("nav-")
    deputy = ctx.deployment.deputy_named(sc)
    cfg = deputy.navigation
    rng = np.random.default_rng([ctx.deployment.run.seed, cfg.seed, sum(map(ord, sc))])
    sigma = np.array([cfg.position_noise] * 3 + [cfg.velocity_noise] * 3)
    bias = np.array(cfg.position_bias + cfg.velocity_bias)
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    # only the two craft it needs (a swarm's other deputies would multiply the traffic); the
    # two subscriptions interleave arbitrarily, and samples are paired by time below
    for craft in ("chief", sc):
        ctx.bus.subscribe(f"truth/{craft}", queue_handler(inbox), expected_schema="truth")
    ctx.bus.subscribe("clock", queue_handler(inbox), expected_schema="clock")
    ctx.bus.subscribe("fault/bias", queue_handler(inbox), expected_schema="fault")
    # bias faults: the deployment's at their times, the ground's from the next sample on
    orbit = orbit_period(ctx.deployment)
    bias_faults = [
        (f.at_orbits * orbit, np.array(f.position_bias + f.velocity_bias), "scheduled")
        for f in ctx.deployment.fault
        if f.kind == "bias" and f.deputy == sc
    ]
    if ctx.joining:
        ctx.log("warning", "restarted into the running mission: publishing from the next truth")
    else:
        ctx.ready()
    pending: dict[float, dict[str, np.ndarray]] = {}
    counters = {"published": 0, "unmatched": 0, "bias_faults": 0, "bad_faults": 0}
    final_t: float | None = None
    final_seen = 0.0  # wall time the final clock arrived
    last_t = -1.0  # last published sample
    last_pair = -1.0  # last sample for which both truths arrived

    def handle(msg: Message) -> None:
        nonlocal final_t, final_seen, last_t, last_pair, bias
        if msg.schema == "clock":
            if msg.body["final"]:
                final_t, final_seen = msg.t, time.monotonic()
        elif msg.schema == "fault":
            if msg.body["target"] != sc:
                return  # another deputy's navigation
            p = msg.body["params"]
            keys = ("px", "py", "pz", "vx", "vy", "vz")
            values = [p.get(k, 0.0) for k in keys]
            if not all(isinstance(v, float | int) and math.isfinite(v) for v in values):
                counters["bad_faults"] += 1
                ctx.log("warning", f"fault bias {sc}: refused (params {keys} must be finite "
                        f"numbers; got {p})", msg.t)  # fmt: skip
                return
            bias_faults.append((-math.inf, np.array(values, dtype=float), f"from {msg.src}"))
        elif msg.body["sc"] in ("chief", sc):
            slot = pending.setdefault(msg.t, {})
            slot[msg.body["sc"]] = np.concatenate([msg.body["r_N"], msg.body["v_N"]])
            if "chief" in slot and sc in slot:
                del pending[msg.t]
                last_pair = max(last_pair, msg.t)
                if on_grid(msg.t, cfg.period) and msg.t > last_t:
                    for fault in [f for f in bias_faults if f[0] <= msg.t + 1e-6]:
                        bias_faults.remove(fault)
                        bias = fault[1]
                        counters["bias_faults"] += 1
                        ctx.log("warning", f"fault bias {sc}: navigation bias now "
                                f"{bias.tolist()} from t = {msg.t:.0f} s ({fault[2]})",
                                msg.t)  # fmt: skip
                    x = navigation_state(ctx.deployment, deputy, slot["chief"], slot[sc]) + bias
                    if sigma.any():
                        x = x + rng.normal(0.0, 1.0, 6) * sigma
                    altitude = float(np.linalg.norm(slot[sc][:3])) - R_EARTH
                    body = {"sc": sc, "x_hill": x, "altitude": altitude, "valid": True}
                    ctx.bus.publish(f"nav/{sc}/state", "nav", body, msg.t)
                    counters["published"] += 1
                    last_t = msg.t
                    ctx.ready()  # a restarted service is alive once it publishes again
            # a half pair well behind the newest sample will never complete (a lost message);
            # the two subscriptions can drift apart by the steps the environment runs ahead
            # of a delayed control loop, so "well behind" is ten flight-software steps
            horizon = msg.t - 10 * ctx.deployment.run.fsw_period
            for t in [t for t in pending if t < horizon]:
                del pending[t]
                counters["unmatched"] += 1

    while not ctx.stop.is_set():
        try:
            _, msg = inbox.get(timeout=0.5)
        except queue.Empty:
            if final_t is not None and time.monotonic() - final_seen > END_GRACE:
                break  # the last truth never came (a lost message): nothing more will
            continue
        # what one pass over the queue publishes goes out as one zenoh sample per topic:
        # the environment's step arrives at once, so a step's samples leave together
        with ctx.bus.batch():
            while True:
                handle(msg)
                try:
                    _, msg = inbox.get_nowait()
                except queue.Empty:
                    break
        if final_t is not None and last_pair >= final_t - 1e-6:
            break
    ctx.publish_stats(last_t, counters)
    return 0


if __name__ == "__main__":
    sys.exit(run_service(main, "nav"))
