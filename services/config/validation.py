"""The deployment's semantic checks, and :func:`deployment_from_table` (read, each deputy's
learning completed from the mission, then check).

The table reader (``ddvi_core.tables``) checks keys, types and shapes; the checks here are what
a deployment must also satisfy to be run: values in range, periods that divide one another,
names that exist.  :data:`CHECKS` runs them in order; each raises DeploymentError naming the key.
Which services and topics a deployment's patterns name (links, restarts, hosts, kills) is
checked in ``services.config.wiring``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import fields, replace
from typing import Any

from ddvi_core.learning_config import mission_learning
from ddvi_core.relnav import FRAMES
from ddvi_core.tables import from_table
from services.config.atmosphere import check_atmosphere
from services.config.deployment import (
    FAULT_KINDS,
    ROS2_TOPICS,
    Deployment,
    DeploymentError,
    Deputy,
    Fault,
)
from services.config.ranges import ENDPOINT, MAX_AREA_FACTOR, check_bias, check_ranges
from services.config.wiring import check_hosts, check_links, check_restarts

__all__ = [
    "CHECKS",
    "check_atmosphere",
    "check_fault",
    "check_panel",
    "check_ros2_endpoint",
    "deployment_from_table",
    "validate",
]

DEPLOYMENT_KEYS = tuple(f.name for f in fields(Deployment) if f.name != "path")
"""The top-level keys of a deployment file (``path`` is where it was read from)."""


def _positive(where: str, value: float) -> None:
    if not value > 0:
        raise DeploymentError(f"{where}: must be positive, got {value}")


def _multiple(where: str, value: float, base: float, base_name: str) -> None:
    ratio = value / base
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise DeploymentError(
            f"{where}: must be a whole multiple of {base_name} ({base} s), got {value}"
        )


def _one_of(where: str, value: str, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        quoted = " or ".join(repr(a) for a in allowed)
        raise DeploymentError(f"{where}: expected {quoted}, got {value!r}")


def check_run(dep: Deployment) -> None:
    """run: positive times, a known mode, the command period a multiple of the nav period."""
    r = dep.run
    for key in ("orbits", "nav_period", "fsw_period", "rate", "command_deadline", "hang_timeout"):
        _positive(f"run.{key}", getattr(r, key))
    _positive("run.startup_timeout", r.startup_timeout)
    _one_of("run.mode", r.mode, ("lockstep", "realtime"))
    _multiple("run.fsw_period", r.fsw_period, r.nav_period, "run.nav_period")


def check_bus(dep: Deployment) -> None:
    """bus: a known mode and a port number."""
    _one_of("bus.mode", dep.bus.mode, ("peer", "client"))
    if not 0 <= dep.bus.port < 65536:
        raise DeploymentError(f"bus.port: expected 0..65535, got {dep.bus.port}")


def check_environment(dep: Deployment) -> None:
    """environment: a known backend, positive factors and steps (Basilisk's step dividing the
    nav period)."""
    env = dep.environment
    _one_of("environment.backend", env.backend, ("builtin", "basilisk"))
    for key in ("density_factor", "max_step", "basilisk_step"):
        _positive(f"environment.{key}", getattr(env, key))
    if env.backend == "basilisk":
        _multiple(
            "run.nav_period", dep.run.nav_period, env.basilisk_step, "environment.basilisk_step"
        )


def check_bodies(dep: Deployment) -> None:
    """spacecraft, atmosphere and chief: positive sizes, an elliptic chief orbit."""
    for key in ("mass", "area", "cd"):
        _positive(f"spacecraft.{key}", getattr(dep.spacecraft, key))
    for key in ("rho0", "scale_height"):
        _positive(f"atmosphere.{key}", getattr(dep.atmosphere, key))
    _positive("chief.a", dep.chief.a)
    _positive("chief.area_factor", dep.chief.area_factor)
    if not 0 <= dep.chief.e < 1:
        raise DeploymentError(f"chief.e: expected 0 <= e < 1, got {dep.chief.e}")


def _check_deputy_craft(w: str, d: Deputy) -> None:
    """A deputy's controller, orbit, panel and attitude limit."""
    _one_of(f"{w}.controller", d.controller, CONTROLLERS)
    _positive(f"{w}.orbit.a", d.orbit.a)
    _positive(f"{w}.area_factor", d.area_factor)
    if not 0 < d.attitude_limit <= 1:
        raise DeploymentError(f"{w}.attitude_limit: expected 0 < limit <= 1 (MRP)")


