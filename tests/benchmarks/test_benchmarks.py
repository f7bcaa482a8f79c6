"""The benchmarks' own measuring tools: the learning benchmark's search for the fewest
iterations to a gain tolerance, the mission benchmark's memory of a process tree and the live
benchmark's CPU of each of its processes, the one-process run's split of its work among the
services, the lock-step floor, what ``ddvi bench`` says when the benchmarks cannot be
imported, and the twin benchmark's perfect learner on the truth's gains."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from benchmarks.floor import run_floor
from benchmarks.learning import EXPLICIT_STEP, ddvi_after, iterations_to
from benchmarks.live import ProcessCpu
from benchmarks.mission import _PeakMemory
from ddvi_core.systems import BUILTIN_SYSTEMS, System
from services.config import deployment_from_table, read_table
from services.flight.inprocess import run_in_process
from services.model import duration
from tests.support import wait_until


def _explicit_rendezvous() -> System:
    """The mission's learner by value iteration's explicit constant step: tens of thousands of
    iterations, so a search over its budget has room to bisect."""
    system = BUILTIN_SYSTEMS["rendezvous"]()
    return replace(system, learning=replace(system.learning, **EXPLICIT_STEP))


@pytest.mark.integration  # runs the mission's learner about a dozen times
def test_iterations_to_finds_where_the_gain_error_crosses_the_tolerance() -> None:
    system = _explicit_rendezvous()
    n, wall, err = iterations_to(system, 1e-3, upper=30_000, resolution=2_000)
    assert err < 1e-3
    assert err == pytest.approx(ddvi_after(system, n)[1], rel=1e-9)
    assert ddvi_after(system, n - 2_000)[1] >= 1e-3  # not reached a resolution earlier
    assert 0 < n < 30_000
    assert wall > 0


def test_iterations_to_refuses_a_bound_that_does_not_reach_the_tolerance() -> None:
    system = _explicit_rendezvous()
    with pytest.raises(ValueError, match=r"after 100 iterations: not below 0\.001"):
        iterations_to(system, 1e-3, upper=100, resolution=10)


@pytest.mark.integration
def test_peak_memory_counts_a_descendant_once() -> None:
    """A grandchild holding 200 MB of its own, under a parent that holds nothing: the
    summed memory of the tree sees it, and once."""
    # the grandchild says when it holds the 200 MB, and holds them until its stdin (the
    # parent's, this test's pipe) closes
    code = (
        "import numpy, sys; a = numpy.ones(25_000_000); print('held', flush=True); sys.stdin.read()"
    )
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import subprocess, sys; subprocess.run([sys.executable, '-c', {code!r}])",
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    assert parent.stdin is not None and parent.stdout is not None
    try:
        assert parent.stdout.readline() == b"held\n"
        memory = _PeakMemory(parent.pid)  # every read from now on sees all of it
        assert wait_until(lambda: memory.peak > 0, timeout=30)  # the first read of the tree
        peak = memory.stop()
    finally:
        parent.stdin.close()
        parent.wait(timeout=30)
    assert 200e6 < peak < 400e6


def test_process_cpu_reads_each_process_of_a_tree_by_the_module_it_runs() -> None:
    """A child busy for about a second under ``python -m timeit`` is counted under
    ``timeit``, its idle parent apart."""
    code = (
        "import subprocess, sys; "
        "subprocess.run([sys.executable, '-m', 'timeit', '-n', '20000000', 'sum(range(1))'])"
    )
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.DEVNULL)
    cpu = ProcessCpu(parent.pid, period=0.05)
    parent.wait(timeout=120)
    by_module = cpu.stop()
    assert by_module["timeit"] > 0.5
    assert sum(v for k, v in by_module.items() if k != "timeit") < 0.5 * by_module["timeit"]


def test_one_process_timing_splits_its_work_among_the_services() -> None:
    table = read_table(None)
    table["run"]["orbits"] = 1.0
    dep = deployment_from_table(table)
    timing: dict[str, float] = {}
    run_in_process(dep, timing=timing)
    shares = {"environment", "nav-lqr", "ctrl-lqr", "nav-ddvi", "ctrl-ddvi"}
    assert set(timing) == shares | {"steps"}
    assert timing["steps"] == round(duration(dep) / dep.run.fsw_period)
    assert all(timing[name] > 0 for name in shares)


@pytest.mark.integration
@pytest.mark.parametrize(
    ("layer", "topology"), [("plain", "peer"), ("bus", "peer"), ("plain", "routed")]
)
def test_floor_carries_every_message_and_waits_on_the_chain(layer: str, topology: str) -> None:
    """Three deputies, 40 steps: the monitor has every sample, and each step waits for the
    environment's 3 ms of work and then a navigation's 3 ms (lock-step: in series)."""
    spins = {"environment": 0.003, "nav-b": 0.003}
    floor = run_floor(["a", "b", "c"], 40, samples=3, spins=spins, layer=layer, topology=topology)
    assert floor["steps"] == 40
    assert floor["received"] == 40 * (3 + 3 + 2 * 3) + 1
    assert floor["loop_s"] >= 40 * 0.006


@pytest.mark.integration
def test_routed_floor_records_every_message_through_the_access_controlled_router() -> None:
    """On the mission's topology every message of a step is recorded, one MCAP message each:
    a step's 3 samples of 2 truths, the exostate and a navigation, its clock and command;
    every put passed the router's access control (a refused one would be missing)."""
    floor = run_floor(["a"], 20, samples=3, layer="bus", topology="routed")
    assert floor["recorded"] == 20 * (3 * (2 + 1 + 1) + 1 + 1)


