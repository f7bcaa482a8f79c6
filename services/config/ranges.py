"""Physical plausibility of every numeric deployment key, checked before anything starts.

A value out of range raises DeploymentError naming the key, the range and what it would do:
orbits above the atmosphere's floor (``environment.min_altitude``) with an eccentricity below
one for every craft, a mission of at least one flight-software step, periods, counts and seeds
a service can use, delays shorter than the mission, bus endpoints zenoh can open, and a number
of deputies the launcher can start (:data:`MAX_DEPUTIES`; ``services.ground.launch.lifecycle``
estimates the processes and memory against the machine's before a run starts).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable

from ddvi_core.constants import MU_EARTH, R_EARTH
from services.config.deployment import Deployment, DeploymentError, Deputy, Orbit
from services.interface.links import LinkSpec

MAX_DEPUTIES = 100
"""Deputies a deployment may have: each is two processes (navigation, controller)."""
MAX_SEED = 2**32 - 1  # numpy's seeds
MAX_ORBITS = 10_000.0
MAX_RADIUS = 1e9  # m: beyond the Moon's orbit, no drag, no rendezvous by drag
ENDPOINT = re.compile(r"^(tcp|udp|tls|quic)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9.-]*):(\d+)$")
RUN_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")
MAX_POSITION_BIAS = 1e7  # m: a navigation bias, the deputy's or a bias fault's
MAX_VELOCITY_BIAS = 1e4  # m/s
MAX_AREA_FACTOR = 100.0  # a facet's true area over the nominal: a craft's or a panel fault's


def within(where: str, value: float, lo: float, hi: float, *, open_lo: bool = False) -> None:
    """Raise DeploymentError unless ``value`` is a finite number in [lo, hi] ((lo, hi] with
    ``open_lo``)."""
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if ok and (value > lo if open_lo else value >= lo) and value <= hi:
        return
    interval = f"{'(' if open_lo else '['}{lo:g}, {hi:g}]"
    raise DeploymentError(f"{where}: expected a finite number in {interval}, got {value!r}")


def _all_within(where: str, values: Iterable[float], lo: float, hi: float, **kw: bool) -> None:
    for k, v in enumerate(values):
        within(f"{where}[{k}]", v, lo, hi, **kw)


def check_bias(where: str, position: Iterable[float], velocity: Iterable[float]) -> None:
    """A navigation bias (a deputy's ``navigation`` or a bias fault, scheduled or from the
    ground): ``position_bias`` m and ``velocity_bias`` m/s, each component finite and within
    :data:`MAX_POSITION_BIAS` and :data:`MAX_VELOCITY_BIAS`."""
    _all_within(f"{where}.position_bias", position, -MAX_POSITION_BIAS, MAX_POSITION_BIAS)
    _all_within(f"{where}.velocity_bias", velocity, -MAX_VELOCITY_BIAS, MAX_VELOCITY_BIAS)


def check_orbit(where: str, o: Orbit, floor: float) -> None:
    """An elliptic orbit whose perigee lies above ``floor`` m of altitude, angles in degrees."""
    within(f"{where}.e", o.e, 0.0, 1.0 - 1e-9)
    within(f"{where}.a", o.a, R_EARTH, MAX_RADIUS, open_lo=True)
    perigee = o.a * (1.0 - o.e) - R_EARTH
    if perigee < floor:
        raise DeploymentError(
            f"{where}: perigee altitude {perigee / 1e3:.1f} km (a = {o.a:g} m, e = {o.e:g}) is "
            f"below environment.min_altitude = {floor / 1e3:g} km: the craft would re-enter at "
            "once; a is the semi-major axis in metres from the Earth's centre"
        )
    within(f"{where}.i", o.i, 0.0, 180.0)
    for key in ("raan", "argp", "f"):
        within(f"{where}.{key}", getattr(o, key), -360.0, 360.0)


def check_run_ranges(dep: Deployment) -> None:
    """run: a safe name, sane periods, counts and seed."""
    r = dep.run
    if not isinstance(r.name, str) or not RUN_NAME.match(r.name):
        raise DeploymentError(
            f"run.name: expected 1 to 64 of letters, digits, '_', '.' and '-' (not starting with "
            f"'.' or '-'; it names the run folder and the bus keys), got {r.name!r}"
        )
    within("run.orbits", r.orbits, 0.0, MAX_ORBITS, open_lo=True)
    within("run.nav_period", r.nav_period, 0.01, 3600.0)
    within("run.fsw_period", r.fsw_period, r.nav_period, 86400.0)
    within("run.rate", r.rate, 0.0, 1e6, open_lo=True)
    within("run.command_deadline", r.command_deadline, 0.0, 3600.0, open_lo=True)
    within("run.startup_timeout", r.startup_timeout, 0.0, 3600.0, open_lo=True)
    within("run.hang_timeout", r.hang_timeout, 0.0, 3600.0, open_lo=True)
    within("run.nav_stale_limit", r.nav_stale_limit, 0.0, 86400.0)
    within("run.seed", r.seed, 0, MAX_SEED)
    within("run.status_every", r.status_every, 1, 1_000_000)


def check_bus_ranges(dep: Deployment) -> None:
    """bus.connect: endpoints ``proto/host:port`` zenoh can open."""
    for k, endpoint in enumerate(dep.bus.connect):
        m = ENDPOINT.match(endpoint) if isinstance(endpoint, str) else None
        if m is None or not 0 < int(m.group(3)) < 65536:
            raise DeploymentError(
                f"bus.connect[{k}]: expected an endpoint like 'tcp/192.168.1.2:7447' (tcp, udp, "
                f"tls or quic; a port 1..65535), got {endpoint!r}"
            )


def check_body_ranges(dep: Deployment) -> None:
    """environment, atmosphere, spacecraft and chief: physical values."""
    env, atm, sc = dep.environment, dep.atmosphere, dep.spacecraft
    within("environment.density_factor", env.density_factor, 0.0, 1e3, open_lo=True)
    within("environment.max_step", env.max_step, 0.0, 3600.0, open_lo=True)
    within("environment.min_altitude", env.min_altitude, 0.0, 2000e3)
    within("environment.rtol", env.rtol, 1e-14, 1e-3)
    within("environment.basilisk_step", env.basilisk_step, 0.0, dep.run.nav_period, open_lo=True)
    within("atmosphere.rho0", atm.rho0, 0.0, 1.3, open_lo=True)  # kg/m^3: sea level is 1.225
    within("atmosphere.h_ref", atm.h_ref, 0.0, 2000e3)
    within("atmosphere.scale_height", atm.scale_height, 100.0, 1e6)
    within("spacecraft.mass", sc.mass, 0.0, 1e6, open_lo=True)
    within("spacecraft.area", sc.area, 0.0, 1e4, open_lo=True)
    within("spacecraft.cd", sc.cd, 0.0, 10.0, open_lo=True)
    within("spacecraft.normal_angle", sc.normal_angle, 0.0, 90.0, open_lo=True)
    check_orbit("chief", dep.chief, env.min_altitude)
    within("chief.area_factor", dep.chief.area_factor, 0.0, MAX_AREA_FACTOR, open_lo=True)


def _check_deputy_ranges(w: str, d: Deputy, dep: Deployment) -> None:
    """One deputy's orbit, slot, panel, navigation and learning numbers."""
    check_orbit(f"{w}.orbit", d.orbit, dep.environment.min_altitude)
    within(f"{w}.y_ref", d.y_ref, -1e7, 1e7)
    within(f"{w}.area_factor", d.area_factor, 0.0, MAX_AREA_FACTOR, open_lo=True)
    nav = d.navigation
    within(f"{w}.navigation.position_noise", nav.position_noise, 0.0, 1e6)
    within(f"{w}.navigation.velocity_noise", nav.velocity_noise, 0.0, 1e3)
    check_bias(f"{w}.navigation", nav.position_bias, nav.velocity_bias)
    within(f"{w}.navigation.seed", nav.seed, 0, MAX_SEED)
    lrn, where = d.learning, f"{w}.learning"
    within(f"{where}.seed", lrn.seed, 0, MAX_SEED)
    within(f"{where}.max_iterations", lrn.max_iterations, 1, 10**9)
    within(f"{where}.tol", lrn.tol, 0.0, 1.0, open_lo=True)
    within(f"{where}.step_size", lrn.step_size, 0.0, 1e6, open_lo=True)
    within(f"{where}.bound_base", lrn.bound_base, 0.0, 1e12, open_lo=True)
    within(f"{where}.learn_at_orbits", lrn.learn_at_orbits, 0.0, MAX_ORBITS, open_lo=True)
    within(f"{where}.retry_orbits", lrn.retry_orbits, 0.0, MAX_ORBITS, open_lo=True)
    _all_within(
        f"{where}.exploration_frequencies", lrn.exploration_frequencies, 0.0, 1e3, open_lo=True
    )
    if lrn.K0 is not None:
        _all_within(f"{where}.K0", [v for row in lrn.K0 for v in row], -1e12, 1e12)


