"""services.bus: settings, and two real zenoh peer sessions on loopback in one process."""

from __future__ import annotations

import json
import queue
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from services.bus import (
    DEFAULT_HUB,
    EPHEMERAL_LOOPBACK,
    Bus,
    BusSettings,
    LinkModel,
    LinkRule,
    LinkSpec,
    SequenceGuard,
    SequenceGuards,
    open_session,
    queue_handler,
    wait_for_alive,
    zenoh_config,
)
from services.bus.guards import BOOTS_KEPT, JUMP_CONFIRM, REPLAY_WINDOW
from services.ground.launch.launcher import free_port
from services.interface import MAX_BATCH, MAX_PAYLOAD, Message, MessageError, encode, pack_batch
from tests.support import unique_run_name, wait_until

TIMEOUT = 5.0


def nav_body(x: float = 0.0, sc: str = "deputy1") -> dict[str, Any]:
    return {
        "sc": sc,
        "x_hill": np.full(6, x),
        "z_hill": np.full(6, x),
        "cov": np.eye(6),
        "altitude": 300e3,
        "valid": True,
    }


Inbox = queue.Queue[tuple[str, Message]]


@pytest.fixture(scope="module")
def sessions() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """A hub peer listening on a free port and a service peer connecting to it."""
    hub_endpoint = f"tcp/127.0.0.1:{free_port()}"
    service = BusSettings(listen=[EPHEMERAL_LOOPBACK], connect=[hub_endpoint])
    with open_session(service.hub()) as hub, open_session(service) as svc:
        assert wait_until(lambda: len(list(svc.info.peers_zid())) == 1)
        yield hub, svc
    assert hub.is_closed() and svc.is_closed()


@pytest.fixture
def run() -> str:
    return unique_run_name()


def connect(tx: Bus, inbox: Inbox, topic: str) -> None:
    """Publish probes until the subscription has propagated, then one more, and take every
    probe out of the inbox up to that last one (a publisher's messages arrive in order)."""
    assert wait_until(lambda: tx.publish(topic, "nav", nav_body(), 0.0) >= 0 and not inbox.empty())
    last = tx.publish(topic, "nav", nav_body(), 0.0)
    while inbox.get(timeout=TIMEOUT)[1].seq != last:
        pass
    assert inbox.empty()


# --- settings -------------------------------------------------------------------------------


def test_default_settings_follow_the_convention() -> None:
    s = BusSettings()
    assert (s.mode, s.listen, s.connect) == ("peer", [EPHEMERAL_LOOPBACK], [DEFAULT_HUB])
    assert s.hub() == BusSettings(mode="peer", listen=[DEFAULT_HUB], connect=[])
    config = zenoh_config(s)
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("connect/endpoints")) == [DEFAULT_HUB]
    assert json.loads(config.get_json("mode")) == "peer"


@pytest.mark.parametrize(
    ("table", "key"),
    [
        ({"mode": "broker"}, "bus.mode"),
        ({"listen": ["localhost:7447"]}, r"bus.listen\[0\]"),
        ({"connect": "tcp/127.0.0.1:7447"}, "bus.connect"),
        ({"connect": ["tcp/127.0.0.1:7447", 5]}, r"bus.connect\[1\]"),
        ({"mode": "client", "connect": []}, "bus.connect"),
        ({"mode": "peer", "listen": []}, "bus.listen"),
        ({"mode": "router", "listen": []}, "bus.listen"),
    ],
)
def test_settings_validation_names_the_key(table: dict[str, Any], key: str) -> None:
    with pytest.raises(ValueError, match=rf"^{key}:"):
        BusSettings(**table)


def test_names_are_checked(sessions: tuple[zenoh.Session, zenoh.Session]) -> None:
    hub, _ = sessions
    with pytest.raises(ValueError, match="service"):
        Bus(hub, "run", "nav/deputy1")
    with pytest.raises(ValueError, match="run"):
        Bus(hub, "r*", "nav")


