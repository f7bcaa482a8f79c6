"""services.bus.security: credentials, the access control made from the topology, and a real
router in this process that enforces them (authentication at connect, puts by user)."""

from __future__ import annotations

import math
import queue
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from services.bus import BusSettings, open_session, zenoh_config
from services.bus.guards import check_origin
from services.bus.security import (
    DICTIONARY,
    OBSERVER,
    OPERATOR,
    ROUTER,
    SECURITY_DIR,
    Credentials,
    access_control,
    credentials_path,
    issue_credentials,
    issue_tls,
    load_credentials,
)
from services.ground.launch.launcher import free_port
from services.interface import Message, encode
from services.interface.topics import may_publish, topic_identity
from tests.support import wait_until

RUN = "sec"
USERS = ["environment", "nav-lqr", "ctrl-lqr", "monitor", OPERATOR, OBSERVER]


def _puts(acl: dict, user: str) -> list[str]:
    """The keys ``user`` may put, per the access control block."""
    rules = {r["id"]: r for r in acl["rules"]}
    keys = []
    for policy in acl["policies"]:
        subjects = [s for s in acl["subjects"] if s["id"] in policy["subjects"]]
        if any(user in s["usernames"] for s in subjects):
            for rule in map(rules.get, policy["rules"]):
                if "put" in rule["messages"] and rule["flows"] == ["ingress"]:
                    keys += rule["key_exprs"]
    return keys


def test_access_control_gives_each_user_its_topics_only() -> None:
    acl = access_control(RUN, USERS)
    assert acl["enabled"] and acl["default_permission"] == "deny"
    p = f"ddvi/{RUN}/"
    assert sorted(_puts(acl, "nav-lqr")) == [
        p + "log/nav-lqr",
        p + "nav/lqr/state",
        p + "stats/nav-lqr",
    ]
    assert set(_puts(acl, "ctrl-lqr")) == {
        p + "cmd/lqr/att",
        p + "ctrl/lqr/gains",
        p + "ctrl/lqr/status",
        p + "stats/ctrl-lqr",
        p + "log/ctrl-lqr",
    }
    assert {p + "clock", p + "exo/state", p + "truth/*"} <= set(_puts(acl, "environment"))
    assert set(_puts(acl, OPERATOR)) == {
        p + f"fault/{k}" for k in ("kill", "panel", "bias", "outage", "link")
    }
    assert _puts(acl, OBSERVER) == []
    assert set(_puts(acl, "monitor")) == {p + "recorded", p + "stats/monitor", p + "log/monitor"}
    assert not any("fault" in k for u in USERS if u != OPERATOR for k in _puts(acl, u))


def test_the_ros2_gateway_puts_its_stats_log_and_the_commands_of_ros2_deputies_only() -> None:
    p = f"ddvi/{RUN}/"
    own = {p + "stats/ros2-gateway", p + "log/ros2-gateway"}
    acl = access_control(RUN, [*USERS, "ros2-gateway"])
    assert set(_puts(acl, "ros2-gateway")) == own  # it flies nobody
    tokens = [r["key_exprs"] for r in acl["rules"] if r["id"] == "alive ros2-gateway"]
    assert tokens == [[p + "alive/ros2-gateway"]]
    flying = access_control(RUN, [*USERS, "ros2-gateway"], ["rosd"])
    assert set(_puts(flying, "ros2-gateway")) == own | {p + "cmd/rosd/att"}
    assert set(_puts(flying, "ctrl-lqr")) == set(_puts(acl, "ctrl-lqr"))


def test_credentials_are_private_files_never_alike(tmp_path: Path) -> None:
    issued = issue_credentials(tmp_path, ["nav-lqr", "ctrl-lqr"])
    assert set(issued) == {"nav-lqr", "ctrl-lqr", ROUTER}
    assert len({c.password for c in issued.values()}) == 3
    assert issued["nav-lqr"].password not in repr(issued["nav-lqr"])
    folder = tmp_path / SECURITY_DIR
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    for path in folder.iterdir():
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path
    assert load_credentials(credentials_path(tmp_path, "nav-lqr")) == issued["nav-lqr"]
    lines = (folder / DICTIONARY).read_text().splitlines()
    assert sorted(lines) == sorted(f"{c.user}:{c.password}" for c in issued.values())
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(ValueError, match="not a credentials file"):
        load_credentials(tmp_path / "bad.json")


def _msg(src: str, t: float = 60.0, sc: str = "lqr", **body: float) -> Message:
    return Message("cmd", 1, 0, t, src, {"sc": sc, **body})


