"""Topic names below ``ddvi/<run>/`` and the topology of the flight system.

One function (or constant) builds each topic name, so no service spells a topic by hand.  A
deputy's or a service's name is one key chunk (``check_name`` in the bus refuses ``/`` and
wildcards), so each function below returns a key with no wildcards.

``TOPIC_SCHEMAS`` and ``schema_for_topic`` say which message type a topic carries.
``TOPOLOGY`` says, as data, who publishes and who subscribes each topic and how often (the
basis of access control: ``topics_published_by``, ``topics_subscribed_by``); ``SERVICES``
names every kind of participant.  ``python -m services.interface.reference`` renders them into
``docs/interface.md``.
"""

from __future__ import annotations

import functools
import itertools
import re
from dataclasses import dataclass

from services.interface.keys import PatternError, check_pattern, key_matches

CLOCK = "clock"
"""The environment's simulation clock (``final = true`` ends the mission)."""

EXOSTATE = "exo/state"
"""The exosystem state v(t) the controllers regulate against."""

RECORDED = "recorded"
"""The monitor's acknowledgement of what it has recorded (lock-step waits for the recorder)."""

ROS2_GATEWAY = "ros2-gateway"
"""The service that carries a run's topics to ROS 2 (a deployment's ``[ros2]``)."""


def truth_topic(craft: str) -> str:
    """``truth/<craft>``: the environment's inertial state of one craft (chief or deputy)."""
    return f"truth/{craft}"


def nav_state_topic(deputy: str) -> str:
    """``nav/<deputy>/state``: navigation's relative Hill state of one deputy."""
    return f"nav/{deputy}/state"


def command_topic(deputy: str) -> str:
    """``cmd/<deputy>/att``: a controller's attitude command for one deputy."""
    return f"cmd/{deputy}/att"


def command_deputy(topic: str) -> str | None:
    """The deputy a command topic ``cmd/<deputy>/att`` is for; None for any other topic."""
    parts = topic.split("/")
    if len(parts) == 3 and parts[0] == "cmd" and parts[2] == "att" and parts[1]:
        return parts[1]
    return None


def gains_topic(deputy: str) -> str:
    """``ctrl/<deputy>/gains``: the gains (K, L) a deputy's controller flies."""
    return f"ctrl/{deputy}/gains"


def status_topic(deputy: str) -> str:
    """``ctrl/<deputy>/status``: a controller's mode, phase and learning progress."""
    return f"ctrl/{deputy}/status"


def fault_topic(kind: str) -> str:
    """``fault/<kind>``: a fault the ground injects (kill, panel, bias, outage, link)."""
    return f"fault/{kind}"


def stats_topic(service: str) -> str:
    """``stats/<service>``: a service's counters (received, rejected, late, ...)."""
    return f"stats/{service}"


def log_topic(service: str) -> str:
    """``log/<service>``: a service's log lines, for the ground."""
    return f"log/{service}"


def alive_topic(service: str) -> str:
    """``alive/<service>``: a service's liveliness token (a zenoh liveliness key, no payload)."""
    return f"alive/{service}"


# ---- which schema each topic carries ---------------------------------------------------------

TOPIC_SCHEMAS: tuple[tuple[str, str], ...] = (
    ("clock", "clock"),
    ("exo/state", "exo"),
    ("truth/*", "truth"),
    ("nav/*/state", "nav"),
    ("cmd/*/att", "cmd"),
    ("ctrl/*/gains", "gains"),
    ("ctrl/*/status", "status"),
    ("fault/*", "fault"),
    ("recorded", "recorded"),
    ("stats/*", "stats"),
    ("log/*", "log"),
)
"""Which schema each topic (below ``ddvi/<run>/``) carries (docs/design.md, "The bus"): ``*`` is
one key chunk (``services.interface.keys``)."""


@functools.lru_cache(maxsize=4096)  # a run has a few dozen topics; garbage may add more
def schema_for_topic(topic: str) -> str | None:
    """The schema a topic carries (``TOPIC_SCHEMAS``), None for a topic outside the table or
    one that is not a key (a wildcard, an empty chunk)."""
    try:
        check_pattern(topic)
    except PatternError:
        return None
    if "*" in topic:
        return None
    return next((schema for pattern, schema in TOPIC_SCHEMAS if key_matches(pattern, topic)), None)


# ---- the topology: who publishes and who subscribes each topic -------------------------------
# In the names below, <sc> is a deputy's name, <craft> the chief or a deputy, <service> the
# publishing service's own name and <pid> a ground command's process id.


