"""When a controller's step may fly (``services.flight.step_gate.StepGate``): on the sample
measured by T - delay once it is accounted for, without navigation once it is away, said and
given up in lock-step; flown safe on stale navigation in real time and in lock-step
(``services.flight.control_loop.StaleNavigation``)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from services.flight import step_gate
from services.flight.control_loop import StaleNavigation, newest_sample_time
from services.flight.health import HangError
from services.flight.step_gate import StepGate


def _run(mode: str = "lockstep", stale: float = 0.0) -> SimpleNamespace:
    return SimpleNamespace(
        mode=mode, fsw_period=60.0, command_deadline=1.0, hang_timeout=3.0, nav_stale_limit=stale
    )


def _gate(run: SimpleNamespace, delay: float = 0.0) -> StepGate:
    """The gate of deputy "lqr", navigating every 10 s, its inputs ``delay`` s late."""
    return StepGate(run, "lqr", lambda T: newest_sample_time(T, delay, 10.0))


class _Stale:
    """The stale-navigation rule as a step at T sees it, its inputs ``delay`` s late."""

    def __init__(self, limit: float = 120.0, delay: float = 0.0) -> None:
        self.rule, self.delay = StaleNavigation(limit), delay

    def __call__(self, T: float, newest: float | None, first: bool) -> tuple[bool, str | None]:
        return self.rule.check(newest_sample_time(T, self.delay, 10.0), newest, first)


class _Clock:
    """A monotonic clock the test moves."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> _Clock:
    c = _Clock()
    monkeypatch.setattr(step_gate.time, "monotonic", c)
    monkeypatch.setattr("services.flight.health.time.monotonic", c)
    return c


def test_a_step_flies_on_the_sample_measured_a_delay_before_it_once_accounted_for() -> None:
    gate = _gate(_run(), delay=15.0)
    assert gate.expected_sample(120.0) == 100.0  # 120 - 15 = 105: the sample of t = 100
    gate.clock(120.0)
    assert not gate.ready(120.0)
    gate.accounted("nav", 100.0)
    assert not gate.ready(120.0)  # its exostate too
    gate.accounted("exo", 100.0)
    assert gate.ready(120.0)
    assert not gate.ready(180.0)  # the clock has not reached it


def test_a_flood_counts_the_pending_steps_sample_as_lost() -> None:
    gate = _gate(_run())
    gate.clock(60.0)
    gate.accounted("exo", 60.0)
    gate.flooded("nav", 60.0)
    assert gate.ready(60.0)
    gate.flooded("nav", float("inf"))  # a restarted controller with no step yet: nothing


def test_steps_stop_waiting_for_navigation_a_grace_after_its_token_goes(clock: _Clock) -> None:
    gate = _gate(_run())
    gate.clock(60.0)
    gate.accounted("exo", 60.0)
    gate.presence(False)
    assert not gate.ready(60.0)
    clock.now += step_gate.NAV_AWAY_GRACE
    assert gate.ready(60.0)
    gate.presence(True)
    assert not gate.ready(60.0)


def test_lock_step_says_a_wait_then_gives_up_naming_the_silent_service(clock: _Clock) -> None:
    gate = _gate(_run())
    gate.clock(60.0)
    gate.accounted("exo", 60.0)
    said: list[str] = []
    gate.check(60.0, said.append)
    assert said == []
    clock.now += 1.0
    gate.check(60.0, said.append)
    assert said == ["lock-step paused at t = 60 s: no sample for t = 60 s from nav-lqr for 1 s"]
    clock.now += 2.0
    with pytest.raises(HangError, match="nav-lqr is hung") as caught:
        gate.check(60.0, said.append)
    assert caught.value.service == "nav-lqr" and len(said) == 1
    gate.accounted("nav", 60.0)
    gate.check(60.0, said.append)  # ready: the wait is over
    assert gate.waiting is None


def test_real_time_flies_safe_on_stale_navigation_and_says_so_once_each_way() -> None:
    gate, stale = _gate(_run("realtime", stale=120.0)), _Stale()
    assert stale(0.0, None, first=True) == (False, None)  # nothing measured yet
    assert stale(120.0, 0.0, first=False) == (False, None)  # 120 s old: at the limit
    safe, said = stale(180.0, 0.0, first=False)
    assert safe and said is not None and "flying the safe attitude" in said
    assert stale(240.0, 0.0, first=False) == (True, None)
    assert stale(300.0, 300.0, first=False) == (
        False,
        "navigation is back: flying the control law",
    )
    gate.clock(300.0 + 120.0)
    assert gate.ready(300.0)  # real time does not wait past the limit
    _gate(_run()).check(60.0, lambda _: None)  # lock-step: no clock yet


def test_lock_step_flies_safe_on_a_sample_held_past_the_limit_and_says_so_once_each_way() -> None:
    """In lock-step a step waits until its sample is accounted for, but a sample held on its
    link (a run-time delay the step does not know of) leaves the step only an older one: past
    run.nav_stale_limit it flies the safe attitude, as in real time."""
    gate, stale = _gate(_run()), _Stale()
    assert stale(0.0, None, first=True) == (False, None)  # nothing measured yet
    assert stale(600.0, 600.0, first=False) == (False, None)  # nominal: its own sample
    gate.clock(720.0)
    gate.accounted("nav", 720.0)  # held on its link: accounted for, never flown on
    gate.accounted("exo", 720.0)
    assert gate.ready(720.0)  # the step does not wait for what its link holds
    assert stale(720.0, 600.0, first=False) == (False, None)  # 120 s: two steps, the limit
    safe, said = stale(780.0, 600.0, first=False)
    assert safe and said == "navigation 180 s old (limit 120 s): flying the safe attitude"
    assert stale(50000.0, 600.0, first=False) == (True, None)  # said once
    back = stale(50040.0, 50040.0, first=False)
    assert back == (False, "navigation is back: flying the control law")


def test_no_step_flies_safe_before_its_first_sample_is_due() -> None:
    """A step before a delayed link's first sample can have come holds zero (the rule is the
    same in either mode): its navigation is not stale, there is none yet."""
    stale = _Stale(delay=300.0)
    assert stale(0.0, None, first=True) == (False, None)
    assert stale(240.0, None, first=False) == (False, None)  # due at 300 s
    safe, said = stale(480.0, None, first=False)  # due from 300 s, never came
    assert safe and said == "no navigation yet (limit 120 s): flying the safe attitude"