CONTROLLERS = ("lqr", "ddvi", "ros2")
"""deputy.controller: the model-based LQR, the learner, or a ROS 2 node's commands through the
ROS 2 gateway (docs/ros2.md)."""

NAV_FILTERS = ("kalman", "none")
"""navigation.filter: a Kalman filter on the Hill state (ddvi_core.navfilter), or none."""


def _check_deputy_navigation(w: str, d: Deputy, dep: Deployment) -> None:
    """A deputy's navigation period (between run.nav_period and run.fsw_period, dividing
    both), noise, frame, biases and filter."""
    nav, r = d.navigation, dep.run
    _multiple(f"{w}.navigation.period", nav.period, r.nav_period, "run.nav_period")
    _multiple("run.fsw_period", r.fsw_period, nav.period, f"{w}.navigation.period")
    for key in ("position_noise", "velocity_noise"):
        if getattr(nav, key) < 0:
            raise DeploymentError(f"{w}.navigation.{key}: must be >= 0")
    if nav.frame not in FRAMES:
        raise DeploymentError(f"{w}.navigation.frame: {nav.frame!r} is not one of {list(FRAMES)}")
    for key in ("position_bias", "velocity_bias"):
        if len(getattr(nav, key)) != 3:
            raise DeploymentError(f"{w}.navigation.{key}: expected 3 values")
    if nav.filter not in NAV_FILTERS:
        raise DeploymentError(
            f"{w}.navigation.filter: {nav.filter!r} is not one of {list(NAV_FILTERS)}"
        )
    if not (math.isfinite(nav.acceleration_noise) and nav.acceleration_noise > 0):
        raise DeploymentError(
            f"{w}.navigation.acceleration_noise: must be a positive number of m/s^2 "
            f"(default 3e-5), got {nav.acceleration_noise}"
        )


LEARNING_METHODS = ("value-iteration", "model-fit")
LEARNING_SOURCES = ("estimate", "measurement")
LEARNING_FALLBACKS = ("last", "lqr")
"""learning.fallback: the gains validated last (the nominal LQR's before any), or the LQR's."""