@dataclass(frozen=True)
class ServiceName:
    """A kind of bus participant: its name (a template with placeholders) and its job."""

    name: str
    module: str
    doc: str


SERVICES: tuple[ServiceName, ...] = (
    ServiceName("environment", "services.flight.environment", "the truth and the time master"),
    ServiceName("nav-<sc>", "services.flight.navigation", "one deputy's relative navigation"),
    ServiceName(
        "ctrl-<sc>",
        "services.flight.controller",
        "one deputy's controller, the software under test",
    ),
    ServiceName(
        "monitor",
        "services.ground.monitoring.monitor",
        "the ground: records every message, writes the report",
    ),
    ServiceName(
        "launcher",
        "services.ground.launch.launcher",
        "starts and supervises the services; acts on kills",
    ),
    ServiceName(
        "ground-<pid>", "services.ground.launch.faults", "an operator's `ddvi fault` command"
    ),
    ServiceName(
        ROS2_GATEWAY,
        "services.ros2.gateway.service",
        "carries the run's topics to ROS 2 over rmw_zenoh (`ddvi run --ros2`, docs/ros2.md)",
    ),
)
"""Every kind of participant on the bus, by name."""

_EVERY_SERVICE = ("environment", "nav-<sc>", "ctrl-<sc>", "monitor", "launcher", ROS2_GATEWAY)
# what services.flight.runtime runs
_FLIGHT_RUNTIME = ("environment", "nav-<sc>", "ctrl-<sc>", "monitor", ROS2_GATEWAY)


@dataclass(frozen=True)
class Route:
    """One topic of the flight system: the schema it carries, the services that publish and
    subscribe it (``ServiceName`` templates) and how often it is published, in words."""

    topic: str
    schema: str
    publishers: tuple[str, ...]
    subscribers: tuple[str, ...]
    rate: str
    # the rate as a period its receivers budget each publisher by (services.bus.budget):
    # "nav" (run.nav_period, or a deputy's shorter one), "fsw" (run.fsw_period), "status"
    # (run.status_every flight-software steps); at most one message a period, sustained
    budget: str = "nav"
    identity: tuple[tuple[str, str], ...] = ()
    """(body field, topic placeholder) pairs: the body's field must name what the topic names
    (a command on ``cmd/<sc>/att`` is for deputy <sc>, whatever else its body says)."""


_DEPUTY = (("sc", "sc"),)  # the body's deputy is the topic's
_SERVICE = (("service", "service"),)  # the body's service is the topic's (its publisher)

