"""How a run ended and what happened to its commands: the report's outcome, and its lines.

``outcome`` is pure (the counters in, a dict out): it is the ``outcome`` block of summary.json,
which ``ddvi run``'s exit status is decided from (``services.ground.lifecycle.verdict``).

    ended_by    "final clock" (the environment's, at the planned end), "early final clock"
                (the environment ended the mission before it: a re-entry), "stopped" (no
                final clock: a stop signal, a crash, a killed monitor)
    commands    {"refused", "stale", "missing", "late"}: the environment's counts of the
                attitude commands it refused (undecodable, wrong sender, out of the clock's
                window), did not apply as older than the one in force, did not have at a step,
                or had too late
    refused_clocks  clock messages from anyone but the environment, recorded and not obeyed
    refused     the messages the ground refused to believe, by publisher, topic and reason
                (``services.ground.refusals``): a topic its publisher may not send, or a body
                naming another deputy or service than its topic
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
) -> dict[str, Any]:
    """The outcome block: how the run ended (``sim_t`` s of ``duration``, orbit ``period``
    s) and the command problems counted by the environment in ``services`` (service ->
    counters); ``monitor``: the monitor's counters; ``refused``: ``Refusals.summary()``."""
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
        "refused": [dict(r) for r in refused],
    }


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
    if out.get("refused_clocks"):
        lines.append(
            f"- **{out['refused_clocks']} clock messages refused**: not from the environment "
            "(recorded, never obeyed)"
        )
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
