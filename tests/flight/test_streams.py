"""The input streams navigation and the controller share: pairing by time, fault queues, the
grace after the final clock; and the pure control law's step on a navigation sample."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddvi_core.constants import R_EARTH
from services.config import load_deployment
from services.flight import streams
from services.flight.control import Controller
from services.flight.streams import FaultQueue, FinalClock, SamplePairs
from services.interface import Message


def test_sample_pairs_complete_by_time_and_forget_half_pairs() -> None:
    pairs = SamplePairs(("nav", "exo"))
    assert pairs.add(10.0, "nav", 1) is None
    assert pairs.add(20.0, "exo", 2) is None
    assert pairs.add(10.0, "nav", 3) is None  # a repeat replaces the part
    assert pairs.add(10.0, "exo", 4) == {"nav": 3, "exo": 4}
    assert pairs.add(30.0, "nav", 5) is None
    assert pairs.forget_before(30.0) == [{"exo": 2}]
    assert list(pairs.pending) == [30.0]


def test_fault_queue_gives_due_faults_in_queue_order() -> None:
    faults = FaultQueue([(100.0, "a"), (50.0, "b"), (300.0, "c")])
    faults.from_ground("g", "ground")
    assert faults.pop_due(10.0) == [(-math.inf, "g", "from ground")]
    due = faults.pop_due(100.0)
    assert [(f.value, f.origin) for f in due] == [("a", "scheduled"), ("b", "scheduled")]
    assert faults.pop_due(200.0) == [] and [f.value for f in faults.waiting] == ["c"]


def test_final_clock_grace(monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    monkeypatch.setattr(streams.time, "monotonic", lambda: now[0])
    final = FinalClock()

    def clock(t: float, last: bool) -> Message:
        body = {"step": 1, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": last}
        return Message(schema="clock", version=1, seq=0, t=t, src="environment", body=body)

    final.on_clock(clock(60.0, False))
    assert final.t is None and not final.grace_over()
    final.on_clock(clock(120.0, True))
    assert final.t == 120.0 and not final.grace_over()
    now[0] += streams.END_GRACE + 0.1
    assert final.grace_over()


def test_controller_steps_on_the_flight_software_grid_only() -> None:
    """``on_sample``: a sample on the flight-software grid runs a step (a new command within
    the attitude limit); one between steps leaves the command in force."""
    dep = load_deployment(None)
    ctrl = Controller(dep, "lqr")
    x, v = np.array([10.0, -500.0, 0.0, 0.01]), np.array([1.0, 0.0, 0.0, 0.0, 0.0])
    h0 = dep.chief.a - R_EARTH
    first = ctrl.on_sample(0.0, x, v, h0)
    assert first.fsw and first.learn_log is None and first.rejected is None
    u = ctrl.u
    assert u != 0.0 and abs(u) <= ctrl.actuation.limit
    between = ctrl.on_sample(dep.run.nav_period, 2 * x, v, h0)
    assert not between.fsw and ctrl.u == u
    assert ctrl.actuation.steps == [(0.0, ctrl.actuation.u_applied)]
