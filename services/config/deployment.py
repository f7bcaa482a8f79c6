"""The deployment's types: what runs, with which parameters, on which links.

A deployment is TOML; every table maps onto one dataclass below, read by the strict table
reader (``ddvi_core.tables``): a typo or a wrong type raises DeploymentError naming the key
(``deputy[1].learning.intervl: unknown key (did you mean 'interval'?)``).  Services take all
their parameters from here.  Angles in the file are degrees; lengths metres; times seconds.
A deputy's ``learning`` table is a ``ddvi_core.learning_config.LearningConfig``; the keys it
leaves out follow from the mission (``ddvi_core.learning_config.mission_learning``, applied by
``services.config.validation.deployment_from_table``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ddvi_core.learning_config import FLIGHT_SCHEDULE_KEYS, LearningConfig
from ddvi_core.tables import table_field
from services.interface.keys import key_matches
from services.interface.links import LinkRule, LinkSpec, rule_latency
from services.interface.topics import ROS2_GATEWAY, command_deputy, concrete_topics, publisher_of

__all__ = [
    "DEPUTY_LEARNING_KEYS",
    "FAULT_KINDS",
    "RESTART_POLICIES",
    "ROS2_TOPICS",
    "Atmosphere",
    "Bus",
    "Chief",
    "Deployment",
    "DeploymentError",
    "Deputy",
    "Environment",
    "Fault",
    "Host",
    "Link",
    "Navigation",
    "Orbit",
    "Restart",
    "Ros2",
    "Run",
    "SpacecraftSpec",
    "controller_label",
]


LEASE_MARGIN = 15.0
"""Wall seconds a session's lease outlasts run.hang_timeout (``Deployment.session_lease_ms``)."""


class DeploymentError(ValueError):
    """A deployment file that cannot be run; the message names the key."""


@dataclass(frozen=True)
class Run:
    name: str = "run"
    orbits: float = 40.0  # mission length in chief orbits
    nav_period: float = 10.0  # truth and navigation sample period, s
    fsw_period: float = 60.0  # flight-software (command) period, s
    mode: str = "lockstep"  # or "realtime"
    rate: float = 1.0  # realtime: simulated seconds per wall second
    command_deadline: float = 10.0  # lockstep: wall seconds before a missing command is said
    hang_timeout: float = 60.0  # lockstep: wall seconds a step waits for a service at most
    nav_stale_limit: float = 0.0  # navigation age (s) past which a controller flies the safe
    # attitude; 0: two flight-software steps
    startup_timeout: float = 60.0  # wall seconds for every service to come alive
    output: str = "runs"  # where run folders (recording, report) are written
    seed: int = 1
    status_every: int = 10  # flight-software steps between status / stats messages


@dataclass(frozen=True)
class Bus:
    mode: str = "peer"
    port: int = 0  # the hub's loopback port; 0 picks a free one
    connect: list[str] = field(default_factory=list)  # extra endpoints (a router elsewhere)
    # authenticated clients of the launcher's router, access control from the topology
    # (docs/security.md); false: the insecure bus of ``mode``, said so by the launcher
    security: bool = True


@dataclass(frozen=True)
class Environment:
    backend: str = "builtin"
    j2: bool = True
    drag: bool = True
    density_factor: float = 1.0  # truth density / nominal density
    max_step: float = 60.0  # integrator step bound, s
    min_altitude: float = 150e3  # m above R_E: a craft below it has re-entered; the run ends
    rtol: float = 1e-11
    basilisk_step: float = 1.0  # Basilisk backend: RK4 step, s (density, attitude held over it)


