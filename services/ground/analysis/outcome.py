"""How a run ended and what happened to its commands: the report's outcome, and its lines.

``outcome`` is pure (the counters in, a dict out): it is the ``outcome`` block of summary.json,
which ``ddvi run``'s exit status is decided from (``services.ground.launch.lifecycle.verdict``).

    ended_by    "final clock" (the environment's, at the planned end), "early final clock"
                (the environment ended the mission before it: a re-entry), "stopped" (no
                final clock: a stop signal, a crash, a killed monitor)
    commands    {"refused", "stale", "missing", "late"}: the environment's counts of the
                attitude commands it refused (undecodable, wrong sender, out of the clock's
                window), did not apply as older than the one in force, did not have at a step,
                or had too late
    refused_clocks  clock messages from anyone but the environment, recorded and not obeyed
    flooded     {publisher: {receiver: n}}: messages a receiver dropped unread, past the
                publisher's rate budget (``services.bus.budget``): the publisher flooded
    health      {"safe_attitude_steps": {controller: n}, "paused_steps": n}: real-time steps a
                controller flew the safe attitude (its navigation too old), lock-step steps
                the mission paused for a silent controller or recorder (docs/health.md)
    refused     the messages the ground refused to believe, by publisher, topic and reason
                (``services.ground.analysis.refusals``): a topic its publisher may not send, or a
                body naming another deputy or service than its topic
    impossible  the counters a service claimed in its stats that cannot be true, by publisher,
                counter and reason (``services.ground.analysis.claims``): never believed
    clipped_commands  {"total": n, "by_deputy": {deputy: n}}: commands the environment clipped
                to the deputy's attitude limit (``deputy.attitude_limit``)
    record      whether the record of the run is whole (``services.ground.storage.record``)
    refused_by_number  {reason: n}: messages the ground recorded but kept out of the report
                by their sequence number (``services.bus.SequenceGuard``: a duplicate, a stale
                replay, a jump past any number its publisher reached): refused, never lost
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

TIME_MASTER = "environment"

COMMAND_COUNTERS = {
    "refused": ("rejected", "bad_commands"),
    "stale": ("stale_commands",),
    "missing": ("missing_commands",),
    "late": ("late_commands",),
}
"""A command problem: the environment's counters that add up to it."""


def outcome(
    *,
    final_seen: bool,
    sim_t: float,
    duration: float,
    period: float,
    services: Mapping[str, Mapping[str, Any]],
    monitor: Mapping[str, Any],
    refused: Sequence[Mapping[str, Any]] = (),
    impossible: Sequence[Mapping[str, Any]] = (),
    deputies: Sequence[str] = (),
    record: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The outcome block: how the run ended (``sim_t`` s of ``duration``, orbit ``period``
    s) and the command problems counted by the environment in ``services`` (service ->
    counters); ``monitor``: the monitor's counters; ``refused``: ``Refusals.summary()``;
    ``impossible``: ``Claims.impossible()``; ``deputies``: the deputies' names; ``record``:
    ``record.record_block`` (None: whole)."""
    env = services.get(TIME_MASTER, {})
    commands = {
        name: sum(int(env.get(key, 0) or 0) for key in keys)
        for name, keys in COMMAND_COUNTERS.items()
    }
    if final_seen and sim_t >= duration - 1e-6:
        ended_by = "final clock"
    elif final_seen:
        ended_by = "early final clock"
    else:
        ended_by = "stopped"
    return {
        "ended_by": ended_by,
        "ended_at_orbits": sim_t / period if period > 0 else 0.0,
        "planned_orbits": duration / period if period > 0 else 0.0,
        "commands": commands,
        "refused_clocks": int(monitor.get("refused.clock", 0) or 0),
        "flooded": flooded({**services, "monitor": monitor}),
        "health": {
            "safe_attitude_steps": {
                name: n
                for name, counters in services.items()
                if (n := int(counters.get("safe_attitude_steps", 0) or 0))
            },
            "paused_steps": int(env.get("paused_steps", 0) or 0),
        },
        "refused": [dict(r) for r in refused],
        "impossible": [dict(c) for c in impossible],
        "clipped_commands": clipped(env, deputies),
        "record": dict(record) if record is not None else {"complete": True},
        "refused_by_number": {
            key.removeprefix("ignored."): int(n)
            for key, n in monitor.items()
            if key.startswith("ignored.") and int(n or 0)
        },
    }


def clipped(env: Mapping[str, Any], deputies: Sequence[str]) -> dict[str, Any]:
    """The environment's commands clipped to the attitude limit: in all and by deputy."""
    return {
        "total": int(env.get("clipped_commands", 0) or 0),
        "by_deputy": {sc: int(env.get(f"clipped_commands.{sc}", 0) or 0) for sc in deputies},
    }


def flooded(receivers: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, int]]:
    """{publisher: {receiver: messages dropped}} from the receivers' ``flood.<publisher>``
    counters, those not zero."""
    out: dict[str, dict[str, int]] = {}
    for receiver, counters in receivers.items():
        for key, n in counters.items():
            if key.startswith("flood.") and int(n or 0) > 0:
                out.setdefault(key.removeprefix("flood."), {})[receiver] = int(n)
    return out