# --- two live sessions ----------------------------------------------------------------------


def test_published_message_arrives_decoded(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    with Bus(hub, run, "monitor") as rx, Bus(svc, run, "nav-deputy1") as tx:
        rx.subscribe("nav/*/state", queue_handler(inbox), expected_schema="nav")
        connect(tx, inbox, "nav/deputy1/state")
        first = tx.publish("nav/deputy1/state", "nav", nav_body(1.5), t=60.0)
        second = tx.publish("nav/deputy1/state", "nav", nav_body(2.5), t=120.0)
        assert second == first + 1
        topic, msg = inbox.get(timeout=TIMEOUT)
        assert topic == "nav/deputy1/state"
        assert (msg.schema, msg.seq, msg.t, msg.src) == ("nav", first, 60.0, "nav-deputy1")
        np.testing.assert_array_equal(msg.body["x_hill"], np.full(6, 1.5))
        assert inbox.get(timeout=TIMEOUT)[1].seq == second
        assert tx.publish("nav/deputy2/state", "nav", nav_body(), t=0.0) == 0  # per-topic seq
        # another deputy's navigation state: not this publisher's topic, refused and counted
        assert wait_until(lambda: rx.counters["rejected.src"] == 1)
        assert inbox.empty()
        assert tx.counters["sent"] >= 3
        assert rx.counters["received"] == rx.counters["delivered"] >= 2


def test_garbage_is_rejected_counted_and_subscriber_survives(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    key = f"ddvi/{run}/nav/deputy1/state"
    with Bus(hub, run, "monitor") as rx, Bus(svc, run, "nav-deputy1") as tx:
        rx.subscribe("nav/*/state", queue_handler(inbox), expected_schema="nav")
        connect(tx, inbox, "nav/deputy1/state")
        before = rx.counters
        cmd = {"sc": "deputy1", "sigma": [0.0, 0.0, 0.1], "for_t": 0.0}
        garbage = [
            b"\xc1\xc1 not msgpack",
            b"\x00" * (MAX_PAYLOAD + 1),
            encode("cmd", cmd, seq=0, t=0.0, src="intruder"),
        ]
        for payload in garbage:  # BLOCK: the default (DROP) may drop after the large one
            svc.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
        tx.publish("nav/deputy1/state", "nav", nav_body(3.0), t=1.0)
        _, msg = inbox.get(timeout=TIMEOUT)
        np.testing.assert_array_equal(msg.body["x_hill"], np.full(6, 3.0))
        assert wait_until(lambda: rx.counters["rejected"] - before["rejected"] == 3)
        after = rx.counters
        for reason in ("malformed", "oversized", "wrong_schema"):
            assert after[f"rejected.{reason}"] - before[f"rejected.{reason}"] == 1
        assert after["rejected"] - before["rejected"] == 3
        assert inbox.empty()


def test_a_batch_travels_as_one_sample_and_arrives_message_by_message(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    """What is published inside ``Bus.batch()`` leaves as one zenoh sample per topic; the
    receiver decodes, links and delivers each message on its own, in order, with its own seq
    and time, and a bad message inside a batch is rejected without losing its neighbours."""
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    samples: queue.Queue[bytes] = queue.Queue()
    rules = [LinkRule("nav-*", "nav/*/state", LinkSpec(delay=10.0))]
    key = f"ddvi/{run}/nav/deputy1/state"
    with Bus(hub, run, "controller", links=rules) as rx, Bus(svc, run, "nav-deputy1") as tx:
        probe: Inbox = queue.Queue()
        rx.subscribe("probe", queue_handler(probe))
        rx.subscribe("nav/*/state", queue_handler(inbox), expected_schema="nav")
        raw = hub.declare_subscriber(key, lambda s: samples.put(s.payload.to_bytes()))
        connect(tx, probe, "probe")
        before = rx.counters
        with tx.batch():
            seqs = [
                tx.publish("nav/deputy1/state", "nav", nav_body(k), 100.0 + k) for k in range(3)
            ]
            assert samples.empty() and inbox.empty()  # nothing leaves inside the block
        assert samples.get(timeout=TIMEOUT)[0] == 0x93  # one sample: an array of 3 payloads
        assert wait_until(lambda: rx.counters["delayed"] - before["delayed"] == 3)
        assert rx.pump(sim_time=110.0) == 1  # each message has its own due time on the link
        assert rx.pump(sim_time=112.0) == 2
        got = [inbox.get_nowait()[1] for _ in range(3)]
        assert [m.seq for m in got] == seqs and [m.t for m in got] == [100.0, 101.0, 102.0]
        assert tx.counters["sent"] - before["sent"] >= 3
        # a batch with garbage inside: each bad message is rejected, the good one delivered
        good = encode("nav", nav_body(7.0), seq=10**6, t=200.0, src="nav-deputy1")
        cmd = {"sc": "deputy1", "sigma": [0.0, 0.0, 0.1], "for_t": 0.0}
        wrong = encode("cmd", cmd, seq=0, t=0.0, src="intruder")
        svc.put(key, pack_batch([b"\xc1 not msgpack", wrong, good]))
        svc.put(key, b"\x92\xc4\x01a\x01")  # an array, but not of byte strings
        assert wait_until(lambda: rx.counters["rejected"] - before["rejected"] == 3)
        assert rx.pump(sim_time=210.0) == 1
        assert inbox.get_nowait()[1].seq == 10**6
        after = rx.counters
        assert after["rejected.malformed"] - before["rejected.malformed"] == 2
        assert after["rejected.wrong_schema"] - before["rejected.wrong_schema"] == 1
        raw.undeclare()


def test_batches_stay_within_their_bounds(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    """More than MAX_BATCH messages of a topic in one block leave as several batches, all
    delivered; a lone message leaves as itself."""
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    with Bus(hub, run, "controller") as rx, Bus(svc, run, "nav-deputy1") as tx:
        rx.subscribe("nav/*/state", queue_handler(inbox), expected_schema="nav")
        connect(tx, inbox, "nav/deputy1/state")
        n = 2 * MAX_BATCH + 5
        with tx.batch():
            for k in range(n):
                tx.publish("nav/deputy1/state", "nav", nav_body(k), float(k))
        got = [inbox.get(timeout=TIMEOUT)[1].t for _ in range(n)]
        assert got == [float(k) for k in range(n)]
    with pytest.raises(ValueError, match="at least one"):
        pack_batch([])
    with pytest.raises(MessageError, match="exceeds"):
        pack_batch([b"x"] * (MAX_BATCH + 1))


def test_handler_errors_are_contained(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    forward = queue_handler(inbox)

    def flaky(topic: str, msg: Message) -> None:
        if msg.t < 0:
            raise RuntimeError("handler bug")
        forward(topic, msg)

    with Bus(hub, run, "controller") as rx, Bus(svc, run, "nav-deputy1") as tx:
        rx.subscribe("nav/**", flaky)
        connect(tx, inbox, "nav/deputy1/state")
        tx.publish("nav/deputy1/state", "nav", nav_body(), t=-1.0)
        tx.publish("nav/deputy1/state", "nav", nav_body(), t=2.0)
        assert inbox.get(timeout=TIMEOUT)[1].t == 2.0
        assert rx.counters["handler_errors"] == 1


def test_link_model_holds_until_receiver_sim_time(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    hub, svc = sessions
    probe: Inbox = queue.Queue()
    inbox: Inbox = queue.Queue()
    with Bus(hub, run, "controller") as rx, Bus(svc, run, "nav-deputy1") as tx:
        rx.subscribe("probe", queue_handler(probe))
        link = LinkModel(LinkSpec(delay=10.0), seed=1, clock="sim")
        rx.subscribe("nav/deputy1/state", queue_handler(inbox), "nav", link=link)
        connect(tx, probe, "probe")
        tx.publish("nav/deputy1/state", "nav", nav_body(), t=0.0)
        assert wait_until(lambda: rx.counters["delayed"] == 1)
        assert inbox.empty()
        assert rx.pump(sim_time=9.0) == 0
        assert rx.pump(sim_time=10.0) == 1
        assert inbox.get_nowait()[1].schema == "nav"


def test_deployment_link_rules_apply_per_publisher(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    """A rule impairs only its publisher's messages; the observer sees every message, held or
    not; latency() reports the rule's nominal delay."""
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    seen: Inbox = queue.Queue()
    rules = [LinkRule("nav-deputy1", "nav/*/state", LinkSpec(delay=10.0))]
    with (
        Bus(hub, run, "controller", links=rules) as rx,
        Bus(svc, run, "nav-deputy1") as nav,
        Bus(svc, run, "nav-deputy2") as other,
    ):
        rx.subscribe("nav/*/state", queue_handler(inbox), "nav", observe=queue_handler(seen))
        assert rx.latency("nav-deputy1", "nav/deputy1/state") == 10.0
        assert rx.latency("nav-deputy2", "nav/deputy2/state") == 0.0
        connect(nav, seen, "nav/deputy1/state")
        while not seen.empty():
            seen.get_nowait()
        while not inbox.empty():
            inbox.get_nowait()
        rx.pump(sim_time=100.0)
        inbox.queue.clear()
        nav.publish("nav/deputy1/state", "nav", nav_body(1.0), t=200.0)
        other.publish("nav/deputy2/state", "nav", nav_body(2.0, "deputy2"), t=200.0)
        assert [seen.get(timeout=TIMEOUT)[1].src for _ in range(2)].count("nav-deputy1") == 1
        assert inbox.get(timeout=TIMEOUT)[1].src == "nav-deputy2"  # no rule: straight through
        assert inbox.empty()
        assert rx.pump(sim_time=209.0) == 0
        assert rx.pump(sim_time=210.0) == 1  # sent at 200, 10 s link
        assert inbox.get_nowait()[1].src == "nav-deputy1"


def test_a_message_refused_by_origin_is_not_observed_one_refused_by_number_is(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    """A message refused by its body's identity reaches neither the handler nor the observer
    (a lock-step wait must not count it as accounted for); one refused by the replay window
    reaches only the observer: a number proves nothing of who sent it, and a forged message
    that took the genuine one's number first must not leave a lock-step wait waiting."""
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    seen: Inbox = queue.Queue()
    key = f"ddvi/{run}/nav/deputy1/state"
    with Bus(hub, run, "controller") as rx, Bus(svc, run, "nav-deputy1") as nav:
        rx.subscribe("nav/deputy1/state", queue_handler(inbox), "nav", observe=queue_handler(seen))
        connect(nav, seen, "nav/deputy1/state")
        inbox.queue.clear()
        first = nav.publish("nav/deputy1/state", "nav", nav_body(1.0), t=100.0)
        nav.publish("nav/deputy1/state", "nav", nav_body(2.0), t=110.0)
        assert [seen.get(timeout=TIMEOUT)[1].t for _ in range(2)] == [100.0, 110.0]
        for payload in (
            encode("nav", nav_body(9.0), seq=first, t=100.0, src="nav-deputy1", boot=nav.boot),
            encode(
                "nav",
                nav_body(9.0, "deputy2"),
                seq=first + 2,
                t=120.0,
                src="nav-deputy1",
                boot=nav.boot,
            ),
        ):
            svc.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
        assert wait_until(lambda: rx.counters["rejected"] == 2)
        c = rx.counters
        assert c["rejected.duplicate"] == 1 and c["rejected.identity"] == 1
        assert seen.get(timeout=TIMEOUT)[1].seq == first  # the replay, accounted for
        assert seen.empty() and inbox.qsize() == 2  # handled: the two genuine ones only


def test_a_link_rule_added_at_run_time_takes_the_next_message(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    """A bus with no link rules passes messages straight through; a rule added while they
    flow (a link fault from the ground) impairs every later one, and one added before it on
    the same messages takes precedence."""
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    seen: Inbox = queue.Queue()
    with Bus(hub, run, "controller") as rx, Bus(svc, run, "nav-deputy1") as tx:
        rx.subscribe("nav/deputy1/state", queue_handler(inbox), "nav", observe=queue_handler(seen))
        connect(tx, inbox, "nav/deputy1/state")
        seen.queue.clear()
        tx.publish("nav/deputy1/state", "nav", nav_body(1.0), t=1.0)
        assert inbox.get(timeout=TIMEOUT)[1].t == 1.0
        rx.add_link_rule(LinkRule("nav-*", "nav/*/state", LinkSpec(loss=1.0)))
        for t in (2.0, 3.0, 4.0):
            tx.publish("nav/deputy1/state", "nav", nav_body(t), t=t)
        assert [seen.get(timeout=TIMEOUT)[1].t for _ in range(4)] == [1.0, 2.0, 3.0, 4.0]
        assert inbox.empty() and rx.counters["dropped"] == 3
        rx.add_link_rule(LinkRule("nav-deputy1", "nav/deputy1/state", LinkSpec()))
        tx.publish("nav/deputy1/state", "nav", nav_body(5.0), t=5.0)
        assert inbox.get(timeout=TIMEOUT)[1].t == 5.0 and rx.counters["dropped"] == 3


def test_a_replay_on_a_wildcard_key_meets_the_topic_replay_window(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    """zenoh hands a put on a wildcard key to every subscription it intersects: to one on a
    plain key it is a message on that topic, and a recorded message put again that way is a
    replay like any other."""
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    with Bus(hub, run, "controller") as rx, Bus(svc, run, "nav-deputy1") as tx:
        rx.subscribe("nav/deputy1/state", queue_handler(inbox), "nav")
        connect(tx, inbox, "nav/deputy1/state")
        seq = tx.publish("nav/deputy1/state", "nav", nav_body(1.0), t=1.0)
        assert inbox.get(timeout=TIMEOUT)[1].seq == seq
        replay = encode("nav", nav_body(1.0), seq=seq, t=1.0, src="nav-deputy1", boot=tx.boot)
        for key in (f"ddvi/{run}/nav/*/state", f"ddvi/{run}/**"):
            svc.put(key, replay, congestion_control=zenoh.CongestionControl.BLOCK)
        assert wait_until(lambda: rx.counters["rejected.duplicate"] == 2)
        fresh = encode("nav", nav_body(2.0), seq=seq + 1, t=2.0, src="nav-deputy1", boot=tx.boot)
        svc.put(f"ddvi/{run}/nav/*/state", fresh, congestion_control=zenoh.CongestionControl.BLOCK)
        assert inbox.get(timeout=TIMEOUT)[0] == "nav/deputy1/state"
        assert inbox.empty()


def test_liveliness(sessions: tuple[zenoh.Session, zenoh.Session], run: str) -> None:
    hub, svc = sessions
    tx = Bus(svc, run, "nav-deputy1")
    try:
        tx.declare_alive()
        assert wait_for_alive(hub, run, ["nav-deputy1"], TIMEOUT) == {"nav-deputy1"}
        assert wait_for_alive(hub, run, ["nav-deputy1", "ghost"], 0.2) == {"nav-deputy1"}
    finally:
        tx.close()
    assert wait_until(lambda: wait_for_alive(hub, run, ["nav-deputy1"], 0.05) == set())


def test_publish_validates_and_closed_bus_refuses(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    _, svc = sessions
    tx = Bus(svc, run, "nav-deputy1")
    with pytest.raises(MessageError) as info:
        tx.publish("nav/deputy1/state", "nav", {"sc": "deputy1"}, t=0.0)
    assert info.value.reason == "bad_field"
    assert tx.publish("nav/deputy1/state", "nav", nav_body(), t=0.0) == 0  # seq not consumed
    with pytest.raises(ValueError, match="topic"):
        tx.publish("nav/*/state", "nav", nav_body(), t=0.0)
    tx.close()
    tx.close()  # idempotent
    with pytest.raises(RuntimeError, match="closed"):
        tx.publish("nav/deputy1/state", "nav", nav_body(), t=0.0)
    assert tx.counters["sent"] == 1


def test_sequence_guard_accepts_each_seq_once_in_any_order() -> None:
    guard = SequenceGuard(window=4)
    assert [guard.check(s) for s in (0, 2, 1, 3)] == [None] * 4  # reordered: fine
    assert guard.check(2) == "duplicate"
    assert guard.check(10) is None
    assert guard.check(1) == "stale"  # behind the window: a replay
    assert guard.check(7) is None  # inside the window, not seen yet
    assert guard.check(7) == "duplicate"
    with pytest.raises(ValueError, match="window"):
        SequenceGuard(window=0)
    with pytest.raises(ValueError, match="ahead"):
        SequenceGuard(ahead=0)


def test_one_far_sequence_number_never_moves_the_window() -> None:
    """A number no publisher of the boot has reached (a stolen credential's 2^64 - 1, then
    2^62) is refused as a jump and leaves the mark where it was: the genuine traffic after it
    is taken; what the receiver knows it missed (its budget's drops) widens the reach, and a
    publisher that really is that far on is followed after ``JUMP_CONFIRM`` in a row."""
    guard = SequenceGuard()
    assert [guard.check(s) for s in range(10)] == [None] * 10
    assert guard.check(2**64 - 1) == "jump"
    assert guard.check(2**62) == "jump"
    assert [guard.check(s) for s in range(10, 20)] == [None] * 10
    assert guard.check(19 + REPLAY_WINDOW) is None  # within reach
    assert guard.check(19 + 2 * REPLAY_WINDOW + 100, slack=100) is None  # it missed 100
    far = 10_000
    assert [guard.check(far + k) for k in range(JUMP_CONFIRM)] == ["jump"] * (JUMP_CONFIRM - 1) + [
        None
    ]
    assert guard.check(far + JUMP_CONFIRM) is None
    assert guard.check(far - REPLAY_WINDOW) == "stale"
    behind_a_link = SequenceGuard(ahead=None)
    assert [behind_a_link.check(s) for s in (0, 2**62, 2**62 + 1)] == [None] * 3


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 8),
    st.integers(1, 8),
    st.lists(st.integers(0, 60), max_size=80),
)
def test_sequence_guard_matches_its_definition(window: int, ahead: int, arrivals: list) -> None:
    """The guard's bit mask against the plain words of its docstring, on any arrivals: each
    seq once, none at or below highest - window, none past highest + ahead unless it ends
    ``JUMP_CONFIRM`` consecutive such numbers (the window then follows it)."""
    guard = SequenceGuard(window=window, ahead=ahead)
    seen: set[int] = set()
    highest = -1
    run: list[int] = []
    for seq in arrivals:
        if highest >= 0 and seq - highest > ahead:
            run = [*run, seq] if run and seq == run[-1] + 1 else [seq]
            if len(run) < JUMP_CONFIRM:
                assert guard.check(seq) == "jump", seq
                continue
            seen, highest = set(), seq - 1
        run = []
        if seq <= highest - window:
            want = "stale"
        elif seq in seen:
            want = "duplicate"
        else:
            want = None
            seen.add(seq)
            highest = max(highest, seq)
        assert guard.check(seq) == want, seq


def test_each_boot_of_a_publisher_has_its_own_window() -> None:
    """A restarted publisher counts from 0 under a new boot and is taken at once; a message
    that claims another boot, however far its number, cannot touch the window of the boot in
    flight; a bounded number of boots is kept."""
    guards = SequenceGuards()

    def msg(seq: int, boot: int) -> Message:
        return Message("nav", 2, seq, float(seq), "nav-deputy1", {}, boot)

    assert [guards.check(msg(s, 1), "nav/deputy1/state") for s in range(300)] == [None] * 300
    assert guards.check(msg(0, 2), "nav/deputy1/state") is None  # restarted
    assert guards.check(msg(2**64 - 1, 3), "nav/deputy1/state") is None  # a boot of its own
    assert guards.check(msg(300, 1), "nav/deputy1/state") is None  # boot 1 goes on
    assert guards.check(msg(299, 1), "nav/deputy1/state") == "duplicate"
    assert guards.check(msg(1, 2), "nav/deputy1/state") is None
    assert guards.check(msg(1, 1), "nav/deputy2/state") is None  # another topic, another window
    for boot in range(100, 100 + BOOTS_KEPT):  # as many boots as are kept push boot 1 out
        guards.check(msg(0, boot), "nav/deputy1/state")
    assert guards.check(msg(5, 1), "nav/deputy1/state") is None  # forgotten: a new window


def test_replays_and_link_duplicates_are_refused_once_counted(
    sessions: tuple[zenoh.Session, zenoh.Session], run: str
) -> None:
    """A recorded message put again (a replay, recent or old) and the copies a duplicating
    link makes reach no handler; each is counted by reason, and every original arrives."""
    hub, svc = sessions
    inbox: Inbox = queue.Queue()
    dups: Inbox = queue.Queue()
    probe: Inbox = queue.Queue()
    key = f"ddvi/{run}/nav/deputy1/state"
    rules = [LinkRule("nav-*", "nav/deputy2/state", LinkSpec(duplicate=1.0))]
    with (
        Bus(hub, run, "controller", links=rules) as rx,
        Bus(svc, run, "nav-deputy1") as tx,
        Bus(svc, run, "nav-deputy2") as tx2,
    ):
        rx.subscribe("probe", queue_handler(probe))
        rx.subscribe("nav/deputy1/state", queue_handler(inbox), "nav")
        rx.subscribe("nav/deputy2/state", queue_handler(dups), "nav")
        connect(tx, probe, "probe")
        first = encode("nav", nav_body(1.0), seq=0, t=10.0, src="nav-deputy1", boot=tx.boot)
        for payload in (first, first):  # the second is a replay
            svc.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
        assert inbox.get(timeout=TIMEOUT)[1].seq == 0
        assert wait_until(lambda: rx.counters["rejected.duplicate"] == 1)
        tx._out.seq["nav/deputy1/state"] = 1  # the raw put above took seq 0
        for seq in range(1, 300):
            tx.publish("nav/deputy1/state", "nav", nav_body(3.0), t=10.0 + seq)
        assert [inbox.get(timeout=TIMEOUT)[1].seq for _ in range(299)] == list(range(1, 300))
        old = encode("nav", nav_body(2.0), seq=5, t=15.0, src="nav-deputy1", boot=tx.boot)
        svc.put(key, old, congestion_control=zenoh.CongestionControl.BLOCK)
        assert wait_until(lambda: rx.counters["rejected.stale"] == 1)
        for _ in range(5):  # at t = 0: due at once, each with its copy
            tx2.publish("nav/deputy2/state", "nav", nav_body(4.0, "deputy2"), t=0.0)
        assert [dups.get(timeout=TIMEOUT)[1].seq for _ in range(5)] == list(range(5))
        assert wait_until(lambda: rx.counters["rejected.duplicate"] == 1 + 5)
        c = rx.counters
        assert c["duplicated"] == 5
        assert c["rejected"] == 1 + 5 + 1
        assert inbox.empty() and dups.empty()
