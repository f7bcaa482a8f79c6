"""The Basilisk environment backend against the built-in truth: the default mission's chief
and deputy, one orbit, same initial state and attitude commands, relative Hill position.

Measured with basilisk_step = 1 s: at most 4e-7 m apart without drag (J2 on or
off); 0.12 m (J2 off) and 0.16 m (J2 on) apart with drag, where drag itself moves the deputy
36 m relative to the chief over that orbit (the drag-off run against the drag-on one).  The
difference with drag is Basilisk's hold of density and attitude over its step, linear in the
step (with a constant 0.15 MRP command: 0.38 m at 1 s, 1.9 m at 5 s, 3.8 m at 10 s).
"""

from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np
import pytest

from ddvi_core.orbit import body_dcm, mrp_to_dcm, rv_to_hill
from services.config import DeploymentError, deployment_from_table, load_deployment
from services.model import BuiltinTruth, duration, open_truth

ONE_DEPUTY = """
[run]
orbits = 1.0
[environment]
backend = "{backend}"
j2 = {j2}
drag = {drag}
[[deputy]]
name = "d1"
controller = "lqr"
"""


def _deployment(backend: str, j2: bool, drag: bool):
    import tomllib

    text = ONE_DEPUTY.format(backend=backend, j2=str(j2).lower(), drag=str(drag).lower())
    return deployment_from_table(tomllib.loads(text), "test")


def _commands(k: int) -> np.ndarray:
    """A relative-MRP command per flight-software step that exercises all three axes."""
    u = 2 * math.pi * k / 30
    return np.array([[0.03 * math.cos(u), -0.02, 0.15 * math.sin(u)]])


def _fly(truth, dep) -> tuple[np.ndarray, np.ndarray]:
    """Relative Hill positions (K, 3) at every navigation sample of one orbit, and the final
    inertial state (2, 6)."""
    fsw, t_end = dep.run.fsw_period, duration(dep)
    rel = []
    for k in range(round(t_end / fsw)):
        _, traj = truth.step(k * fsw, _commands(k))
        for x in traj:
            rel.append(rv_to_hill(x[0, :3], x[0, 3:], x[1, :3], x[1, 3:])[:3])
    return np.array(rel), truth.state


@pytest.fixture(scope="module")
def basilisk():
    return pytest.importorskip(
        "Basilisk", reason="Basilisk is not installed: pip install -e '.[basilisk]'"
    )


@pytest.mark.parametrize(
    ("j2", "drag", "tolerance"),
    [(False, False, 1e-5), (True, False, 1e-5), (False, True, 0.5), (True, True, 0.5)],
)
def test_basilisk_truth_matches_the_builtin_truth_over_one_orbit(basilisk, j2, drag, tolerance):
    from services.model.basilisk import BasiliskTruth

    bsk_dep, builtin_dep = _deployment("basilisk", j2, drag), _deployment("builtin", j2, drag)
    bsk = open_truth(bsk_dep)
    assert isinstance(bsk, BasiliskTruth)
    try:
        rel_bsk, _ = _fly(bsk, bsk_dep)
        sigma_bsk = bsk.sigma_BN
        final = bsk.state
    finally:
        bsk.close()
    rel_builtin, _ = _fly(BuiltinTruth(builtin_dep), builtin_dep)
    gap = np.linalg.norm(rel_bsk - rel_builtin, axis=1)
    moved = np.linalg.norm(rel_builtin[-1] - rel_builtin[0])
    print(
        f"j2={j2} drag={drag}: max |rho_bsk - rho_builtin| = {gap.max():.3g} m "
        f"(final {gap[-1]:.3g} m; relative motion over the orbit {moved:.0f} m)"
    )
    assert gap.max() < tolerance
    # Basilisk's attitude is the command composed with each craft's own Hill frame (held over
    # a 1 s step while the Hill frame turns by n * 1 s, about 1.2 mrad)
    n_last = round(duration(bsk_dep) / bsk_dep.run.fsw_period) - 1
    sigma_rel = np.vstack([np.zeros(3), _commands(n_last)])
    expected = body_dcm(final[:, :3], final[:, 3:], sigma_rel)
    got = mrp_to_dcm(sigma_bsk)
    for e, g in zip(expected, got, strict=True):
        angle = math.acos(np.clip((np.trace(e @ g.T) - 1) / 2, -1, 1))
        assert angle < 2e-3


def test_drag_moves_the_deputy_relative_to_the_chief(basilisk):
    """The comparison above would pass vacuously if drag did nothing in either backend."""
    rel = {}
    for drag in (False, True):
        dep = _deployment("basilisk", True, drag)
        truth = open_truth(dep)
        try:
            rel[drag], _ = _fly(truth, dep)
        finally:
            truth.close()
    assert np.linalg.norm(rel[True][-1] - rel[False][-1]) > 20.0  # 36 m measured


def test_basilisk_step_must_divide_the_navigation_period() -> None:
    table = {"environment": {"backend": "basilisk", "basilisk_step": 3.0}}
    with pytest.raises(DeploymentError, match=r"environment\.basilisk_step"):
        deployment_from_table(table, "test")


def test_missing_basilisk_names_the_extra(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "services.model.basilisk", None)  # import fails
    dep = dataclasses.replace(
        load_deployment(None),
        environment=dataclasses.replace(load_deployment(None).environment, backend="basilisk"),
    )
    with pytest.raises(RuntimeError, match=r"ddvi-fsw\[basilisk\]|\.\[basilisk\]"):
        open_truth(dep)
