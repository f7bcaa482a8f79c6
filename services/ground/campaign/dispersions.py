"""Campaign files and their dispersions: what ``ddvi campaign`` reads, and how each run's
deployment is drawn from it.

A campaign file (TOML; docs/campaigns.md)::

    [campaign]
    deployment = "rendezvous"      # name or path (a relative path: from the campaign file)
    runs = 200
    seed = 2026                    # the campaign seed: every run's seed derives from it
    success_threshold = 100.0      # m: a deputy succeeds when its final along-track error is below

    [overrides.run]                # deployment keys set for every run (merged table by table)
    orbits = 10.0

    [[dispersion]]
    key = "environment.density_factor"      # any deployment key by its path
    distribution = "uniform"
    low = 0.8
    high = 1.25

    [[dispersion]]
    key = "deputy[*].initial.along_track"   # [*]: one draw, every deputy
    distribution = "normal"
    mean = -29139.0
    std = 2000.0
    low = -35000.0                          # bounds of a normal: truncated there
    high = -23000.0

Distributions: ``uniform`` (low, high), ``normal`` (mean, std; optional low, high: a truncated
normal), ``choice`` (values, optional weights), ``list`` (values: run i takes values[i mod
len]) and ``seed`` (an integer from the run's own stream: exploration or noise seeds).

Besides the deployment's keys, a deputy's initial relative state may be dispersed:
``deputy[k].initial.along_track`` and ``deputy[k].initial.radial`` (m, Hill y and x from the
chief) set its orbit's true anomaly and semi-major axis from the chief's (a near-circular chief:
y0 = a_chief (u_deputy - u_chief), x0 = a_deputy - a_chief).

Seeds: run i's stream is ``numpy.random.SeedSequence(seed, spawn_key=(i,))`` (the i-th child of
``SeedSequence(seed).spawn``), so a run's draws depend on the campaign seed and its index alone:
the same campaign gives the same runs, on any number of workers, in any order, resumed or not.
"""

from __future__ import annotations

import copy
import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ddvi_core.tables import TableError, from_table
from services.config import DeploymentError, deployment_from_table

DISTRIBUTIONS = ("uniform", "normal", "choice", "list", "seed")
INITIAL_KEYS = ("along_track", "radial")  # deputy[k].initial.<key>, m
_SEGMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\*|\d+)\])?$")


class CampaignError(ValueError):
    """A campaign file that cannot run; the message names the key."""


@dataclass(frozen=True)
class _DispersionTable:
    """A ``[[dispersion]]`` table's keys but ``values`` (any TOML scalars, read apart)."""

    key: str
    distribution: str
    low: float | None = None
    high: float | None = None
    mean: float | None = None
    std: float | None = None
    weights: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class Dispersion(_DispersionTable):
    """One dispersed deployment key and its distribution."""

    values: tuple = ()

    def __post_init__(self) -> None:
        d = self.distribution
        if d not in DISTRIBUTIONS:
            raise ValueError(
                f"Dispersion.distribution: expected one of {list(DISTRIBUTIONS)}, got {d!r}"
            )
        need = {
            "uniform": ("low", "high"),
            "normal": ("mean", "std"),
            "choice": ("values",),
            "list": ("values",),
            "seed": (),
        }[d]
        for name in need:
            if getattr(self, name) in (None, ()):
                raise ValueError(f"Dispersion.{name}: required by a {d} distribution")
        if d == "uniform" and not self.low < self.high:
            raise ValueError(f"Dispersion.high: must exceed low ({self.low:g}), got {self.high:g}")
        if d == "normal" and not self.std > 0:
            raise ValueError(f"Dispersion.std: must be above 0, got {self.std:g}")
        if d == "normal" and None not in (self.low, self.high) and not self.low < self.high:
            raise ValueError(f"Dispersion.high: must exceed low ({self.low:g})")
        if self.weights and (len(self.weights) != len(self.values) or d != "choice"):
            raise ValueError("Dispersion.weights: a choice's, one per value")
        if self.weights and (min(self.weights) < 0 or sum(self.weights) <= 0):
            raise ValueError("Dispersion.weights: non-negative, not all zero")
        parse_key(self.key)

    def draw(self, rng: np.random.Generator, index: int) -> Any:
        """One value for run ``index`` from its stream ``rng`` (a Python scalar)."""
        d = self.distribution
        if d == "uniform":
            return float(rng.uniform(self.low, self.high))
        if d == "normal":
            lo = -np.inf if self.low is None else (self.low - self.mean) / self.std
            hi = np.inf if self.high is None else (self.high - self.mean) / self.std
            from scipy.stats import truncnorm

            return float(truncnorm.rvs(lo, hi, loc=self.mean, scale=self.std, random_state=rng))
        if d == "choice":
            p = np.asarray(self.weights, float) / sum(self.weights) if self.weights else None
            return self.values[int(rng.choice(len(self.values), p=p))]
        if d == "list":
            return self.values[index % len(self.values)]
        return int(rng.integers(0, 2**31 - 1))