@pytest.mark.integration
def test_floor_ends_when_one_of_its_processes_fails() -> None:
    """A deputy name zenoh cannot put under: its processes fail at their first declaration,
    and the floor says which instead of waiting for them."""
    with pytest.raises(RuntimeError, match=r"floor: (nav-x\*|ctrl-x\*|environment) failed"):
        run_floor(["x*"], 5)


def test_floor_refuses_an_empty_mission_and_an_unknown_layer() -> None:
    with pytest.raises(ValueError, match="at least one deputy"):
        run_floor([], 10)
    with pytest.raises(ValueError, match="layer 'zmq' is not one of"):
        run_floor(["a"], 10, layer="zmq")
    with pytest.raises(ValueError, match="topology 'mesh' is not one of"):
        run_floor(["a"], 10, topology="mesh")


def test_ddvi_bench_without_the_benchmarks_says_why_in_one_line(monkeypatch, capsys) -> None:
    from services.cli import EXIT_USAGE, main

    monkeypatch.setitem(sys.modules, "benchmarks.run", None)  # import fails
    assert main(["bench", "--quick"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert err.startswith("ddvi bench: cannot import the benchmarks") and err.count("\n") == 1


def test_swarm_tables_are_valid_deployments_of_lqr_or_learning_deputies() -> None:
    from benchmarks.mission import swarm_table

    lqr = deployment_from_table(swarm_table(32, 2.0))
    assert [d.name for d in lqr.deputy] == [f"d{k:02d}" for k in range(32)]
    assert {d.controller for d in lqr.deputy} == {"lqr"}
    assert [d.y_ref for d in lqr.deputy][:2] == [-15500.0, -14500.0]
    learning = deployment_from_table(swarm_table(8, 2.0, controller="ddvi"))
    assert {d.controller for d in learning.deputy} == {"ddvi"}
    default = deployment_from_table(read_table(None))
    mine = learning.deputy[0].learning
    # as the default mission's learner, but its deadline, which follows from the mission's end
    assert mine.learn_until_orbits == mine.learn_at_orbits  # 2 orbits: before learn_at_orbits
    theirs = next(d for d in default.deputy if d.controller == "ddvi").learning
    assert mine == dataclasses.replace(theirs, learn_until_orbits=mine.learn_until_orbits)


def test_swarm_rows_compare_a_deputy_orbit_with_the_four_deputy_swarm() -> None:
    """The rows are ratios of the figures given: 32 deputies at 8 s of loop an orbit against
    4 at 1.5 s are 0.25 s against 0.375 s a deputy-orbit."""
    from benchmarks.mission import _swarm_rows

    def run(loop: float, cpu: float, pss: float, messages: int) -> dict:
        return {
            "loop_s": loop,
            "cpu_s": cpu,
            "pss_bytes": pss,
            "summary": {"messages": {"recorded": messages}},
        }

    results = {
        (1, "lqr"): (run(1.0, 4.0, 300e6, 1000), run(0.5, 1.0, 80e6, 0)),
        (4, "lqr"): (run(3.0, 10.0, 600e6, 4000), run(1.0, 2.0, 90e6, 0)),
        (32, "lqr"): (run(16.0, 60.0, 3200e6, 32000), run(8.0, 10.0, 100e6, 0)),
    }
    rows = {r["metric"]: r for r in _swarm_rows(32, "lqr", 2.0, results)}
    per_deputy = rows["32 lqr deputies: loop per deputy-orbit"]
    assert (per_deputy["project"], per_deputy["baseline"]) == (0.25, 0.375)
    assert per_deputy["cost_ratio"] == pytest.approx(2 / 3)
    assert rows["32 lqr deputies: loop per orbit, against one process"]["cost_ratio"] == 2.0
    assert rows["32 lqr deputies: peak memory (PSS) per deputy"]["project"] == 100.0
    assert rows["32 lqr deputies: messages recorded a second"]["project"] == 2000.0


@pytest.mark.integration  # one 40-orbit mission of one deputy, a few seconds
def test_the_velocity_noise_table_flies_the_paper_learner_alone_at_the_noise_asked() -> None:
    from benchmarks.velocity_noise import LEARNER, draw

    row = draw(0.0, 1)  # exact velocity, 1 m of position noise through the filter
    assert row["deputy"] == LEARNER and row["completed"]
    assert row["learned"] is True and row["learned_at_orbits"] == pytest.approx(15.0, abs=0.01)
    assert 0.05 < row["gain_error"] < 0.3  # learned, but not to K*: the position noise


def test_the_perfect_learner_on_the_truth_gains_flies_k_star_and_l_star_padded(
    monkeypatch,
) -> None:
    from benchmarks import twin_lqr
    from services.flight import learners
    from services.model import lqr_gains

    @dataclasses.dataclass
    class Fitted:
        K: np.ndarray
        L: np.ndarray

    fitted = Fitted(K=np.ones((1, 4)), L=np.ones((1, 6)))  # the exostate and its density ratio
    monkeypatch.setattr(learners, "fit_attempt", lambda *a, **k: (fitted, {"rank": 4}, "why"))
    dep = deployment_from_table(read_table("storm"))
    K, L = twin_lqr.GAINS["truth"](dep, dep.deputy[2])
    K_lqr, L_lqr = lqr_gains(dep, dep.deputy[0])
    # the truth's density and scale height: the LQR's gain error of docs/atmosphere.md
    assert np.linalg.norm(K - K_lqr) / np.linalg.norm(K) == pytest.approx(0.023, abs=0.002)
    assert not L_lqr.any() and L[0, 0] > 0.01  # the chief's extra drag, L* alone cancels it
    r, info, why = twin_lqr._perfect_fit((K, L))()
    assert why is None and info == {"rank": 4}  # every attempt accepted
    np.testing.assert_array_equal(r.K, K)
    np.testing.assert_array_equal(r.L, np.hstack([L, [[0.0]]]))


@pytest.mark.integration  # a 6.5-orbit mission of three deputies in NRLMSIS, a few seconds
def test_the_twin_benchmark_flies_another_deployment_with_the_perfect_learner_at_orbit_6(
    tmp_path,
) -> None:
    from benchmarks import twin_lqr
    from services.config import write_deployment

    table = read_table("storm")
    table["run"]["orbits"] = 6.5
    path = write_deployment(table, tmp_path, "storm-short")
    lqr, twin, learner, learned_at = twin_lqr._draw(twin_lqr.Draw(path, 1.0, 1, gains="truth"))
    assert learned_at == pytest.approx(twin_lqr.BY_ORBIT, abs=0.05)
    assert all(np.isfinite([lqr, twin, learner]))