@dataclass(frozen=True)
class Atmosphere:
    """The truth's atmosphere (docs/atmosphere.md).  ``rho0``, ``h_ref`` and ``scale_height``
    are the exponential model: the controllers' nominal model always, and the truth's with
    ``model = "exponential"``.  With ``model = "nrlmsis"`` the truth's density is NRLMSIS 2.1's
    along each craft's position, at ``epoch`` plus simulation time, under the solar flux
    ``f107`` (sfu, the F10.7 MSIS takes: the previous day's), its 81-day mean ``f107a`` and
    the geomagnetic index ``ap``, or through ``storm``: breakpoints ``[t_s, ap]`` or
    ``[t_s, f107, ap]`` (t in simulation seconds, strictly increasing), linear between them,
    held at the first before it and at the last after it; they replace ``ap`` (and ``f107``
    with three columns).  environment.density_factor scales either model's truth density."""

    rho0: float = 2.2e-11  # kg/m^3 at h_ref
    h_ref: float = 300e3
    scale_height: float = 8e3
    model: str = "exponential"  # or "nrlmsis" (the truth only)
    epoch: str = "2024-03-20T00:00:00Z"  # UTC at simulation time 0 (ISO 8601)
    f107: float = 150.0  # sfu
    f107a: float = 150.0  # sfu, 81-day mean
    ap: float = 4.0  # daily Ap (and every 3-hour ap)
    storm: list[list[float]] = field(default_factory=list)  # [[t_s, ap] or [t_s, f107, ap], ...]


@dataclass(frozen=True)
class SpacecraftSpec:
    mass: float = 6.0
    area: float = 0.06
    cd: float = 2.2
    normal_angle: float = 45.0  # facet normal in the body x-y plane, deg from body x


@dataclass(frozen=True)
class Orbit:
    a: float = 6678.136e3
    e: float = 0.0
    i: float = 45.0
    raan: float = 20.0
    argp: float = 30.0
    f: float = 20.0


@dataclass(frozen=True)
class Chief(Orbit):
    """The chief: its osculating orbit and its true facet area over the nominal design's
    (``area_factor``, as a deputy's: a non-cooperative object whose ballistic coefficient
    differs from the model's).  The truth flies it; the controllers' nominal model never
    knows it."""

    area_factor: float = 1.0  # truth facet area / nominal


@dataclass(frozen=True)
class Navigation:
    period: float = 10.0  # s, a whole multiple of run.nav_period
    frame: str = "path"  # "path" (against the chief's path) or "curvilinear" (ddvi_core.relnav)
    position_noise: float = 0.0  # 1-sigma white noise per axis, m
    velocity_noise: float = 0.0  # m/s
    position_bias: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    velocity_bias: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    seed: int = 0
    filter: str = "kalman"  # "kalman" (ddvi_core.navfilter) or "none" (the raw measurement)
    acceleration_noise: float = 3e-5  # m/s^2, the filter's unmodelled acceleration, 1-sigma


DEPUTY_LEARNING_KEYS = (
    "interval",
    "exploration_amplitude",
    "exploration_frequencies",
    "K0",
    "step",
    "step_size",
    "bounds",
    "bound_base",
    "tol",
    "max_iterations",
    "seed",
    *FLIGHT_SCHEDULE_KEYS,
)
"""The keys a deputy's learning table may give (the sample and command periods, the state and
exostate and the iteration's units come from the rest of the deployment)."""


@dataclass(frozen=True)
class Deputy:
    name: str = ""
    controller: str = "lqr"  # "lqr", "ddvi" or "ros2" (its commands from ROS 2: docs/ros2.md)
    y_ref: float = 0.0  # along-track slot, m
    orbit: Orbit = field(default_factory=lambda: Orbit(a=6678.376e3, f=19.75))
    area_factor: float = 1.0  # truth facet area / nominal
    navigation: Navigation = field(default_factory=Navigation)
    # read from a table, the keys it leaves out follow from the mission (deployment_from_table)
    learning: LearningConfig = table_field(LearningConfig, keys=DEPUTY_LEARNING_KEYS)
    attitude_limit: float = 0.2  # |sigma_i| limit (MRP)

    @property
    def label(self) -> str:
        """What tables call its controller (``controller_label``)."""
        return controller_label(self.controller, self.learning.method)


def controller_label(controller: str, method: str | None) -> str:
    """A controller as results tables name it: ``lqr``, ``ros2``, or a learner with its
    learning.method (``ddvi value-iteration``, ``ddvi model-fit``)."""
    return f"{controller} {method}" if controller == "ddvi" and method else controller