def test_origin_check_refuses_another_publisher_and_times_outside_the_window() -> None:
    window = (-120.0, 8220.0)
    assert check_origin(_msg("ctrl-lqr", for_t=120.0), "cmd/lqr/att", window) is None
    assert check_origin(_msg("intruder", for_t=120.0), "cmd/lqr/att", window) == "src"
    assert check_origin(_msg("ctrl-ddvi", for_t=120.0), "cmd/lqr/att", window) == "src"
    assert check_origin(_msg("ctrl-lqr", for_t=1e12), "cmd/lqr/att", window) == "time"
    assert check_origin(_msg("ctrl-lqr", t=1e12, for_t=60.0), "cmd/lqr/att", window) == "time"
    assert check_origin(_msg("ctrl-lqr", t=-1e6), "cmd/lqr/att", window) == "time"
    assert check_origin(_msg("ctrl-lqr", for_t=math.inf), "cmd/lqr/att", window) == "time"
    assert check_origin(_msg("ctrl-lqr", for_t=1e12), "cmd/lqr/att") is None  # no window
    assert check_origin(_msg("anyone"), "probe", window) is None  # outside the topology
    # the owner of cmd/lqr/att speaks for lqr only: a command naming another deputy is refused
    assert check_origin(_msg("ctrl-lqr", sc="ddvi", for_t=120.0), "cmd/lqr/att") == "identity"
    stats = Message("stats", 1, 0, 60.0, "nav-lqr", {"service": "environment", "counters": {}})
    assert check_origin(stats, "stats/nav-lqr") == "identity"
    assert check_origin(stats, "stats/environment") == "src"
    assert topic_identity("truth/chief") == (("sc", "chief"),)
    assert topic_identity("stats/nav-lqr") == (("service", "nav-lqr"),)
    assert topic_identity("clock") == () and topic_identity("fault/panel") == ()
    assert may_publish("ground-4242", "fault/kill") and not may_publish("ctrl-lqr", "fault/kill")
    assert may_publish("environment", "clock") and not may_publish("nav-evil", "clock")


@pytest.fixture
def router(tmp_path: Path) -> Iterator[tuple[str, dict[str, Credentials]]]:
    """A router in this process with the run's dictionary and access control."""
    issued = issue_credentials(tmp_path, USERS)
    hub = f"tcp/127.0.0.1:{free_port()}"
    settings = BusSettings(
        mode="router",
        listen=[hub],
        connect=[],
        user=ROUTER,
        password=issued[ROUTER].password,
        dictionary=str(tmp_path / SECURITY_DIR / DICTIONARY),
        access_control=_with_observer_marker(access_control(RUN, USERS)),
    )
    with open_session(settings):
        yield hub, issued


OBSERVER_MARKER = f"ddvi/{RUN}/marker/{OBSERVER}"
"""A key the test's router lets the observer put on, and nothing else: the subscribe-only user
has no topic of its own to say "my forgeries went before this" on."""


def _with_observer_marker(acl: dict) -> dict:
    """The run's access control with one rule more: the observer may put ``OBSERVER_MARKER``
    (an allow rule adds a key; every other key stays denied by default)."""
    acl["rules"].append(
        {
            "id": "observer marker",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["put"],
            "key_exprs": [OBSERVER_MARKER],
        }
    )
    acl["subjects"].append({"id": "observer marker", "usernames": [OBSERVER]})
    acl["policies"].append(
        {"id": "observer marker", "rules": ["observer marker"], "subjects": ["observer marker"]}
    )
    return acl


def _client(hub: str, cred: Credentials | None) -> BusSettings:
    if cred is None:
        return BusSettings(mode="client", listen=[], connect=[hub])
    return BusSettings(
        mode="client",
        listen=[],
        connect=[hub],
        user=cred.user,
        password=cred.password,
        tls=cred.tls,
    )


