"""Deployment files: what runs, with which parameters, on which links.

A deployment is TOML; every table maps onto one dataclass below, and every key is checked:
a typo or a wrong type raises DeploymentError naming the key (``deputy[1].learning.intervl:
unknown key (did you mean 'interval'?)``).  Services take all their parameters from here.
Angles in the file are degrees; lengths metres; times seconds.
"""

from __future__ import annotations

import copy
import difflib
import math
import tomllib
import types
import typing
from dataclasses import MISSING, dataclass, field, fields
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

from ddvi_core.relnav import FRAMES
from services.bus import LinkRule, LinkSpec, impairs_truth, rule_latency

__all__ = [
    "Atmosphere",
    "Deployment",
    "DeploymentError",
    "Deputy",
    "Environment",
    "Fault",
    "Host",
    "Learning",
    "Link",
    "Navigation",
    "Orbit",
    "Restart",
    "Run",
    "SpacecraftSpec",
    "load_deployment",
]


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
    command_deadline: float = 10.0  # lockstep: wall seconds to wait for a step's commands
    startup_timeout: float = 60.0  # wall seconds for every service to come alive
    output: str = "runs"  # where run folders (recording, report) are written
    seed: int = 1
    status_every: int = 10  # flight-software steps between status / stats messages


@dataclass(frozen=True)
class Bus:
    mode: str = "peer"
    port: int = 0  # the hub's loopback port; 0 picks a free one
    connect: list[str] = field(default_factory=list)  # extra endpoints (a router elsewhere)


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
    rho0: float = 2.2e-11  # kg/m^3 at h_ref
    h_ref: float = 300e3
    scale_height: float = 8e3


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
class Navigation:
    period: float = 10.0  # s, a whole multiple of run.nav_period
    frame: str = "path"  # "path" (against the chief's path) or "curvilinear" (ddvi_core.relnav)
    position_noise: float = 0.0  # 1-sigma white noise per axis, m
    velocity_noise: float = 0.0  # m/s
    position_bias: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    velocity_bias: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    seed: int = 0


@dataclass(frozen=True)
class Learning:
    learn_at_orbits: float = 15.0  # when to learn and switch gains
    retry_orbits: float = 1.0  # after a failed attempt, explore on and try again this much later
    interval: float = 600.0  # s per data interval
    exploration_amplitude: float = 0.1  # rad (MRP) of the multi-sine
    exploration_frequencies: list[float] = field(default_factory=list)  # rad/s; [] = spread
    K0: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])
    window_orbits: float = 0.0  # learn from the last this many orbits of data; 0 = all of it
    along_track_reference: bool = True  # xbar about the data's mean along-track position
    step: str = "constant"
    step_size: float = 0.01  # in units of the orbit rate
    bounds: str = "geometric"
    bound_base: float = 10.0
    tol: float = 1e-6
    max_iterations: int = 200_000
    seed: int = 1
    # after learning, watch the plant for a change (an actuator fault) and learn again
    relearn: bool = False
    relearn_settle_orbits: float = 2.0  # after a detection, K0 stops the approach: not data
    relearn_window_orbits: float = 10.0  # then explore this long and re-learn from it
    relearn_max_attempts: int = 5  # re-learning attempts that fail before the old gains return
    detector_bound: float = 100.0  # x the input-equivalent residual's RMS on the learning data
    detector_window_orbits: float = 1.0  # the residual's mean is taken over this window


@dataclass(frozen=True)
class Deputy:
    name: str = ""
    controller: str = "lqr"  # "lqr" or "ddvi"
    y_ref: float = 0.0  # along-track slot, m
    orbit: Orbit = field(default_factory=lambda: Orbit(a=6678.376e3, f=19.75))
    area_factor: float = 1.0  # truth facet area / nominal
    navigation: Navigation = field(default_factory=Navigation)
    learning: Learning = field(default_factory=Learning)
    attitude_limit: float = 0.2  # |sigma_i| limit (MRP)


