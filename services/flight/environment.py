"""Environment service: the truth and the time master.

Inputs:  cmd/<deputy>/att (cmd) from each controller; fault/panel (fault: target = deputy,
         params.area_factor and/or params.normal_angle) from the ground; the deployment's
         scheduled [[fault]] panels.
Outputs: truth/<sc> (truth) for the chief and every deputy and exo/state (exo) at every
         navigation sample; clock (clock) at every flight-software step in lock-step (at every
         sample in real time); stats/environment.

Propagates every craft in one ODE (two-body + J2 + facet drag, ddvi_core.truth), one
flight-software step at a time, with each deputy's commanded relative MRP (clipped to its
attitude limit) held over the step.  Lock-step mode: after publishing the samples of step t_k it
waits until every controller's command for the step its link delay maps to (issued at T, it
arrives at T + delay, so the newest that can act from t_k is for floor((t_k - delay) / fsw)
steps) is accounted for (delivered, or dropped by its link), or until the wall-clock deadline;
a missing command leaves the last one in force (zero-order hold, as an actuator would) and is
counted.  A controller that goes away (its liveliness token gone: crashed, restarting) is not
waited for step by step: lock-step pauses once, up to run.command_deadline wall seconds, for it
to come back (a restart takes a few), and from its return it is waited for again from the next
step; while it is away its deputy holds its last command (counted in controller_away_steps).
Real-time mode: paces the samples to
wall time times run.rate and never waits.
"""

from __future__ import annotations

import contextlib
import math
import queue
import sys
import time

import numpy as np

from ddvi_core.orbit import dcm_to_mrp, hill_frame, mrp_to_dcm
from services.bus import queue_handler, wait_for_alive, watch_alive
from services.config import check_panel
from services.flight.runtime import ServiceContext, run_service
from services.interface import Message
from services.model import (
    ReentryError,
    Truth,
    describe_panel,
    duration,
    exostate,
    on_grid,
    open_truth,
    panel_schedule,
)

_OBSERVED = "observed"  # inbox tag of a command seen by the link layer (see subscribe)
_PRESENCE = "presence"  # inbox tag of a controller's liveliness change
_PANEL = "fault/panel"  # topic of run-time panel faults


def main(ctx: ServiceContext) -> int:
    truth = open_truth(ctx.deployment)
    try:
        return _serve(ctx, truth)
    finally:
        truth.close()


def _serve(ctx: ServiceContext, truth: Truth) -> int:
    dep = ctx.deployment
    run = dep.run
    deputies = [d.name for d in dep.deputy]
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    # every command that reaches this host is also observed after its link has delivered, held
    # or dropped it: the lock-step wait ends when the command it waits for is accounted for
    ctx.bus.subscribe(
        "cmd/*/att",
        queue_handler(inbox),
        expected_schema="cmd",
        observe=lambda _topic, msg: inbox.put((_OBSERVED, msg)),
    )
    ctx.bus.subscribe(_PANEL, queue_handler(inbox), expected_schema="fault")
    ctx.ready()
    others = [s for s in dep.services if s != ctx.name]
    alive = wait_for_alive(ctx.bus.session, ctx.run, others, run.startup_timeout)
    if set(others) - alive:
        ctx.log(
            "error",
            f"services not alive after {run.startup_timeout} s: {sorted(set(others) - alive)}",
        )
        return 1

    present = {sc for sc in deputies if f"ctrl-{sc}" in alive}  # controllers to wait for

    def on_presence(service: str, up: bool) -> None:
        inbox.put((_PRESENCE, (service.removeprefix("ctrl-"), up)))

    presence = watch_alive(ctx.bus.session, ctx.run, "ctrl-*", on_presence)
    try:
        return _propagate(ctx, truth, inbox, present)
    finally:
        presence.undeclare()