def check_deputy_ranges(dep: Deployment) -> None:
    """At most :data:`MAX_DEPUTIES` deputies, each with physical values."""
    if len(dep.deputy) > MAX_DEPUTIES:
        raise DeploymentError(
            f"deputy: {len(dep.deputy)} deputies is {2 * len(dep.deputy) + 2} processes; at most "
            f"{MAX_DEPUTIES} deputies are run (split the swarm into several runs)"
        )
    for k, d in enumerate(dep.deputy):
        _check_deputy_ranges(f"deputy[{k}]", d, dep)


def mission_seconds(dep: Deployment) -> float:
    """The mission's length (s): its whole flight-software steps, as services.model.duration."""
    period = 2.0 * math.pi * math.sqrt(dep.chief.a**3 / MU_EARTH)
    return math.floor(dep.run.orbits * period / dep.run.fsw_period + 1e-9) * dep.run.fsw_period


def check_link_latency(where: str, link: LinkSpec, duration: float) -> None:
    """A link's delay + jitter shorter than the mission (``duration`` s): a [[link]], or a link
    impaired at run time (``services.config.wiring.check_link_fault``)."""
    latency = link.delay + link.jitter
    if not latency < duration:
        raise DeploymentError(
            f"{where}: delay + jitter = {latency:g} s is not shorter than the mission "
            f"({duration:.0f} s): every message on it would be lost; give a delay + jitter "
            f"below {duration:.0f} s"
        )


def check_link_ranges(dep: Deployment, duration: float) -> None:
    """[[link]] and [[restart]]: delays shorter than the mission, bounded restarts."""
    for k, link in enumerate(dep.link):
        check_link_latency(f"link[{k}]", link, duration)
    for k, r in enumerate(dep.restart):
        within(f"restart[{k}].max_restarts", r.max_restarts, 0, 1000)


def check_ranges(dep: Deployment) -> None:
    """Every numeric key in its physical range (the first problem raises DeploymentError);
    runs before the other checks, whose arithmetic then sees finite, sane numbers."""
    check_run_ranges(dep)
    check_bus_ranges(dep)
    check_body_ranges(dep)
    period = 2.0 * math.pi * math.sqrt(dep.chief.a**3 / MU_EARTH)
    r = dep.run
    if r.orbits * period < r.fsw_period:
        raise DeploymentError(
            f"run.orbits: {r.orbits:g} orbits ({r.orbits * period:.3g} s) is less than one "
            f"flight-software step (run.fsw_period = {r.fsw_period:g} s)"
        )
    check_deputy_ranges(dep)
    check_link_ranges(dep, mission_seconds(dep))