@dataclass(frozen=True)
class Link:
    """One impaired link (DESIGN.md section 2): messages from the publishing service(s) to the
    subscribing service(s), on the topics that match; names and topics are shell-style globs
    (``nav-*``, ``cmd/*/att``).  The first [[link]] that matches a message applies.  Times are
    simulation seconds in lock-step mode, wall seconds in real-time mode; the clock is never
    delayed (it is the time base), and the monitor records what is published, unimpaired."""

    publisher: str = "*"
    subscriber: str = "*"
    topic: str = "*"
    delay: float = 0.0  # s
    jitter: float = 0.0  # s, uniform on [0, jitter] on top of the delay
    loss: float = 0.0  # probability
    duplicate: float = 0.0  # probability
    reorder: float = 0.0  # probability that a message swaps with the next one

    @property
    def spec(self) -> LinkSpec:
        return LinkSpec(self.delay, self.jitter, self.loss, self.duplicate, self.reorder)


@dataclass(frozen=True)
class Restart:
    """A restart policy (DESIGN.md section 4): what the launcher does when a service whose name
    matches ``service`` (a shell-style glob) dies before the mission ends.  ``"on-failure"``
    starts it again, into the running mission, up to ``max_restarts`` times; ``"never"`` (the
    default for every service) ends the run.  The first matching [[restart]] applies."""

    service: str = "*"
    policy: str = "on-failure"
    max_restarts: int = 3


RESTART_POLICIES = ("never", "on-failure")


@dataclass(frozen=True)
class Fault:
    """A scheduled fault (DESIGN.md section 4), applied at ``at_orbits`` chief orbits to one
    deputy by the service that owns what fails:

    - ``panel``: the drag panel's true area becomes ``area_factor`` times the nominal design's
      (a partly deployed or damaged panel), and/or its hinge sticks at ``normal_angle`` (deg in
      (0, 90), the facet normal in the body x-y plane, nominally spacecraft.normal_angle), the
      body's attitude still turning it; at least one of the two is given, the other stays as
      it was.  The environment applies it; the controllers' model keeps the nominal panel.
    - ``bias``: the navigation solution's bias becomes ``position_bias`` (m, Hill x y z) and
      ``velocity_bias`` (m/s); the deputy's navigation service applies it.

    ``ddvi fault RUN panel|bias DEPUTY ...`` injects the same at run time."""

    at_orbits: float = 0.0
    kind: str = "panel"
    deputy: str = ""
    area_factor: float | None = None
    normal_angle: float | None = None
    position_bias: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    velocity_bias: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


FAULT_KINDS = ("panel", "bias")


@dataclass(frozen=True)
class Host:
    """A separate network host for some services: a Linux network namespace ``netns``, joined
    to the launcher's by a veth pair (``services.ground.netns``: ``ddvi netns up|down``).  The
    services whose names match ``services`` (globs) run in it and reach the run's hub, a
    Zenoh router in the launcher, over that link.  Needs ``bus.mode = "client"`` and a fixed
    ``bus.port``."""

    netns: str = ""
    services: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Deployment:
    run: Run = field(default_factory=Run)
    bus: Bus = field(default_factory=Bus)
    environment: Environment = field(default_factory=Environment)
    atmosphere: Atmosphere = field(default_factory=Atmosphere)
    spacecraft: SpacecraftSpec = field(default_factory=SpacecraftSpec)
    chief: Orbit = field(default_factory=Orbit)
    deputy: list[Deputy] = field(default_factory=list)
    link: list[Link] = field(default_factory=list)
    restart: list[Restart] = field(default_factory=list)
    fault: list[Fault] = field(default_factory=list)
    host: list[Host] = field(default_factory=list)
    path: str = ""

    @property
    def services(self) -> list[str]:
        """Service names, in start order (the environment, the time master, last)."""
        names = ["monitor"]
        for d in self.deputy:
            names += [f"nav-{d.name}", f"ctrl-{d.name}"]
        return [*names, "environment"]

    def links_for(self, subscriber: str) -> list[LinkRule]:
        """The link rules that apply at one subscribing service, in file order."""
        return [
            LinkRule(k.publisher, k.topic, k.spec)
            for k in self.link
            if fnmatchcase(subscriber, k.subscriber)
        ]

    def link_latency(self, publisher: str, subscriber: str, topic: str) -> float:
        """The largest latency (s: delay + jitter) of the link from one service to another on
        ``topic``; 0 when no [[link]] applies."""
        return rule_latency(self.links_for(subscriber), publisher, topic)

    def restart_policy(self, service: str) -> Restart:
        """The [[restart]] that applies to ``service`` (by default: never restart)."""
        for r in self.restart:
            if fnmatchcase(service, r.service):
                return r
        return Restart(service, "never", 0)

    def host_of(self, service: str) -> int | None:
        """The index of the [[host]] a service runs on (None: the launcher's own)."""
        for k, h in enumerate(self.host):
            if any(fnmatchcase(service, pattern) for pattern in h.services):
                return k
        return None

    def deputy_named(self, name: str) -> Deputy:
        for d in self.deputy:
            if d.name == name:
                return d
        raise DeploymentError(
            f"no deputy named {name!r}; deputies: " + ", ".join(d.name for d in self.deputy)
        )