TOPOLOGY: tuple[Route, ...] = (
    Route(
        CLOCK,
        "clock",
        ("environment",),
        ("nav-<sc>", "ctrl-<sc>", "monitor", "launcher", "ground-<pid>", ROS2_GATEWAY),
        "every flight-software step (run.fsw_period) in lock-step, every navigation sample "
        "(run.nav_period) in real time, and a final one",
        budget="nav",
    ),
    Route(
        EXOSTATE,
        "exo",
        ("environment",),
        ("ctrl-<sc>", "monitor"),
        "every navigation sample (run.nav_period)",
    ),
    Route(
        truth_topic("<craft>"),
        "truth",
        ("environment",),
        ("nav-<sc>", "monitor", ROS2_GATEWAY),
        "every navigation sample (run.nav_period), for the chief and every deputy; "
        "nav-<sc> takes truth/chief and truth/<sc>",
        identity=(("sc", "craft"),),
    ),
    Route(
        nav_state_topic("<sc>"),
        "nav",
        ("nav-<sc>",),
        ("ctrl-<sc>", "monitor", ROS2_GATEWAY),
        "every navigation sample of the deputy (its navigation.period)",
        identity=_DEPUTY,
    ),
    Route(
        command_topic("<sc>"),
        "cmd",
        ("ctrl-<sc>", ROS2_GATEWAY),
        ("environment", "monitor", ROS2_GATEWAY),
        "every flight-software step (run.fsw_period); the ROS 2 gateway's for a deputy flown "
        "from ROS 2 (controller = ros2), its controller's for any other",
        budget="fsw",
        identity=_DEPUTY,
    ),
    Route(
        gains_topic("<sc>"),
        "gains",
        ("ctrl-<sc>",),
        ("monitor", ROS2_GATEWAY),
        "at the start, every flight-software step while exploring, on learning, and at the end",
        budget="fsw",
        identity=_DEPUTY,
    ),
    Route(
        status_topic("<sc>"),
        "status",
        ("ctrl-<sc>",),
        ("monitor", ROS2_GATEWAY),
        "every run.status_every flight-software steps, and at the end",
        budget="status",
        identity=_DEPUTY,
    ),
    Route(
        fault_topic("kill"),
        "fault",
        ("ground-<pid>",),
        ("launcher", "monitor"),
        "on an operator's command (ddvi fault RUN kill)",
        budget="fsw",
    ),
    Route(
        fault_topic("panel"),
        "fault",
        ("ground-<pid>",),
        ("environment", "monitor"),
        "on an operator's command (ddvi fault RUN panel)",
        budget="fsw",
    ),
    Route(
        fault_topic("bias"),
        "fault",
        ("ground-<pid>",),
        ("nav-<sc>", "monitor"),
        "on an operator's command (ddvi fault RUN bias)",
        budget="fsw",
    ),
    Route(
        fault_topic("outage"),
        "fault",
        ("ground-<pid>",),
        ("nav-<sc>", "monitor"),
        "on an operator's command (ddvi fault RUN outage)",
        budget="fsw",
    ),
    Route(
        fault_topic("link"),
        "fault",
        ("ground-<pid>",),
        _FLIGHT_RUNTIME,
        "on an operator's command (ddvi fault RUN link)",
        budget="fsw",
    ),
    Route(
        RECORDED,
        "recorded",
        ("monitor",),
        ("environment", "monitor"),
        "in lock-step, once the monitor has recorded the clock of every RECORDER_ACK_STEPS-th "
        "flight-software step (services.flight.health)",
        budget="fsw",
    ),
    Route(
        stats_topic("<service>"),
        "stats",
        _EVERY_SERVICE,
        ("monitor", ROS2_GATEWAY),
        "every run.status_every flight-software steps (environment, controllers), after every "
        "restart or kill (launcher), and at each service's end",
        budget="status",
        identity=_SERVICE,
    ),
    Route(
        log_topic("<service>"),
        "log",
        _EVERY_SERVICE,
        ("monitor", "ground-<pid>", ROS2_GATEWAY),
        "on an event: a fault acted on, a learning outcome, a warning",
        identity=_SERVICE,
    ),
)
"""Every topic below ``ddvi/<run>/``: its schema, publishers, subscribers and rate.  The
monitor subscribes to every topic (``ddvi/<run>/**``) and records it."""

_PLACEHOLDER = re.compile(r"<([a-z]+)>")


@functools.lru_cache(maxsize=256)
def _name_pattern(template: str) -> re.Pattern[str]:
    """A ``ServiceName`` template as a regular expression, one group per placeholder."""
    parts = _PLACEHOLDER.split(template)  # literal, name, literal, name, ..., literal
    return re.compile(
        "".join(re.escape(p) if i % 2 == 0 else f"(?P<{p}>.+)" for i, p in enumerate(parts))
    )


def _fill(template: str, names: dict[str, str]) -> str:
    """A topic template with its placeholders from ``names``, any other as ``*``."""
    return _PLACEHOLDER.sub(lambda m: names.get(m.group(1), "*"), template)


def _keys(service: str, role: str) -> tuple[str, ...]:
    """The topics (key expressions, unknown placeholders as ``*``) that ``service`` has a
    ``role`` ("publishers" or "subscribers") in, in table order."""
    out: list[str] = []
    for route in TOPOLOGY:
        for template in getattr(route, role):
            match = _name_pattern(template).fullmatch(service)
            if match is None:
                continue
            names = match.groupdict()
            if role == "publishers":  # <service> in a topic is its publisher's own name
                names["service"] = service
            key = _fill(route.topic, names)
            if key not in out:
                out.append(key)
    return tuple(out)


def topics_published_by(service: str) -> tuple[str, ...]:
    """The topics ``service`` (a bus service name, e.g. ``nav-deputy1``) may publish, as key
    expressions below ``ddvi/<run>/`` (``*`` for any craft); () for a name of no service."""
    return _keys(service, "publishers")


def topics_subscribed_by(service: str) -> tuple[str, ...]:
    """The topics ``service`` subscribes, as key expressions below ``ddvi/<run>/``."""
    return _keys(service, "subscribers")