def _propagate(
    ctx: ServiceContext, truth: Truth, inbox: queue.SimpleQueue, present: set[str]
) -> int:
    dep = ctx.deployment
    run = dep.run
    deputies = [d.name for d in dep.deputy]
    names = ["chief", *deputies]
    limits = np.array([d.attitude_limit for d in dep.deputy])
    dt, fsw, t_end = run.nav_period, run.fsw_period, duration(dep)
    counters = {
        "steps": 0,
        "late_commands": 0,
        "missing_commands": 0,
        "stale_commands": 0,
        "clipped_commands": 0,
        "bad_commands": 0,
        "controller_away_steps": 0,
        "panel_faults": 0,
        "bad_faults": 0,
    }
    # panel faults: the deployment's, at their times, and the ground's (fault/panel) at the
    # next step; (t, deputy, area factor, normal angle, origin)
    panel_faults = [(*f, "scheduled") for f in panel_schedule(dep)]

    def apply_panel_faults(t_k: float) -> None:
        due = [f for f in panel_faults if f[0] <= t_k + 1e-6]
        for fault in sorted(due, key=lambda f: f[0]):
            panel_faults.remove(fault)
            _, sc, factor, angle, origin = fault
            try:
                truth.set_panel(deputies.index(sc), factor, angle)
            except (ValueError, RuntimeError) as exc:
                counters["bad_faults"] += 1
                ctx.log("warning", f"fault panel {sc}: refused ({exc})", t_k)
                continue
            counters["panel_faults"] += 1
            ctx.log("warning", f"fault panel {sc}: {describe_panel(factor, angle)} "
                    f"from t = {t_k:.0f} s ({origin})", t_k)  # fmt: skip

    def on_fault(msg: Message) -> None:
        sc, params = msg.body["target"], msg.body["params"]
        factor, angle = params.get("area_factor"), params.get("normal_angle")
        try:
            if sc not in deputies:
                raise ValueError(f"{sc!r} is not a deputy of this run")
            check_panel(factor, angle)
        except ValueError as exc:
            counters["bad_faults"] += 1
            ctx.log("warning", f"fault panel {sc}: refused ({exc}; got {msg.body})", msg.t)
            return
        factor, angle = (None if a is None else float(a) for a in (factor, angle))
        panel_faults.append((-math.inf, sc, factor, angle, f"from {msg.src}"))

    away_since: dict[str, float] = {}  # wall time each away controller went
    returned_at: dict[str, float] = {}  # step at which each came back
    sigma = np.zeros((len(deputies), 3))  # commands in force
    latest_for_t = dict.fromkeys(deputies, -math.inf)  # step of the command in force
    seen_for_t = dict.fromkeys(deputies, -math.inf)  # newest command accounted for
    # a command issued at T reaches the truth at T + the link's delay (DESIGN.md section 3)
    cmd_delay = {sc: ctx.bus.latency(f"ctrl-{sc}", f"cmd/{sc}/att") for sc in deputies}
    wall0 = time.monotonic()

    def attitudes(traj: np.ndarray) -> np.ndarray:
        """sigma_BN (K, 1 + N, 3) of states (K, 1 + N, 6): the chief Hill-pointing, each
        deputy Hill-pointing composed with its command in force (one batched call a step)."""
        k = traj.shape[0]
        HN = hill_frame(traj[..., :3].reshape(-1, 3), traj[..., 3:].reshape(-1, 3))
        HN = HN.reshape(k, len(names), 3, 3)
        BN = HN.copy()
        BN[:, 1:] = mrp_to_dcm(sigma) @ HN[:, 1:] if len(deputies) else HN[:, 1:]
        return dcm_to_mrp(BN.reshape(-1, 3, 3)).reshape(k, len(names), 3)

    def publish_sample(
        t: float, step: int, X: np.ndarray, sigma_BN: np.ndarray, final: bool
    ) -> None:
        if run.mode == "realtime":
            delay = wall0 + t / run.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        for i, sc in enumerate(names):
            ctx.bus.publish(
                f"truth/{sc}",
                "truth",
                {"sc": sc, "r_N": X[i, :3], "v_N": X[i, 3:], "sigma_BN": sigma_BN[i]},
                t,
            )
        v, phase = exostate(dep, t)
        ctx.bus.publish("exo/state", "exo", {"v": v, "phase": phase}, t)
        fsw_step = on_grid(t, fsw)
        # lock-step services step on flight-software boundaries: a clock between them would
        # only cost every subscriber a message; real time keeps one a sample (its wall-clock
        # links are released at clock messages)
        if fsw_step or final or run.mode == "realtime":
            ctx.bus.publish(
                "clock",
                "clock",
                {"step": step, "dt": dt, "fsw": fsw_step, "mode": run.mode, "final": final},
                t,
            )

    def expected_step(sc: str, t_k: float) -> float:
        """The newest command step that can be in force from t_k on (negative: none yet)."""
        return math.floor((t_k - cmd_delay[sc]) / fsw + 1e-9) * fsw

    def take_commands(t_k: float, wait: bool) -> None:
        """Apply the newest command of each deputy that its link has delivered by t_k; in
        lock-step wait until the one for the step its delay maps to is accounted for."""
        ctx.bus.pump(t_k)  # release what the links held until t_k
        expected = {sc: expected_step(sc, t_k) for sc in deputies}
        deadline = time.monotonic() + run.command_deadline

        def outstanding(sc: str) -> bool:
            due = expected[sc] - 1e-6
            return (
                sc in present
                and returned_at.get(sc, -math.inf) < t_k  # back since before this step
                and expected[sc] >= 0
                and latest_for_t[sc] < due
                and seen_for_t[sc] < due
            )

        def returning(sc: str) -> float | None:
            """Wall time until which to wait for an away controller to come back."""
            if sc in present or sc not in away_since:
                return None
            until = away_since[sc] + run.command_deadline
            return until if until > time.monotonic() else None

        while not ctx.stop.is_set():
            waits = [deadline] if any(outstanding(sc) for sc in deputies) else []
            waits += [u for sc in deputies if (u := returning(sc)) is not None]
            try:
                if wait and waits:
                    kind, msg = inbox.get(timeout=max(min(waits) - time.monotonic(), 0.0))
                else:
                    kind, msg = inbox.get_nowait()
            except queue.Empty:
                if wait and waits and min(waits) > time.monotonic():
                    continue
                break
            if kind == _PANEL:
                on_fault(msg)
                continue
            if kind == _PRESENCE:
                sc, up = msg
                if sc in latest_for_t and up and sc not in present:
                    present.add(sc)
                    returned_at[sc] = t_k
                    ctx.log("warning", f"controller of {sc} is back at t = {t_k:.0f} s", t_k)
                elif sc in latest_for_t and not up and sc in present:
                    present.discard(sc)
                    away_since[sc] = time.monotonic()
                    ctx.log("warning", f"controller of {sc} went away at t = {t_k:.0f} s; "
                            "holding its last command", t_k)  # fmt: skip
                continue
            sc = msg.body["sc"]
            if sc not in latest_for_t:
                counters["bad_commands"] += kind != _OBSERVED
                continue
            for_t = msg.body["for_t"]
            if kind == _OBSERVED:
                seen_for_t[sc] = max(seen_for_t[sc], for_t)
                continue
            if for_t <= latest_for_t[sc]:
                counters["stale_commands"] += 1  # not newer than the one in force: a replay
                continue
            if for_t < expected[sc] - 1e-6:
                counters["late_commands"] += 1
            i = deputies.index(sc)
            s_cmd = msg.body["sigma"]
            clipped = np.clip(s_cmd, -limits[i], limits[i])
            counters["clipped_commands"] += int(np.any(clipped != s_cmd))
            sigma[i] = clipped
            latest_for_t[sc] = for_t
        if wait:
            counters["missing_commands"] += sum(
                expected[sc] >= 0 and latest_for_t[sc] < expected[sc] - 1e-6 for sc in deputies
            )
        counters["controller_away_steps"] += len(set(deputies) - present)

    step = 0
    publish_sample(0.0, 0, truth.state, attitudes(truth.state[None])[0], final=t_end <= 0)
    t_k = 0.0
    while t_k < t_end - 1e-6 and not ctx.stop.is_set():
        take_commands(t_k, wait=run.mode == "lockstep")
        apply_panel_faults(t_k)
        t_next = t_k + fsw
        try:
            samples, traj = truth.step(t_k, sigma)
        except ReentryError as exc:
            ctx.log("error", f"mission ended early: {exc}", t_k)
            # tell every service the run is over at the last published sample
            ctx.bus.publish(
                "clock",
                "clock",
                {"step": step, "dt": dt, "fsw": True, "mode": run.mode, "final": True},
                t_k,
            )
            break
        sigma_BN = attitudes(traj)
        # lock-step: the step's samples leave together, one zenoh sample per topic (each
        # message keeps its own seq and time); real time paces them one by one
        with ctx.bus.batch() if run.mode == "lockstep" else contextlib.nullcontext():
            for k, t in enumerate(samples):
                step += 1
                publish_sample(float(t), step, traj[k], sigma_BN[k], final=abs(t - t_end) < 1e-6)
        t_k = t_next
        counters["steps"] += 1
        if counters["steps"] % run.status_every == 0:
            ctx.publish_stats(t_k, counters)
    completed = t_k >= t_end - 1e-6
    ctx.publish_stats(t_k, {**counters, "completed": int(completed)})
    return 0 if completed else 3


if __name__ == "__main__":
    sys.exit(run_service(main, "environment"))