def _check_deputy_learning(w: str, d: Deputy) -> None:
    """A deputy's learning schedule, exploration, initial gain and iteration."""
    lrn, where = d.learning, f"{w}.learning"
    _positive(f"{where}.learn_at_orbits", lrn.learn_at_orbits)
    _multiple(f"{where}.interval", lrn.interval, d.navigation.period, f"{w}.navigation.period")
    if not 0 <= lrn.exploration_amplitude <= d.attitude_limit:
        raise DeploymentError(
            f"{where}.exploration_amplitude: must lie in [0, attitude_limit = {d.attitude_limit}]"
        )
    until = lrn.learn_until_orbits
    if not (math.isfinite(until) and until >= lrn.learn_at_orbits):
        raise DeploymentError(
            f"{where}.learn_until_orbits: must be at least learn_at_orbits "
            f"({lrn.learn_at_orbits:g}): after it a learner that has validated no gain flies "
            f"its fallback (leave it out: half-way from learn_at_orbits to the mission's end), "
            f"got {until}"
        )
    _one_of(f"{where}.fallback", lrn.fallback, LEARNING_FALLBACKS)
    if not (math.isfinite(lrn.saturated_fraction) and 0 < lrn.saturated_fraction <= 1):
        raise DeploymentError(
            f"{where}.saturated_fraction: must lie in (0, 1] (the fraction of the steps an "
            f"attempt learned from with the attitude at its limit, from which a failed attempt "
            f"flies the fallback at once), got {lrn.saturated_fraction}"
        )
    _positive(f"{where}.resume_fit_tolerance", lrn.resume_fit_tolerance)
    if not (math.isfinite(lrn.resume_window_orbits) and lrn.resume_window_orbits >= 0):
        raise DeploymentError(
            f"{where}.resume_window_orbits: must be >= 0 (0 = never learn on the fallback), "
            f"got {lrn.resume_window_orbits}"
        )
    if not (math.isfinite(lrn.window_orbits) and lrn.window_orbits >= 0):
        raise DeploymentError(f"{where}.window_orbits: must be >= 0 (0 = all data)")
    for key in ("relearn_window_orbits", "detector_bound", "detector_window_orbits"):
        _positive(f"{where}.{key}", getattr(lrn, key))
    if lrn.relearn_settle_orbits < 0:
        raise DeploymentError(f"{where}.relearn_settle_orbits: must be >= 0")
    if lrn.relearn_max_attempts < 1:
        raise DeploymentError(f"{where}.relearn_max_attempts: must be >= 1")
    _one_of(f"{where}.method", lrn.method, LEARNING_METHODS)
    _one_of(f"{where}.learn_from", lrn.learn_from, LEARNING_SOURCES)
    if not 0 <= lrn.data_from_orbits < lrn.learn_at_orbits:
        raise DeploymentError(f"{where}.data_from_orbits: must lie in [0, learn_at_orbits)")
    _multiple(f"{where}.fit_stride", lrn.fit_stride, d.navigation.period, f"{w}.navigation.period")
    if not (math.isfinite(lrn.fit_smoothing) and 0 <= lrn.fit_smoothing <= lrn.interval):
        raise DeploymentError(f"{where}.fit_smoothing: must lie in [0, interval] s")
    _positive(f"{where}.fit_tolerance", lrn.fit_tolerance)
    _positive(f"{where}.fit_deadline_tolerance", lrn.fit_deadline_tolerance)
    if not (math.isfinite(lrn.fit_deadline_orbits) and lrn.fit_deadline_orbits >= 0):
        raise DeploymentError(f"{where}.fit_deadline_orbits: must be >= 0 (0 = no deadline)")
    if not (math.isfinite(lrn.validation_orbits) and lrn.validation_orbits >= 0):
        raise DeploymentError(f"{where}.validation_orbits: must be >= 0 (0 = no validation)")
    if not (math.isfinite(lrn.validation_gain_change) and lrn.validation_gain_change > 0):
        raise DeploymentError(
            f"{where}.validation_gain_change: must be > 0 (the largest relative difference of "
            f"the gains fitted with and without the hold-out), got {lrn.validation_gain_change}"
        )
    if not 0 < lrn.validation_residual <= 1:
        raise DeploymentError(
            f"{where}.validation_residual: must lie in (0, 1] (the hold-out's prediction "
            f"residual over the RMS of its motion), got {lrn.validation_residual}"
        )
    if lrn.feedforward_modes not in ("all", "static"):
        raise DeploymentError(
            f"{where}.feedforward_modes: expected 'all' or 'static', got {lrn.feedforward_modes!r}"
        )
    if not 0 <= lrn.feedforward_significance < 1:
        raise DeploymentError(
            f"{where}.feedforward_significance: must lie in [0, 1) (0 = keep every exostate "
            f"mode), got {lrn.feedforward_significance}"
        )
    if not (math.isfinite(lrn.refresh_orbits) and lrn.refresh_orbits >= 0):
        raise DeploymentError(f"{where}.refresh_orbits: must be >= 0 (0 = no refresh)")
    if not (math.isfinite(lrn.trim_orbits) and lrn.trim_orbits >= 0):
        raise DeploymentError(f"{where}.trim_orbits: must be >= 0 (0 = no trim)")
    _positive(f"{where}.station_radius", lrn.station_radius)
    if not 0 < lrn.trim_gain <= 1:
        raise DeploymentError(f"{where}.trim_gain: must lie in (0, 1]")
    if lrn.K0 is None or len(lrn.K0) != 1 or len(lrn.K0[0]) != 4:
        raise DeploymentError(f"{where}.K0: expected 4 values (gain on x, y, xdot, ydot)")
    if lrn.step not in ("harmonic", "constant", "implicit") or lrn.bounds not in (
        "linear",
        "geometric",
    ):
        raise DeploymentError(
            f"{where}.step/bounds: expected step 'harmonic', 'constant' or 'implicit' and "
            "bounds 'linear' or 'geometric'"
        )
    if lrn.step == "implicit" and not lrn.step_size < 1:
        raise DeploymentError(
            f"{where}.step_size: an implicit step's size is a fraction below 1 (of the Euler "
            f"stability limit), got {lrn.step_size}"
        )