# ---- generic strict parsing -----------------------------------------------------------------


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


def _convert(where: str, tp: Any, value: Any) -> Any:
    origin = typing.get_origin(tp)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise DeploymentError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise DeploymentError(f"{where}: must be finite, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise DeploymentError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise DeploymentError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise DeploymentError(f"{where}: expected a string, got {value!r}")
        return value
    if origin is list:
        (item_tp,) = typing.get_args(tp)
        if not isinstance(value, list):
            raise DeploymentError(f"{where}: expected a list, got {value!r}")
        return [_convert(f"{where}[{i}]", item_tp, v) for i, v in enumerate(value)]
    if isinstance(tp, type) and hasattr(tp, "__dataclass_fields__"):
        return parse_table(tp, value, where)
    if origin in (typing.Union, types.UnionType):
        # an optional value (``float | None``): TOML has no null, so a key given is a value
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return _convert(where, args[0], value)
        raise DeploymentError(f"{where}: unsupported type {tp}")
    raise DeploymentError(f"{where}: unsupported type {_type_name(tp)}")


def parse_table(cls: type, table: Any, where: str) -> Any:
    """Build dataclass ``cls`` from a TOML table, checking every key and type."""
    if not isinstance(table, dict):
        raise DeploymentError(f"{where or 'deployment'}: expected a table, got {table!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls) if f.name != "path"]
    kwargs = {}
    prefix = f"{where}." if where else ""
    for key, value in table.items():
        if key not in names:
            near = difflib.get_close_matches(key, names, n=1)
            hint = f" (did you mean '{near[0]}'?)" if near else ""
            raise DeploymentError(f"{prefix}{key}: unknown key{hint}; allowed: {', '.join(names)}")
        kwargs[key] = _convert(f"{prefix}{key}", hints[key], value)
    for f in fields(cls):
        if f.default is MISSING and f.default_factory is MISSING and f.name not in kwargs:
            raise DeploymentError(f"{prefix}{f.name}: required")
    return cls(**kwargs)


# ---- semantic checks ------------------------------------------------------------------------


def _positive(where: str, value: float) -> None:
    if not value > 0:
        raise DeploymentError(f"{where}: must be positive, got {value}")


def _multiple(where: str, value: float, base: float, base_name: str) -> None:
    ratio = value / base
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise DeploymentError(
            f"{where}: must be a whole multiple of {base_name} ({base} s), got {value}"
        )


def validate(dep: Deployment) -> None:
    r = dep.run
    for key in (
        "orbits",
        "nav_period",
        "fsw_period",
        "rate",
        "command_deadline",
        "startup_timeout",
    ):
        _positive(f"run.{key}", getattr(r, key))
    if r.mode not in ("lockstep", "realtime"):
        raise DeploymentError(f"run.mode: expected 'lockstep' or 'realtime', got {r.mode!r}")
    _multiple("run.fsw_period", r.fsw_period, r.nav_period, "run.nav_period")
    if dep.bus.mode not in ("peer", "client"):
        raise DeploymentError(f"bus.mode: expected 'peer' or 'client', got {dep.bus.mode!r}")
    if not 0 <= dep.bus.port < 65536:
        raise DeploymentError(f"bus.port: expected 0..65535, got {dep.bus.port}")
    if dep.environment.backend not in ("builtin", "basilisk"):
        raise DeploymentError(
            "environment.backend: expected 'builtin' or 'basilisk', got "
            f"{dep.environment.backend!r}"
        )
    _positive("environment.density_factor", dep.environment.density_factor)
    _positive("environment.max_step", dep.environment.max_step)
    _positive("environment.basilisk_step", dep.environment.basilisk_step)
    if dep.environment.backend == "basilisk":
        _multiple("run.nav_period", r.nav_period, dep.environment.basilisk_step,
                  "environment.basilisk_step")  # fmt: skip
    for key in ("mass", "area", "cd"):
        _positive(f"spacecraft.{key}", getattr(dep.spacecraft, key))
    for key in ("rho0", "scale_height"):
        _positive(f"atmosphere.{key}", getattr(dep.atmosphere, key))
    _positive("chief.a", dep.chief.a)
    if not 0 <= dep.chief.e < 1:
        raise DeploymentError(f"chief.e: expected 0 <= e < 1, got {dep.chief.e}")
    if not dep.deputy:
        raise DeploymentError("deputy: at least one [[deputy]] table is required")
    seen = set()
    for k, d in enumerate(dep.deputy):
        w = f"deputy[{k}]"
        if not d.name or not d.name.replace("_", "").isalnum() or d.name == "chief":
            raise DeploymentError(
                f"{w}.name: expected a name of letters, digits and _, "
                f"other than 'chief', got {d.name!r}"
            )
        if d.name in seen:
            raise DeploymentError(f"{w}.name: {d.name!r} is used twice")
        seen.add(d.name)
        if d.controller not in ("lqr", "ddvi"):
            raise DeploymentError(f"{w}.controller: expected 'lqr' or 'ddvi', got {d.controller!r}")
        _positive(f"{w}.orbit.a", d.orbit.a)
        _positive(f"{w}.area_factor", d.area_factor)
        if not 0 < d.attitude_limit <= 1:
            raise DeploymentError(f"{w}.attitude_limit: expected 0 < limit <= 1 (MRP)")
        _multiple(f"{w}.navigation.period", d.navigation.period, r.nav_period, "run.nav_period")
        _multiple("run.fsw_period", r.fsw_period, d.navigation.period, f"{w}.navigation.period")
        for key in ("position_noise", "velocity_noise"):
            if getattr(d.navigation, key) < 0:
                raise DeploymentError(f"{w}.navigation.{key}: must be >= 0")
        if d.navigation.frame not in FRAMES:
            raise DeploymentError(
                f"{w}.navigation.frame: {d.navigation.frame!r} is not one of {list(FRAMES)}"
            )
        for key in ("position_bias", "velocity_bias"):
            if len(getattr(d.navigation, key)) != 3:
                raise DeploymentError(f"{w}.navigation.{key}: expected 3 values")
        lrn = d.learning
        _positive(f"{w}.learning.learn_at_orbits", lrn.learn_at_orbits)
        _multiple(
            f"{w}.learning.interval", lrn.interval, d.navigation.period, f"{w}.navigation.period"
        )
        if not 0 <= lrn.exploration_amplitude <= d.attitude_limit:
            raise DeploymentError(
                f"{w}.learning.exploration_amplitude: must lie in "
                f"[0, attitude_limit = {d.attitude_limit}]"
            )
        if not (math.isfinite(lrn.window_orbits) and lrn.window_orbits >= 0):
            raise DeploymentError(f"{w}.learning.window_orbits: must be >= 0 (0 = all data)")
        for key in ("relearn_window_orbits", "detector_bound", "detector_window_orbits"):
            _positive(f"{w}.learning.{key}", getattr(lrn, key))
        if lrn.relearn_settle_orbits < 0:
            raise DeploymentError(f"{w}.learning.relearn_settle_orbits: must be >= 0")
        if lrn.relearn_max_attempts < 1:
            raise DeploymentError(f"{w}.learning.relearn_max_attempts: must be >= 1")
        if len(lrn.K0) != 4:
            raise DeploymentError(f"{w}.learning.K0: expected 4 values (gain on x, y, xdot, ydot)")
        if lrn.step not in ("harmonic", "constant") or lrn.bounds not in ("linear", "geometric"):
            raise DeploymentError(
                f"{w}.learning.step/bounds: expected step 'harmonic' or "
                "'constant' and bounds 'linear' or 'geometric'"
            )


def _validate_links(dep: Deployment) -> None:
    services = dep.services
    for k, link in enumerate(dep.link):
        w = f"link[{k}]"
        try:
            link.spec  # noqa: B018 (validates the numbers)
        except ValueError as exc:
            raise DeploymentError(str(exc).replace("LinkSpec.", f"{w}.")) from None
        for key in ("publisher", "subscriber"):
            pattern = getattr(link, key)
            if not any(fnmatchcase(s, pattern) for s in services):
                raise DeploymentError(
                    f"{w}.{key}: {pattern!r} matches no service; services: {', '.join(services)}"
                )
        if any(
            impairs_truth(link.publisher, s) for s in services if fnmatchcase(s, link.subscriber)
        ):
            raise DeploymentError(
                f"{w}: impairs the environment's truth to navigation "
                f"({link.publisher!r} -> {link.subscriber!r}); impair navigation -> controller "
                '(publisher = "nav-*") or the commands (topic = "cmd/*/att") instead'
            )
        if link.subscriber == "monitor":
            raise DeploymentError(
                f"{w}.subscriber: the monitor records what is published, unimpaired; impair "
                "the links between flight services"
            )


def _validate_restarts(dep: Deployment) -> None:
    services = dep.services
    for k, r in enumerate(dep.restart):
        w = f"restart[{k}]"
        if r.policy not in RESTART_POLICIES:
            raise DeploymentError(
                f"{w}.policy: expected one of {', '.join(RESTART_POLICIES)}, got {r.policy!r}"
            )
        if r.max_restarts < 0:
            raise DeploymentError(f"{w}.max_restarts: must be >= 0, got {r.max_restarts}")
        matched = [s for s in services if fnmatchcase(s, r.service)]
        if not matched:
            raise DeploymentError(
                f"{w}.service: {r.service!r} matches no service; services: {', '.join(services)}"
            )
        if r.policy != "never" and (fixed := {"environment", "monitor"} & set(matched)):
            raise DeploymentError(
                f"{w}.service: {r.service!r} would restart {', '.join(sorted(fixed))}: the "
                "environment is the truth and the time master, the monitor the one recording "
                'of the run; neither can be restarted into it (use service = "ctrl-*" or '
                '"nav-*")'
            )


def check_panel(area_factor: float | None, normal_angle: float | None) -> None:
    """Raise ValueError unless a panel fault's values are numbers in range (area_factor finite
    and > 0, normal_angle in (0, 90) deg), at least one of them given: the one check of the
    deployment file, ``ddvi fault`` and the environment's run-time fault messages."""
    if area_factor is None and normal_angle is None:
        raise ValueError("a panel fault changes area_factor, normal_angle or both: give one")
    for value in (area_factor, normal_angle):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)):
            raise ValueError(
                f"area_factor and normal_angle are numbers, got {value!r} ({type(value).__name__})"
            )
    if area_factor is not None and not (math.isfinite(area_factor) and area_factor > 0):
        raise ValueError(f"area_factor must be finite and > 0, got {area_factor}")
    if normal_angle is not None and not (0 < normal_angle < 90):
        raise ValueError(
            f"normal_angle must lie in (0, 90) deg (the facet normal in the body x-y plane), "
            f"got {normal_angle}"
        )