@dataclass(frozen=True)
class Campaign:
    """A campaign file's ``[campaign]`` table (overrides and dispersions read apart)."""

    deployment: str = "rendezvous"
    runs: int = 1
    seed: int = 0
    success_threshold: float = 100.0  # m, final along-track error
    name: str = ""

    def __post_init__(self) -> None:
        if self.runs < 1:
            raise ValueError(f"Campaign.runs: at least 1, got {self.runs}")
        if self.seed < 0:
            raise ValueError(f"Campaign.seed: a non-negative integer, got {self.seed}")
        if self.success_threshold <= 0:
            raise ValueError("Campaign.success_threshold: must be above 0 (m)")


@dataclass(frozen=True)
class CampaignSpec:
    """A checked campaign: its table, the deployment's merged table and the dispersions."""

    campaign: Campaign
    base: dict[str, Any]  # the deployment table with the overrides merged in
    dispersions: tuple[Dispersion, ...]
    path: str = ""


def parse_key(key: str) -> list[tuple[str, int | str | None]]:
    """``deputy[*].navigation.position_noise`` as [("deputy", "*"), ("navigation", None),
    ("position_noise", None)]; ValueError on a malformed path."""
    parts = []
    for seg in key.split("."):
        m = _SEGMENT.match(seg)
        if not m:
            raise ValueError(
                f"Dispersion.key: {key!r} is no key path (e.g. "
                "'environment.density_factor', 'deputy[*].orbit.f')"
            )
        index = m.group(2)
        parts.append((m.group(1), None if index is None else "*" if index == "*" else int(index)))
    return parts


def _targets(table: dict, parts: list, where: str = "") -> list[tuple[dict, str, str]]:
    """Every (dict, key, path) a key path names in ``table``, creating missing tables."""
    (name, index), rest = parts[0], parts[1:]
    path = f"{where}.{name}" if where else name
    if index is None:
        if not rest:
            return [(table, name, path)]
        sub = table.setdefault(name, {})
        if not isinstance(sub, dict):
            raise CampaignError(f"{path}: is a value, not a table")
        return _targets(sub, rest, path)
    items = table.get(name)
    if not isinstance(items, list) or not items:
        raise CampaignError(f"{path}: the deployment has no [[{name}]] to index")
    picks = range(len(items)) if index == "*" else [index]
    if index != "*" and index >= len(items):
        raise CampaignError(f"{path}[{index}]: the deployment has {len(items)} [[{name}]]")
    if not rest:
        raise CampaignError(f"{path}[{index}]: name a key inside it")
    return [t for k in picks for t in _targets(items[k], rest, f"{path}[{k}]")]


def set_key(table: dict[str, Any], key: str, value: Any) -> None:
    """Set a key path in a deployment table (in place); ``deputy[k].initial.*`` are kept
    under ``initial`` for :func:`place_deputies`."""
    for sub, name, _ in _targets(table, parse_key(key)):
        sub[name] = value


def place_deputies(table: dict[str, Any]) -> None:
    """Turn each deputy's ``initial`` table (along_track, radial, m) into its orbit elements
    (in place): f = chief f + along_track / a_chief (deg), a = a_chief + radial."""
    chief = table.get("chief", {})
    a_c = float(chief.get("a", 6678.136e3))
    for k, dep in enumerate(table.get("deputy", [])):
        init = dep.pop("initial", None)
        if init is None:
            continue
        for key in init:
            if key not in INITIAL_KEYS:
                raise CampaignError(
                    f"deputy[{k}].initial.{key}: unknown key; allowed: " + ", ".join(INITIAL_KEYS)
                )
        orbit = dep.setdefault("orbit", {})
        for key in ("e", "i", "raan", "argp"):
            orbit.setdefault(
                key, chief.get(key, {"e": 0.0, "i": 45.0, "raan": 20.0, "argp": 30.0}[key])
            )
        if "along_track" in init:
            orbit["f"] = float(chief.get("f", 20.0)) + math.degrees(init["along_track"] / a_c)
        if "radial" in init:
            orbit["a"] = a_c + float(init["radial"])