def test_router_refuses_strangers_and_drops_puts_outside_a_users_topics(
    router: tuple[str, dict[str, Credentials]],
) -> None:
    hub, issued = router
    for stranger in (None, Credentials("nav-lqr", "guessed"), Credentials("intruder", "x")):
        with pytest.raises(zenoh.ZError):
            zenoh.open(zenoh_config(_client(hub, stranger)))
    got: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    p = f"ddvi/{RUN}/"
    with (
        open_session(_client(hub, issued["monitor"])) as mon,
        open_session(_client(hub, issued["ctrl-lqr"])) as ctrl,
        open_session(_client(hub, issued["nav-lqr"])) as nav,
        open_session(_client(hub, issued[OBSERVER])) as observer,
    ):
        sub = mon.declare_subscriber(
            p + "**", lambda s: got.put((str(s.key_expr), bytes(s.payload.to_bytes())))
        )
        alive: list[str] = []
        token_sub = mon.liveliness().declare_subscriber(
            p + "alive/*", lambda s: alive.append(str(s.key_expr)), history=True
        )
        genuine = encode(
            "cmd",
            {"sc": "lqr", "sigma": [0.0, 0.0, 0.1], "for_t": 60.0},
            seq=0,
            t=0.0,
            src="ctrl-lqr",
        )
        assert wait_until(lambda: (ctrl.put(p + "cmd/lqr/att", genuine), not got.empty())[1])
        while not got.empty():
            got.get_nowait()
        nav.put(p + "cmd/lqr/att", b"nav forges a command")
        observer.put(p + "cmd/lqr/att", b"the observer forges one")
        ctrl.put(p + "truth/lqr", b"ctrl forges the truth")
        ctrl.put(p + "fault/kill", b"ctrl kills")
        nav.put(p + "clock", b"nav ends the mission")
        tokens = [
            nav.liveliness().declare_token(p + "alive/ctrl-lqr"),
            nav.liveliness().declare_token(p + "alive/nav-lqr"),
        ]
        # each forger's marker, put after its forgeries on the same link: a forgery the router
        # let through would reach the monitor before its sender's marker
        after = encode(
            "cmd",
            {"sc": "lqr", "sigma": [0.0, 0.0, 0.2], "for_t": 120.0},
            seq=1,
            t=60.0,
            src="ctrl-lqr",
        )
        puts = [
            (nav, p + "nav/lqr/state", b"nav's own state, after its forgeries"),
            (observer, OBSERVER_MARKER, b"the observer's marker, after its forgery"),
            (ctrl, p + "cmd/lqr/att", after),  # ctrl-lqr's next genuine command
        ]
        for session, key, payload in puts:
            session.put(key, payload)
        markers = {(key, payload) for _, key, payload in puts}
        heard: list[tuple[str, bytes]] = []
        while not markers <= set(heard):
            heard.append(got.get(timeout=5.0))
        # nothing but the markers and late copies of the first genuine command
        assert set(heard) - markers <= {(p + "cmd/lqr/att", genuine)}, heard
        # nav's token for itself comes after its token for ctrl-lqr, which is not declared
        assert wait_until(lambda: p + "alive/nav-lqr" in alive), alive
        assert alive == [p + "alive/nav-lqr"]
        for token in tokens:
            token.undeclare()
        sub.undeclare()
        token_sub.undeclare()


def test_tls_links_need_the_runs_certificates_and_a_password(tmp_path: Path) -> None:
    """A router on a TLS endpoint (what another host reaches) takes a client holding the
    run's client certificate and its credentials; one without the certificate, or with it but
    a wrong password, is refused at connect."""
    router_tls, client_tls = issue_tls(tmp_path, ["127.0.0.1"])
    issued = issue_credentials(tmp_path, USERS, client_tls)
    for name in ("ca.pem", "router.key", "client.key"):
        assert stat.S_IMODE((tmp_path / SECURITY_DIR / name).stat().st_mode) == 0o600
    assert load_credentials(credentials_path(tmp_path, "nav-lqr")).tls == client_tls
    hub = f"tls/127.0.0.1:{free_port()}"
    router = BusSettings(
        mode="router",
        listen=[hub],
        connect=[],
        user=ROUTER,
        password=issued[ROUTER].password,
        dictionary=str(tmp_path / SECURITY_DIR / DICTIONARY),
        access_control=access_control(RUN, USERS),
        tls=router_tls,
    )
    nav = issued["nav-lqr"]
    no_certificate = {"root_ca_certificate": client_tls["root_ca_certificate"]}
    with open_session(router) as r:
        got: queue.SimpleQueue[bytes] = queue.SimpleQueue()
        sub = r.declare_subscriber(f"ddvi/{RUN}/**", lambda s: got.put(s.payload.to_bytes()))
        for tls, password in ((no_certificate, nav.password), (client_tls, "guessed")):
            with pytest.raises(zenoh.ZError):
                zenoh.open(
                    zenoh_config(
                        BusSettings(
                            mode="client",
                            listen=[],
                            connect=[hub],
                            user=nav.user,
                            password=password,
                            tls=tls,
                        )
                    )
                )
        with open_session(_client(hub, nav)) as s:
            assert wait_until(lambda: (s.put(f"ddvi/{RUN}/nav/lqr/state", b"x"), got.qsize())[1])
        sub.undeclare()