def concrete_topics(names: dict[str, list[str]]) -> dict[str, str]:
    """Every TOPOLOGY topic with its placeholders filled in every way ``names`` allows
    (placeholder -> the names it stands for, e.g. ``{"craft": ["chief", "lqr"], "sc": ["lqr"],
    "service": [...]}``), and the schema it carries; a topic with a placeholder ``names`` lacks
    is left out."""
    out: dict[str, str] = {}
    for route in TOPOLOGY:
        keys = _PLACEHOLDER.findall(route.topic)
        for values in itertools.product(*(names.get(k, []) for k in keys)):
            out[_fill(route.topic, dict(zip(keys, values, strict=True)))] = route.schema
    return out


@functools.lru_cache(maxsize=256)
def _topic_pattern(template: str) -> re.Pattern[str]:
    """A TOPOLOGY topic template as a regular expression, one key chunk per placeholder."""
    return re.compile(_PLACEHOLDER.sub("[^/]+", re.escape(template).replace(r"\<", "<")))


@functools.lru_cache(maxsize=4096)  # (publisher, topic) pairs of a run: a few dozen
def may_publish(service: str, topic: str) -> bool | None:
    """Whether the topology lets ``service`` publish ``topic`` (a concrete topic below
    ``ddvi/<run>/``, e.g. ``cmd/lqr/att``): True, False (the topic is another's), or None for a
    topic outside the topology (nobody owns it)."""
    owned = False
    for route in TOPOLOGY:
        if not _topic_pattern(route.topic).fullmatch(topic):
            continue
        owned = True
        for template in route.publishers:
            match = _name_pattern(template).fullmatch(service)
            if match is None:
                continue
            names = {**match.groupdict(), "service": service}
            if _topic_pattern(_fill(route.topic, names).replace("*", "<any>")).fullmatch(topic):
                return True
    return False if owned else None


@functools.lru_cache(maxsize=1)
def _route_patterns() -> tuple[tuple[re.Pattern[str], Route], ...]:
    """Each TOPOLOGY topic as a regular expression with a named group per placeholder."""
    out = []
    for route in TOPOLOGY:
        parts = _PLACEHOLDER.split(route.topic)
        regex = "".join(
            re.escape(p) if i % 2 == 0 else f"(?P<{p}>[^/]+)" for i, p in enumerate(parts)
        )
        out.append((re.compile(regex), route))
    return tuple(out)


def _route_of(topic: str) -> tuple[Route, dict[str, str]] | None:
    for pattern, route in _route_patterns():
        if (match := pattern.fullmatch(topic)) is not None:
            return route, match.groupdict()
    return None


@functools.lru_cache(maxsize=4096)  # a run's topics: a few dozen
def budget_period(topic: str) -> str | None:
    """The period a receiver budgets ``topic`` by (``Route.budget``), None outside the
    topology."""
    found = _route_of(topic)
    return None if found is None else found[0].budget


@functools.lru_cache(maxsize=4096)
def publisher_of(topic: str) -> str | None:
    """The service that publishes ``topic`` (e.g. ``ctrl-lqr`` for ``cmd/lqr/att``, ``nav-lqr``
    for ``stats/nav-lqr``): its route's first publisher, so a command topic's is the deputy's
    controller (a deployment gives a ROS 2-flown deputy's to the gateway:
    ``Deployment.publisher_of``); ``ground`` for a ground command's; None for a topic outside
    the topology."""
    found = _route_of(topic)
    if found is None:
        return None
    route, names = found
    if "service" in names:
        return names["service"]
    template = route.publishers[0]
    if "<pid>" in template:
        return template.split("-<", 1)[0]
    return _PLACEHOLDER.sub(lambda m: names.get(m.group(1), m.group(0)), template)


@functools.lru_cache(maxsize=4096)  # the topics of a run: a few dozen; garbage may add more
def topic_identity(topic: str) -> tuple[tuple[str, str], ...]:
    """The (body field, value) pairs a message on ``topic`` must carry: what the topic names
    (``cmd/lqr/att``: ``(("sc", "lqr"),)``; ``stats/nav-lqr``: ``(("service", "nav-lqr"),)``);
    () for a topic whose body names nobody, or one outside the topology."""
    found = _route_of(topic)
    if found is None:
        return ()
    route, names = found
    return tuple((field, names[name]) for field, name in route.identity)


def identity_mismatch(topic: str, body: object) -> str | None:
    """The first identity field of ``body`` that is not what ``topic`` names (``topic_identity``),
    None when every one is."""
    for field, value in topic_identity(topic):
        if not isinstance(body, dict) or body.get(field) != value:
            return field
    return None