def flood_text(found: Mapping[str, Mapping[str, int]]) -> str:
    """One phrase naming each flooding publisher and the most any receiver dropped of it."""
    return ", ".join(
        f"{pub} ({max(by.values())} messages dropped at {', '.join(sorted(by))})"
        for pub, by in sorted(found.items())
    )


def outcome_lines(out: Mapping[str, Any]) -> list[str]:
    """report.md's lines on the outcome: how the run ended, what went wrong with commands."""
    ended, at, planned = out["ended_by"], out["ended_at_orbits"], out["planned_orbits"]
    if ended == "final clock":
        lines = [f"- ended: by the environment's final clock at {at:.2f} orbits, as planned"]
    elif ended == "early final clock":
        lines = [
            f"- ended: **early**, by the environment's final clock at {at:.2f} of "
            f"{planned:.2f} orbits (a craft re-entered, or the truth failed: see its log)"
        ]
    else:
        lines = [
            f"- ended: **stopped** at {at:.2f} of {planned:.2f} orbits, before any final "
            "clock (a stop signal, a crash or a killed monitor: this report is partial)"
        ]
    problems = {k: v for k, v in out["commands"].items() if v}
    if problems:
        said = ", ".join(f"{v} {k}" for k, v in problems.items())
        lines.append(f"- commands: **{said}** (ddvi run exits 3 for a completed mission)")
    else:
        lines.append("- commands: none refused, stale, missing or late")
    if found := out.get("flooded"):
        lines.append(
            f"- **flooded by {flood_text(found)}**: past its rate budget, dropped "
            "unread (ddvi run exits 3)"
        )
    health = out.get("health", {})
    if safe := health.get("safe_attitude_steps"):
        said = ", ".join(f"{name} {n}" for name, n in sorted(safe.items()))
        lines.append(f"- **safe attitude flown** (navigation too old): {said} steps")
    if health.get("paused_steps"):
        lines.append(
            f"- lock-step paused {health['paused_steps']} times for a silent "
            "controller or recorder (run.command_deadline); the mission waited for "
            "it"
        )
    if out.get("refused_clocks"):
        lines.append(
            f"- **{out['refused_clocks']} clock messages refused**: not from the environment "
            "(recorded, never obeyed)"
        )
    if by_number := out.get("refused_by_number"):
        said = ", ".join(f"{n} {why}" for why, n in sorted(by_number.items()))
        said += " (recorded, never taken for lost)"
        lines.append(f"- messages the ground refused by their sequence number: {said}")
    if (cut := out.get("clipped_commands")) is not None:
        lines.append(clipped_line(cut))
    if impossible := out.get("impossible"):
        lines.append(
            f"- **{sum(c['count'] for c in impossible)} impossible claims** in services' stats "
            "(never believed; ddvi run exits 3 for a completed mission):"
        )
        lines += [f"  - {impossible_line(c)}" for c in impossible[:20]]
    refused = out.get("refused") or []
    if refused:
        total = sum(r["count"] for r in refused)
        lines.append(
            f"- **{total} messages refused by the ground** (recorded, never believed; ddvi run "
            "exits 3 for a completed mission):"
        )
        lines += [f"  - {refused_line(r)}" for r in refused[:20]]
    return lines


def refused_line(r: Mapping[str, Any]) -> str:
    """One kind of refused message, in words: what, from whom, how many, why."""
    why = {"src": "not this topic's publisher", "topic": "a topic nobody publishes"}.get(
        r["reason"], f"its body names {r.get('claimed')}, not what its topic names"
    )
    return (
        f"`{r['topic']}` from `{r['src']}`: {r['count']} ({why}; first at t = {r['first_t']:.0f} s)"
    )


def clipped_line(cut: Mapping[str, Any]) -> str:
    """report.md's line on the commands clipped to the attitude limit, by deputy."""
    by = cut.get("by_deputy", {})
    if not cut.get("total"):
        return "- commands clipped to the attitude limit: none"
    said = ", ".join(f"{sc} {n}" for sc, n in by.items())
    if (rest := cut["total"] - sum(by.values())) > 0:  # a recording without them by deputy
        said = ", ".join(filter(None, [said, f"{rest} of a deputy not named"]))
    return f"- commands clipped to the attitude limit: {said}"


def impossible_line(c: Mapping[str, Any]) -> str:
    """One kind of impossible claim, in words: who claimed what, and why it cannot be."""
    again = f"; {c['count']} such claims" if c["count"] > 1 else ""
    what = "stats" if c["counter"] == "service" else f"{c['counter']} = {c['claimed']:,}"
    return (
        f"`{c['src']}` claimed {what}: impossible, {c['text']} "
        f"(first at t = {c['first_t']:.0f} s{again})"
    )


def impossible_text(found: Sequence[Mapping[str, Any]]) -> str:
    """One phrase naming each impossible claim's publisher and figure."""
    return ", ".join(f"{c['src']} {c['counter']} = {c['claimed']:,}" for c in found[:5])