def _validate_faults(dep: Deployment) -> None:
    names = [d.name for d in dep.deputy]
    for k, f in enumerate(dep.fault):
        w = f"fault[{k}]"
        if f.kind not in FAULT_KINDS:
            raise DeploymentError(
                f"{w}.kind: expected one of {', '.join(FAULT_KINDS)}, got {f.kind!r}"
            )
        if f.deputy not in names:
            raise DeploymentError(f"{w}.deputy: {f.deputy!r} is not one of {', '.join(names)}")
        if not (math.isfinite(f.at_orbits) and 0 <= f.at_orbits < dep.run.orbits):
            raise DeploymentError(
                f"{w}.at_orbits: must lie in [0, run.orbits = {dep.run.orbits:g}), "
                f"got {f.at_orbits}"
            )
        if f.kind == "panel":
            try:
                check_panel(f.area_factor, f.normal_angle)
            except ValueError as exc:
                raise DeploymentError(f"{w}: {exc}") from None
        elif f.area_factor is not None or f.normal_angle is not None:
            raise DeploymentError(
                f"{w}: area_factor and normal_angle belong to panel faults, not {f.kind!r}"
            )
        for key in ("position_bias", "velocity_bias"):
            values = getattr(f, key)
            if len(values) != 3 or not all(math.isfinite(v) for v in values):
                raise DeploymentError(f"{w}.{key}: expected 3 finite values")
        if f.kind == "panel" and dep.environment.backend == "basilisk":
            raise DeploymentError(
                f"{w}: panel faults need the built-in truth (Basilisk 2.12's "
                "facetDragDynamicEffector cannot change a facet's area or normal once added)"
            )


