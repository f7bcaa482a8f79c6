"""The benchmarks' own measuring tools: the learning benchmark's search for the fewest
iterations to a gain tolerance, and the mission benchmark's memory of a process tree."""

from __future__ import annotations

import subprocess
import sys

import pytest

from benchmarks.learning import ddvi_after, iterations_to
from benchmarks.mission import _PeakMemory
from ddvi_core.systems import BUILTIN_SYSTEMS


def test_iterations_to_finds_where_the_gain_error_crosses_the_tolerance() -> None:
    system = BUILTIN_SYSTEMS["rendezvous"]()
    n, wall, err = iterations_to(system, 1e-3, upper=30_000, resolution=2_000)
    assert err < 1e-3
    assert err == pytest.approx(ddvi_after(system, n)[1], rel=1e-9)
    assert ddvi_after(system, n - 2_000)[1] >= 1e-3  # not reached a resolution earlier
    assert 0 < n < 30_000
    assert wall > 0


def test_iterations_to_refuses_a_bound_that_does_not_reach_the_tolerance() -> None:
    system = BUILTIN_SYSTEMS["rendezvous"]()
    with pytest.raises(ValueError, match=r"after 100 iterations: not below 0\.001"):
        iterations_to(system, 1e-3, upper=100, resolution=10)


def test_peak_memory_counts_a_descendant_once() -> None:
    """A grandchild holding 200 MB of its own, under a parent that holds nothing: the
    summed memory of the tree sees it, and once."""
    code = "import numpy, time; a = numpy.ones(25_000_000); time.sleep(2.5)"
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import subprocess, sys; subprocess.run([sys.executable, '-c', {code!r}])",
        ]
    )
    memory = _PeakMemory(parent.pid)
    parent.wait()
    peak = memory.stop()
    assert 200e6 < peak < 400e6