def check_deputies(dep: Deployment) -> None:
    """At least one deputy; each with a unique name, and its craft, navigation and learning
    in range."""
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
        _check_deputy_craft(w, d)
        _check_deputy_navigation(w, d, dep)
        _check_deputy_learning(w, d)


def check_panel(area_factor: float | None, normal_angle: float | None) -> None:
    """Raise ValueError unless a panel fault's values are numbers in range (area_factor in
    (0, 100] as a deputy's, normal_angle in (0, 90) deg), at least one of them given: the one
    check of the deployment file, ``ddvi fault`` and the environment's run-time fault
    messages."""
    if area_factor is None and normal_angle is None:
        raise ValueError("a panel fault changes area_factor, normal_angle or both: give one")
    for value in (area_factor, normal_angle):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)):
            raise ValueError(
                f"area_factor and normal_angle are numbers, got {value!r} ({type(value).__name__})"
            )
    if area_factor is not None and not 0 < area_factor <= MAX_AREA_FACTOR:
        raise ValueError(
            f"area_factor must lie in (0, {MAX_AREA_FACTOR:g}] (as a deputy's), got {area_factor}"
        )
    if normal_angle is not None and not (0 < normal_angle < 90):
        raise ValueError(
            f"normal_angle must lie in (0, 90) deg (the facet normal in the body x-y plane), "
            f"got {normal_angle}"
        )


def _check_fault_values(w: str, f: Fault, backend: str) -> None:
    """One fault's kind-specific values: a panel's area or angle (built-in truth only), the
    biases (a navigation bias's range)."""
    if f.kind == "panel":
        try:
            check_panel(f.area_factor, f.normal_angle)
        except ValueError as exc:
            raise DeploymentError(f"{w}: {exc}") from None
    elif f.area_factor is not None or f.normal_angle is not None:
        raise DeploymentError(
            f"{w}: area_factor and normal_angle belong to panel faults, not {f.kind!r}"
        )
    if f.kind == "outage" and not (math.isfinite(f.duration_orbits) and f.duration_orbits > 0):
        raise DeploymentError(
            f"{w}.duration_orbits: an outage lasts a time > 0 (chief orbits), "
            f"got {f.duration_orbits}"
        )
    if f.kind != "outage" and f.duration_orbits:
        raise DeploymentError(f"{w}: duration_orbits belongs to outage faults, not {f.kind!r}")
    for key in ("position_bias", "velocity_bias"):
        if len(getattr(f, key)) != 3:
            raise DeploymentError(f"{w}.{key}: expected 3 values (Hill x, y, z)")
    check_bias(w, f.position_bias, f.velocity_bias)
    if f.kind == "panel" and backend == "basilisk":
        raise DeploymentError(
            f"{w}: panel faults need the built-in truth (Basilisk 2.12's "
            "facetDragDynamicEffector cannot change a facet's area or normal once added)"
        )


def check_fault(dep: Deployment, w: str, f: Fault) -> None:
    """One fault, whenever it comes: a known kind, a deputy of ``dep``, values in range.  A
    [[fault]] (``check_faults`` adds its time), and the one check of ``ddvi fault RUN
    panel|bias|outage`` against the run's deployment."""
    names = [d.name for d in dep.deputy]
    if f.kind not in FAULT_KINDS:
        raise DeploymentError(f"{w}.kind: expected one of {', '.join(FAULT_KINDS)}, got {f.kind!r}")
    if f.deputy not in names:
        raise DeploymentError(f"{w}.deputy: {f.deputy!r} is not one of {', '.join(names)}")
    _check_fault_values(w, f, dep.environment.backend)


def check_faults(dep: Deployment) -> None:
    """[[fault]]: a known kind, an existing deputy, a time within the run, values in range."""
    for k, f in enumerate(dep.fault):
        w = f"fault[{k}]"
        if not (math.isfinite(f.at_orbits) and 0 <= f.at_orbits < dep.run.orbits):
            raise DeploymentError(
                f"{w}.at_orbits: must lie in [0, run.orbits = {dep.run.orbits:g}), "
                f"got {f.at_orbits}"
            )
        if f.kind == "outage" and f.at_orbits <= 0:
            raise DeploymentError(
                f"{w}.at_orbits: an outage starts after the first measurement (> 0), got "
                f"{f.at_orbits}"
            )
        check_fault(dep, w, f)