@dataclass(frozen=True)
class Link(LinkSpec):
    """One impaired link (docs/design.md, "The bus"): a LinkSpec's impairments (``delay``,
    ``jitter`` s, uniform on [0, jitter] on top of the delay; ``loss``, ``duplicate``,
    ``reorder`` probabilities) on the messages from the publishing service(s) to the
    subscribing service(s), on the topics that match; names and topics are key expressions
    (``services.interface.keys``: ``nav-*``, ``cmd/*/att``, ``**`` for every topic).  The
    first [[link]] that matches a message applies.  Times are simulation seconds in lock-step
    mode, wall seconds in real-time mode; the clock is never delayed (it is the time base),
    and the monitor records what is published, unimpaired."""

    publisher: str = "*"
    subscriber: str = "*"
    topic: str = "**"


@dataclass(frozen=True)
class Restart:
    """A restart policy (docs/design.md, "Faults"): what the launcher does when a service whose name
    matches ``service`` (a shell-style glob) dies before the mission ends.  ``"on-failure"``
    starts it again, into the running mission, up to ``max_restarts`` times; ``"never"`` (the
    default for every service) ends the run.  The first matching [[restart]] applies."""

    service: str = "*"
    policy: str = "on-failure"
    max_restarts: int = 3


RESTART_POLICIES = ("never", "on-failure")


@dataclass(frozen=True)
class Fault:
    """A scheduled fault (docs/design.md, "Faults"), applied at ``at_orbits`` chief orbits to one
    deputy by the service that owns what fails:

    - ``panel``: the drag panel's true area becomes ``area_factor`` times the nominal design's
      (a partly deployed or damaged panel), and/or its hinge sticks at ``normal_angle`` (deg in
      (0, 90), the facet normal in the body x-y plane, nominally spacecraft.normal_angle), the
      body's attitude still turning it; at least one of the two is given, the other stays as
      it was.  The environment applies it; the controllers' model keeps the nominal panel.
    - ``bias``: the navigation solution's bias becomes ``position_bias`` (m, Hill x y z) and
      ``velocity_bias`` (m/s); the deputy's navigation service applies it.
    - ``outage``: the deputy's navigation measures nothing for ``duration_orbits`` chief orbits
      (a sensor or its link to the chief gone): its filter propagates, its covariance grows,
      and its samples are marked not valid, which the controller does not fly on (its
      stale-navigation rule, docs/health.md).  The deputy's navigation applies it.

    ``ddvi fault RUN panel|bias|outage DEPUTY ...`` injects the same at run time."""

    at_orbits: float = 0.0
    kind: str = "panel"
    deputy: str = ""
    area_factor: float | None = None
    normal_angle: float | None = None
    position_bias: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    velocity_bias: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    duration_orbits: float = 0.0


FAULT_KINDS = ("panel", "bias", "outage")


@dataclass(frozen=True)
class Host:
    """A separate network host for some services: a Linux network namespace ``netns``, joined
    to the launcher's by a veth pair (``services.ground.launch.netns``: ``ddvi netns up|down``).
    The services whose names match ``services`` (globs) run in it and reach the run's hub, a
    Zenoh router in the launcher, over that link.  Needs ``bus.mode = "client"`` and a fixed
    ``bus.port``."""

    netns: str = ""
    services: list[str] = field(default_factory=list)


ROS2_TOPICS = (
    "clock",
    "odom",
    "altitude",
    "truth",
    "attitude",
    "gains",
    "diagnostics",
    "tf",
)
"""What the ROS 2 gateway can carry (docs/ros2.md, "Topics"): ``clock`` /clock; per deputy
``odom`` its navigated relative state, ``altitude`` navigation's altitude, ``truth`` its true
relative state, ``attitude`` its commanded attitude, ``gains`` the gains its controller flies
and the truth model's optimal ones; ``diagnostics`` the services' health; ``tf`` the
chief-to-deputy transforms."""


@dataclass(frozen=True)
class Ros2:
    """The ROS 2 gateway (docs/ros2.md): one more service of the run, ``ros2-gateway``, that
    carries the topics ``topics`` names (``ROS2_TOPICS``) to ROS 2 Jazzy over rmw_zenoh, in
    ROS domain ``domain_id``, on a Zenoh session of its own at ``endpoint``: it joins the Zenoh
    router that answers there (a user's ``rmw_zenohd``) or else serves that endpoint as the
    router itself.  The run's bus is never opened to the ROS 2 side.  Off unless ``enabled``
    (or ``ddvi run --ros2``)."""

    enabled: bool = False
    endpoint: str = "tcp/127.0.0.1:7447"  # rmw_zenoh's default router
    domain_id: int = 0  # ROS_DOMAIN_ID
    topics: list[str] = field(default_factory=lambda: list(ROS2_TOPICS))


