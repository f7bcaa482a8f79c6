"""The learning benchmark's search for the fewest iterations to a gain tolerance."""

from __future__ import annotations

import dataclasses

import pytest

from benchmarks.learning import iterations_to
from ddvi_core.solve import reference_errors, solve
from ddvi_core.systems import BUILTIN_SYSTEMS, System


def _error_after(system: System, n: int) -> float:
    cut = dataclasses.replace(system.learning, max_iterations=n)
    sol = solve(dataclasses.replace(system, learning=cut), "ddvi")
    return reference_errors(system, sol)["K_error"]


def test_iterations_to_finds_where_the_gain_error_crosses_the_tolerance() -> None:
    system = BUILTIN_SYSTEMS["rendezvous"]()
    n, wall, err = iterations_to(system, 1e-3, upper=30_000, resolution=2_000)
    assert err < 1e-3
    assert err == pytest.approx(_error_after(system, n), rel=1e-9)
    assert _error_after(system, n - 2_000) >= 1e-3  # not reached a resolution earlier
    assert 0 < n < 30_000
    assert wall > 0


def test_iterations_to_refuses_a_bound_that_does_not_reach_the_tolerance() -> None:
    system = BUILTIN_SYSTEMS["rendezvous"]()
    with pytest.raises(ValueError, match=r"after 100 iterations: not below 0\.001"):
        iterations_to(system, 1e-3, upper=100, resolution=10)