ROS_DOMAIN_IDS = range(233)
"""The ROS 2 domain ids (``ROS_DOMAIN_ID``): 0 to 232."""
ROS_NAME_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
"""One token of a ROS 2 topic name: a deputy's name is one in its topics' names."""


def check_ros2_endpoint(endpoint: str) -> int:
    """The port of a ROS 2 endpoint ``tcp/HOST:PORT`` (rmw_zenoh's kind of endpoint); ValueError
    saying what to give."""
    match = ENDPOINT.match(endpoint) if isinstance(endpoint, str) else None
    if match is None or match.group(1) != "tcp" or not 0 < int(match.group(3)) < 65536:
        raise ValueError(
            f"expected a Zenoh endpoint tcp/HOST:PORT (rmw_zenoh's router is "
            f"tcp/127.0.0.1:7447), got {endpoint!r}"
        )
    return int(match.group(3))


def check_ros2(dep: Deployment) -> None:
    """[ros2]: an endpoint that is not the run's own bus, a ROS domain id, known topics; with
    the gateway on, deputy names that are ROS 2 name tokens."""
    ros2 = dep.ros2
    try:
        port = check_ros2_endpoint(ros2.endpoint)
    except ValueError as exc:
        raise DeploymentError(f"ros2.endpoint: {exc}") from None
    if port == dep.bus.port:
        raise DeploymentError(
            f"ros2.endpoint: port {port} is bus.port, the run's own bus; the ROS 2 side is "
            "another Zenoh network: give it another port"
        )
    if ros2.domain_id not in ROS_DOMAIN_IDS:
        raise DeploymentError(f"ros2.domain_id: expected 0 to 232, got {ros2.domain_id}")
    for k, topic in enumerate(ros2.topics):
        _one_of(f"ros2.topics[{k}]", topic, ROS2_TOPICS)
        if topic in ros2.topics[:k]:
            raise DeploymentError(f"ros2.topics[{k}]: {topic!r} is given twice")
    if not ros2.enabled:
        for k, d in enumerate(dep.deputy):
            if d.controller == "ros2":
                raise DeploymentError(
                    f"deputy[{k}].controller: 'ros2' flies on a ROS 2 node's commands, which "
                    "come through the ROS 2 gateway: set [ros2] enabled = true or run with --ros2"
                )
        return
    for k, d in enumerate(dep.deputy):
        if not ROS_NAME_TOKEN.fullmatch(d.name):
            raise DeploymentError(
                f"deputy[{k}].name: {d.name!r} names ROS 2 topics (/{d.name}/odom), whose "
                "tokens start with a letter or _: rename it, or turn [ros2] off"
            )


CHECKS: tuple[Callable[[Deployment], None], ...] = (
    check_ranges,  # first: every number finite and physical (services.config.ranges)
    check_run,
    check_bus,
    check_environment,
    check_bodies,
    check_atmosphere,
    check_deputies,
    check_links,
    check_restarts,
    check_faults,
    check_hosts,
    check_ros2,
)
"""The semantic checks, in the order they run."""


def validate(dep: Deployment) -> None:
    """Run every check of :data:`CHECKS`; the first problem raises DeploymentError."""
    for check in CHECKS:
        check(dep)


def deployment_from_table(table: dict[str, Any], path: str = "") -> Deployment:
    """A checked Deployment from a parsed TOML table (``path``: the file it came from); each
    deputy's learning takes the keys its table gives, the mission's for the rest
    (``ddvi_core.learning_config.mission_learning``, by the deputy's attitude limit)."""
    dep = from_table(Deployment, table, keys=DEPLOYMENT_KEYS, error=DeploymentError)
    deputies = [
        replace(
            d,
            learning=mission_learning(
                d.learning, t.get("learning", {}), d.attitude_limit, dep.run.orbits
            ),
        )
        for d, t in zip(dep.deputy, table.get("deputy", []), strict=True)
    ]
    dep = replace(dep, deputy=deputies, path=path)
    validate(dep)
    return dep