@dataclass(frozen=True)
class Deployment:
    run: Run = field(default_factory=Run)
    bus: Bus = field(default_factory=Bus)
    environment: Environment = field(default_factory=Environment)
    atmosphere: Atmosphere = field(default_factory=Atmosphere)
    spacecraft: SpacecraftSpec = field(default_factory=SpacecraftSpec)
    chief: Chief = field(default_factory=Chief)
    deputy: list[Deputy] = field(default_factory=list)
    link: list[Link] = field(default_factory=list)
    restart: list[Restart] = field(default_factory=list)
    fault: list[Fault] = field(default_factory=list)
    host: list[Host] = field(default_factory=list)
    ros2: Ros2 = field(default_factory=Ros2)
    path: str = ""

    @property
    def services(self) -> list[str]:
        """Service names, in start order (the environment, the time master, last)."""
        names = ["monitor"]
        for d in self.deputy:  # a deputy flown from ROS 2 has no controller of the run's
            names += (
                [f"nav-{d.name}"] if d.controller == "ros2" else [f"nav-{d.name}", f"ctrl-{d.name}"]
            )
        if self.ros2.enabled:
            names.append(ROS2_GATEWAY)
        return [*names, "environment"]

    def topics(self) -> dict[str, str]:
        """Every topic a run of this deployment may carry (``topics.TOPOLOGY``, below
        ``ddvi/<run>/``) and its schema."""
        deputies = [d.name for d in self.deputy]
        return concrete_topics(
            {"craft": ["chief", *deputies], "sc": deputies, "service": [*self.services, "launcher"]}
        )

    def commander(self, deputy: str) -> str:
        """The service that puts deputy ``deputy``'s commands on the bus: its controller
        ``ctrl-<deputy>``, or the ROS 2 gateway for a deputy flown from ROS 2."""
        flown = any(d.name == deputy and d.controller == "ros2" for d in self.deputy)
        return ROS2_GATEWAY if flown else f"ctrl-{deputy}"

    def publisher_of(self, topic: str) -> str | None:
        """The one service that publishes ``topic`` in a run of this deployment: the
        topology's (``topics.publisher_of``), but a ROS 2-flown deputy's commands are the
        gateway's."""
        deputy = command_deputy(topic)
        return self.commander(deputy) if deputy is not None else publisher_of(topic)

    def session_lease_ms(self) -> int:
        """Every session's lease (zenoh ``transport/link/tx/lease``), the hub's and each
        service's: run.hang_timeout plus ``LEASE_MARGIN``, so that a frozen service (and the
        hub, as its frozen client sees it) stays on the bus until the hang timeout has named it,
        while a crashed one, whose connection closes, is seen gone at once."""
        return int(1000 * (self.run.hang_timeout + LEASE_MARGIN))

    def links_for(self, subscriber: str) -> list[LinkRule]:
        """The link rules that apply at one subscribing service, in file order."""
        return [
            LinkRule(k.publisher, k.topic, k.spec)
            for k in self.link
            if key_matches(k.subscriber, subscriber)
        ]

    def link_latency(self, publisher: str, subscriber: str, topic: str) -> float:
        """The largest latency (s: delay + jitter) of the link from one service to another on
        ``topic``; 0 when no [[link]] applies."""
        return rule_latency(self.links_for(subscriber), publisher, topic)

    def restart_policy(self, service: str) -> Restart:
        """The [[restart]] that applies to ``service`` (by default: never restart)."""
        for r in self.restart:
            if key_matches(r.service, service):
                return r
        return Restart(service, "never", 0)

    def host_of(self, service: str) -> int | None:
        """The index of the [[host]] a service runs on (None: the launcher's own)."""
        for k, h in enumerate(self.host):
            if any(key_matches(pattern, service) for pattern in h.services):
                return k
        return None

    def deputy_named(self, name: str) -> Deputy:
        for d in self.deputy:
            if d.name == name:
                return d
        raise DeploymentError(
            f"no deputy named {name!r}; deputies: " + ", ".join(d.name for d in self.deputy)
        )