def _validate_hosts(dep: Deployment) -> None:
    if not dep.host:
        return
    if dep.bus.mode != "client" or dep.bus.port == 0:
        raise DeploymentError(
            "host: services on other hosts reach the hub through a router: set bus.mode = "
            '"client" and a fixed bus.port'
        )
    seen = set()
    for k, h in enumerate(dep.host):
        w = f"host[{k}]"
        if not h.netns or not h.netns.replace("-", "").isalnum() or len(h.netns) > 12:
            raise DeploymentError(
                f"{w}.netns: expected a name of letters, digits and '-' (at most 12, it names "
                f"the veth pair too), got {h.netns!r}"
            )
        if h.netns in seen:
            raise DeploymentError(f"{w}.netns: {h.netns!r} is used twice")
        seen.add(h.netns)
        for pattern in h.services:
            if not any(fnmatchcase(s, pattern) for s in dep.services):
                raise DeploymentError(f"{w}.services: {pattern!r} matches no service")
        if any(fnmatchcase("monitor", p) for p in h.services):
            raise DeploymentError(f"{w}.services: the monitor runs beside the launcher")


def deployment_from_table(table: dict[str, Any], path: str = "") -> Deployment:
    dep = parse_table(Deployment, table, "")
    dep = Deployment(
        **{f.name: getattr(dep, f.name) for f in fields(Deployment) if f.name != "path"}, path=path
    )
    validate(dep)
    _validate_links(dep)
    _validate_restarts(dep)
    _validate_faults(dep)
    _validate_hosts(dep)
    return dep