def run_stream(seed: int, index: int) -> tuple[np.random.Generator, int]:
    """Run ``index``'s generator and its integer seed (noise and ``run.seed``)."""
    ss = np.random.SeedSequence(seed, spawn_key=(index,))
    run_seed = int(ss.generate_state(1)[0] & 0x7FFFFFFF)
    return np.random.default_rng(ss), run_seed


def draw_run(spec: CampaignSpec, index: int) -> tuple[dict[str, Any], dict[str, Any], int]:
    """Run ``index``: its deployment table, the dispersed values by key and its seed."""
    rng, run_seed = run_stream(spec.campaign.seed, index)
    table = copy.deepcopy(spec.base)
    run = table.setdefault("run", {})
    run["seed"] = run_seed
    run["name"] = f"{spec.campaign.name}-{index:04d}"
    values = {}
    for d in spec.dispersions:
        values[d.key] = d.draw(rng, index)
        set_key(table, d.key, values[d.key])
    place_deputies(table)
    return table, values, int(table["run"]["seed"])


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``over`` merged in table by table (a value or a list replaces)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _values(where: str, raw: Any) -> tuple:
    if raw is None:
        return ()
    if not isinstance(raw, list) or not raw:
        raise CampaignError(f"{where}: expected a non-empty list of values, got {raw!r}")
    for k, v in enumerate(raw):
        if isinstance(v, dict | list) or (isinstance(v, float) and not math.isfinite(v)):
            raise CampaignError(f"{where}[{k}]: expected a number, string or boolean")
    return tuple(raw)


def spec_from_table(table: dict[str, Any], deployment_table: Any, path: str = "") -> CampaignSpec:
    """Check a parsed campaign file against its deployment; ``deployment_table`` maps the
    ``[campaign] deployment`` name to the deployment's raw table.  Raises CampaignError naming
    the key (a dispersion's key that is no deployment key: the deployment reader's message)."""
    for key in table:
        if key not in ("campaign", "overrides", "dispersion"):
            from_table(_Top, {key: None}, error=CampaignError)  # names the unknown key
    camp = from_table(Campaign, table.get("campaign", {}), "campaign", error=CampaignError)
    raw = table.get("dispersion", [])
    if not isinstance(raw, list):
        raise CampaignError("dispersion: expected [[dispersion]] tables")
    dispersions = []
    for k, d in enumerate(raw):
        where = f"dispersion[{k}]"
        if not isinstance(d, dict):
            raise CampaignError(f"{where}: expected a table")
        d = dict(d)
        values = _values(f"{where}.values", d.pop("values", None))
        keys = (*_DispersionTable.__dataclass_fields__, "values")  # for the message's list
        fields = from_table(_DispersionTable, d, where, keys=keys, error=CampaignError).__dict__
        try:
            dispersions.append(Dispersion(**fields, values=values))
        except ValueError as exc:
            raise CampaignError(f"{where}.{str(exc).removeprefix('Dispersion.')}") from None
    keys = [d.key for d in dispersions]
    if len(set(keys)) != len(keys):
        raise CampaignError(f"dispersion: a key dispersed twice: {keys}")
    overrides = table.get("overrides", {})
    if not isinstance(overrides, dict):
        raise CampaignError("overrides: expected a table of deployment tables")
    name = camp.name or str(camp.deployment).rsplit("/", 1)[-1].removesuffix(".toml")
    camp = Campaign(**{**camp.__dict__, "name": name})
    spec = CampaignSpec(
        camp, merge(deployment_table(camp.deployment), overrides), tuple(dispersions), path
    )
    _check(spec)
    return spec


@dataclass(frozen=True)
class _Top:
    campaign: int = 0
    overrides: int = 0
    dispersion: int = 0


def _check(spec: CampaignSpec) -> None:
    """Draw run 0 and the bounds of each dispersion and check the deployments they make."""
    try:
        deployment_from_table(spec.base)
    except DeploymentError as exc:
        raise CampaignError(f"overrides: {exc}") from None
    for k, d in enumerate(spec.dispersions):
        where = f"dispersion[{k}] ({d.key})"
        probes = [v for v in (d.low, d.high, d.mean) if v is not None] + list(d.values)
        for value in probes or [1]:
            table = copy.deepcopy(spec.base)
            try:
                set_key(table, d.key, value)
                place_deputies(table)
                deployment_from_table(table)
            except (CampaignError, DeploymentError, TableError) as exc:
                raise CampaignError(f"{where}: {exc}") from None
    deployment_from_table(draw_run(spec, 0)[0])
