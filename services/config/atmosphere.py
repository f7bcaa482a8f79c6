"""The checks of a deployment's ``[atmosphere]`` table beyond its numbers' ranges: the truth's
model, and for NRLMSIS its epoch, space weather and storm profile."""

from __future__ import annotations

from datetime import datetime, timedelta

from services.config.deployment import Deployment, DeploymentError

ATMOSPHERE_MODELS = ("exponential", "nrlmsis")
"""atmosphere.model: the exponential profile, or NRLMSIS 2.1 (pymsis) for the truth."""


def parse_epoch(epoch: str) -> datetime:
    """atmosphere.epoch as a UTC datetime without time zone; ValueError saying what to give."""
    try:
        when = datetime.fromisoformat(epoch) if isinstance(epoch, str) else None
    except ValueError:
        when = None
    if when is None:
        raise ValueError(
            f'expected an ISO 8601 UTC time such as "2024-03-20T00:00:00Z", got {epoch!r}'
        )
    if when.tzinfo is not None:
        if when.utcoffset() != timedelta(0):
            raise ValueError(f"give the epoch in UTC (ending Z or +00:00), got {epoch!r}")
        when = when.replace(tzinfo=None)
    if not 1961 <= when.year <= 2099:
        raise ValueError(f"expected a year between 1961 and 2099, got {epoch!r}")
    return when


def _check_storm(storm: list[list[float]]) -> None:
    """atmosphere.storm: rows of [t_s, ap] or [t_s, f107, ap], one width, times increasing."""
    widths = {len(row) for row in storm}
    if storm and (len(widths) != 1 or widths - {2, 3}):
        raise DeploymentError(
            "atmosphere.storm: expected rows [t_s, ap] or [t_s, f107, ap], all the same "
            f"width, got widths {sorted(widths)}"
        )
    times = [row[0] for row in storm]
    for k in range(1, len(times)):
        if not times[k] > times[k - 1]:
            raise DeploymentError(
                f"atmosphere.storm[{k}]: times must increase strictly (s), got {times[k]:g} "
                f"after {times[k - 1]:g}"
            )
    for k, row in enumerate(storm):
        if not 0.0 <= row[-1] <= 400.0:
            raise DeploymentError(f"atmosphere.storm[{k}]: ap must lie in [0, 400], got {row[-1]}")
        if len(row) == 3 and not 50.0 <= row[1] <= 400.0:
            raise DeploymentError(
                f"atmosphere.storm[{k}]: f107 must lie in [50, 400] sfu, got {row[1]}"
            )


def check_atmosphere(dep: Deployment) -> None:
    """atmosphere: a known model; for NRLMSIS a UTC epoch, space weather in range, a storm
    profile of increasing times, and the built-in truth (Basilisk's MSIS module is another
    model version)."""
    atm = dep.atmosphere
    if atm.model not in ATMOSPHERE_MODELS:
        quoted = " or ".join(repr(a) for a in ATMOSPHERE_MODELS)
        raise DeploymentError(f"atmosphere.model: expected {quoted}, got {atm.model!r}")
    if atm.model == "exponential":
        if atm.storm:
            raise DeploymentError(
                'atmosphere.storm: a storm profile drives NRLMSIS: set model = "nrlmsis" or '
                "remove it"
            )
        return
    try:
        parse_epoch(atm.epoch)
    except ValueError as exc:
        raise DeploymentError(f"atmosphere.epoch: {exc}") from None
    for key in ("f107", "f107a"):
        if not 50.0 <= getattr(atm, key) <= 400.0:
            raise DeploymentError(
                f"atmosphere.{key}: expected a solar flux in [50, 400] sfu (quiet sun about 70, "
                f"active 150 to 250), got {getattr(atm, key)}"
            )
    if not 0.0 <= atm.ap <= 400.0:
        raise DeploymentError(
            f"atmosphere.ap: expected Ap in [0, 400] (quiet 4, storm 100 and more), got {atm.ap}"
        )
    _check_storm(atm.storm)
    if dep.environment.backend == "basilisk":
        raise DeploymentError(
            'atmosphere.model = "nrlmsis" needs environment.backend = "builtin": Basilisk\'s '
            "msisAtmosphere is NRLMSISE-00, another model than the NRLMSIS 2.1 the built-in "
            "truth flies, so the two backends would not fly the same truth"
        )