DEPLOYMENTS_DIR = Path(__file__).resolve().parents[2] / "deployments"


def resolve(name_or_path: str | None) -> Path:
    """A deployment file by path, or by name in the project's deployments/ folder."""
    if name_or_path is None:
        name_or_path = "rendezvous"
    p = Path(name_or_path)
    if p.is_file():
        return p
    q = DEPLOYMENTS_DIR / f"{name_or_path}.toml"
    if q.is_file():
        return q
    known = sorted(x.stem for x in DEPLOYMENTS_DIR.glob("*.toml"))
    near = difflib.get_close_matches(name_or_path, known, n=1)
    hint = f" (did you mean '{near[0]}'?)" if near else ""
    raise DeploymentError(
        f"{name_or_path}: no such deployment file or name{hint}; known: " + ", ".join(known)
    )


def read_table(name_or_path: str | None) -> dict[str, Any]:
    """A deployment file's raw TOML table (to derive another deployment from it)."""
    return tomllib.loads(resolve(name_or_path).read_text())


def write_deployment(table: dict[str, Any], folder: Path, name: str) -> Path:
    """Write a deployment table to ``folder/name.toml``, its runs going under ``folder/runs``
    (benchmarks and sweeps derive their deployments this way)."""
    import tomli_w

    table = copy.deepcopy(table)
    table.setdefault("run", {})["output"] = str(folder / "runs")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    path.write_bytes(tomli_w.dumps(table).encode())
    return path


def load_deployment(name_or_path: str | None) -> Deployment:
    path = resolve(name_or_path)
    try:
        table = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise DeploymentError(f"{path}: not valid TOML ({exc})") from None
    return deployment_from_table(table, str(path))
