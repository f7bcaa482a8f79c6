"""The ground's origin check: what a publisher may not say is refused, counted by publisher,
topic and reason in bounded memory, said in the report, and makes a completed run exit 3."""

from __future__ import annotations

import numpy as np

from services.ground.analysis.outcome import outcome, outcome_lines
from services.ground.analysis.refusals import MAX_KINDS, OTHERS, Refusals
from services.ground.launch.lifecycle import EXIT_DEGRADED, EXIT_OK, verdict
from services.interface import Message


def _stats(src: str, service: str, t: float = 60.0) -> Message:
    return Message("stats", 1, 0, t, src, {"service": service, "counters": {}})


def test_only_what_the_topology_lets_a_publisher_say_is_accepted() -> None:
    ground = Refusals()
    assert ground.accepts("stats/nav-lqr", _stats("nav-lqr", "nav-lqr"))
    assert not ground.accepts("stats/nav-lqr", _stats("nav-lqr", "environment"))
    assert not ground.accepts("stats/environment", _stats("nav-lqr", "environment"))
    gains = Message("gains", 1, 0, 60.0, "ctrl-lqr", {"sc": "ddvi", "K": np.zeros((1, 4))})
    assert not ground.accepts("ctrl/lqr/gains", gains)
    assert not ground.accepts("probe", _stats("anyone", "anyone"))  # a topic nobody owns
    kinds = {(k["topic"], k["src"], k["reason"]): k for k in ground.summary()}
    assert set(kinds) == {
        ("stats/nav-lqr", "nav-lqr", "identity"),
        ("stats/environment", "nav-lqr", "src"),
        ("ctrl/lqr/gains", "ctrl-lqr", "identity"),
        ("probe", "anyone", "topic"),
    }
    assert kinds[("ctrl/lqr/gains", "ctrl-lqr", "identity")]["claimed"] == "sc = 'ddvi'"


def test_a_flood_of_invented_names_stays_bounded_and_counted() -> None:
    ground = Refusals()
    for k in range(10 * MAX_KINDS):
        assert not ground.accepts("stats/nav-lqr", _stats("nav-lqr", f"made-up-{k}"))
    assert len(ground.kinds) == 1 and ground.total == 10 * MAX_KINDS
    for k in range(2 * MAX_KINDS):
        ground.accepts(f"probe{k}", _stats("x", "x"))
    assert len(ground.kinds) == MAX_KINDS + 1
    assert any(k["src"] == OTHERS for k in ground.summary())


def test_refusals_are_said_and_make_a_completed_run_exit_3() -> None:
    ground = Refusals()
    ground.accepts("stats/nav-lqr", _stats("nav-lqr", "environment", t=1200.0))
    out = outcome(
        final_seen=True,
        sim_t=100.0,
        duration=100.0,
        period=50.0,
        services={},
        monitor={},
        refused=ground.summary(),
    )
    lines = "\n".join(outcome_lines(out))
    assert "1 messages refused by the ground" in lines
    assert "`stats/nav-lqr` from `nav-lqr`: 1" in lines and "service = 'environment'" in lines
    status, line = verdict({"completed": True, "outcome": out})
    assert status == EXIT_DEGRADED and "stats/nav-lqr from nav-lqr" in line
    assert verdict({"completed": True, "outcome": {**out, "refused": []}})[0] == EXIT_OK
