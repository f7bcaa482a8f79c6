"""Rate budgets: each key's excess dropped unread and counted against its publisher; refilled by
the receiver's simulated time; bounded in keys."""

from __future__ import annotations

import queue

import numpy as np
import pytest
import zenoh

from services.bus import Bus, RateBudget, budget_for, message_count, queue_handler
from services.interface import encode, pack_batch
from tests.bus.test_bus import TIMEOUT, Inbox, connect, nav_body, run, sessions  # noqa: F401
from tests.support import wait_until

PREFIX = "ddvi/r/"


def _cmd(seq: int) -> bytes:
    body = {"sc": "lqr", "sigma": np.zeros(3), "for_t": 60.0}
    return encode("cmd", body, seq=seq, t=60.0, src="ctrl-lqr")


def test_message_count_reads_a_batch_from_its_first_bytes() -> None:
    one = _cmd(0)
    assert message_count(one) == 1
    assert message_count(pack_batch([_cmd(i) for i in range(3)])) == 3
    assert message_count(pack_batch([_cmd(i) for i in range(20)])) == 20  # array 16
    assert message_count(b"") == 1 and message_count(b"\xdd\xff\xff\xff\xff") == 64


def test_a_key_gets_its_topology_rate_in_simulated_time_and_a_burst() -> None:
    budget = RateBudget(PREFIX, {"nav": 10.0, "fsw": 60.0, "status": 600.0}, slack=2.0, burst=4)
    key = PREFIX + "cmd/lqr/att"  # budgeted by the flight-software step: 2 a 60 s
    assert [budget.take(key, _cmd(i)) for i in range(6)] == [True] * 4 + [False] * 2
    assert budget.counters() == {"flood.ctrl-lqr": 2}
    budget.advance(60.0)  # one step: two more
    assert [budget.take(key, _cmd(i)) for i in range(3)] == [True, True, False]
    budget.advance(30.0)  # time never goes back
    assert not budget.take(key, _cmd(0))
    # another key has its own bucket, and a batch costs its messages
    assert not budget.take(PREFIX + "stats/nav-lqr", pack_batch([_cmd(i) for i in range(5)]))
    assert budget.counters() == {"flood.ctrl-lqr": 4, "flood.nav-lqr": 5}


def test_keys_past_the_limit_share_one_bucket() -> None:
    budget = RateBudget(PREFIX, {"nav": 10.0}, burst=1, max_keys=2)
    assert budget.take(PREFIX + "log/a", b"x") and budget.take(PREFIX + "log/b", b"x")
    assert budget.take(PREFIX + "log/c", b"x")  # the shared bucket's first
    assert not any(budget.take(PREFIX + f"log/k{i}", b"x") for i in range(100))
    assert budget.counters() == {"flood.<other>": 100}
    with pytest.raises(ValueError, match="periods"):
        RateBudget(PREFIX, {"nav": 0.0})


def test_a_flooded_key_is_dropped_unread_counted_and_told(
    sessions: tuple[zenoh.Session, zenoh.Session],  # noqa: F811
    run: str,  # noqa: F811
) -> None:
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    lost: queue.Queue[str] = queue.Queue()
    budget = budget_for(f"ddvi/{run}/", 10.0, 60.0, 10)
    with Bus(hub, run, "ctrl-deputy1", budget=budget) as rx, Bus(svc, run, "nav-deputy1") as tx:
        rx.subscribe(
            "nav/deputy1/state", queue_handler(inbox), expected_schema="nav", lost=lost.put
        )
        connect(tx, inbox, "nav/deputy1/state")
        for i in range(1000):  # far past the burst, at one simulated time
            tx.publish("nav/deputy1/state", "nav", nav_body(i), t=0.0)
        assert wait_until(lambda: rx.counters["flooded"] + rx.counters["received"] >= 1000)
        counters = rx.counters
        assert counters["flood.nav-deputy1"] == counters["flooded"] > 400
        assert counters["rejected"] == 0  # dropped before decoding: nothing refused
        assert lost.get(timeout=TIMEOUT) == "nav/deputy1/state" and lost.empty()  # told once
