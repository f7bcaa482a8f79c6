"""Built-in scenarios and system tables: a regulation problem plus how to learn it (a system
file is read by ``services.config.files.load_system``).

A system file is TOML with matrices ``A``, ``B``, ``Q``, ``R`` (lists of rows), optionally
``C``, ``D``, ``E``, ``F``, ``name``, ``description``, and a ``[learning]`` table (see
:class:`LearningConfig`; the keys :data:`SYSTEM_FILE_LEARNING_KEYS`): each key it gives is an
override, and every one it leaves out is derived from the system (:mod:`ddvi_core.defaults`).
The strict table reader (:mod:`ddvi_core.tables`) checks every key and value: every error names
the key and the problem in one line.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ddvi_core.defaults import derive_learning
from ddvi_core.learning_config import (
    FLIGHT_SCHEDULE_KEYS,
    SYSTEM_FILE_LEARNING_KEYS,
    LearningConfig,
    SystemFileError,
)
from ddvi_core.models import (
    DragRendezvous,
    paper_printed_problem,
    rendezvous_problem,
    thrust_rendezvous_problem,
)
from ddvi_core.problem import ProblemError, RegulationProblem
from ddvi_core.tables import Matrix, from_table, table_field

__all__ = [
    "BUILTIN_SYSTEMS",
    "FLIGHT_SCHEDULE_KEYS",
    "SYSTEM_FILE_LEARNING_KEYS",
    "LearningConfig",
    "System",
    "SystemFile",
    "SystemFileError",
    "system_from_table",
]


@dataclass(frozen=True)
class System:
    """A regulation problem and how to learn it; ``derived`` names the learning settings
    derived from the system (:mod:`ddvi_core.defaults`), ``given`` those a system file's
    [learning] table gives."""

    name: str
    description: str
    problem: RegulationProblem
    learning: LearningConfig = field(default_factory=LearningConfig)
    derived: tuple[str, ...] = ()
    given: tuple[str, ...] = ()


def _rendezvous() -> System:
    p = DragRendezvous()
    n = p.mean_motion
    u0 = math.radians(30.0 + 20.0)  # the chief's argument of latitude at t0
    return System(
        "rendezvous",
        "differential-drag rendezvous, in-plane Hill state, u = sigma3 "
        '(docs/design.md, "The default mission")',
        rendezvous_problem(p),
        LearningConfig(
            interval=600.0,
            intervals=135,
            sample_period=10.0,
            command_period=60.0,
            exploration_amplitude=0.1,
            exploration_frequencies=tuple(np.geomspace(0.3 * n, 30 * n, 6)),
            # the default mission's deputy (docs/design.md, "The default mission") seen in the
            # chief's Hill frame at t0
            x0=(176.4, -29139.8, 0.0, -0.4165),
            v0=(1.0, math.cos(u0), math.sin(u0), math.cos(2 * u0), math.sin(2 * u0)),
            seed=1,
            time_unit=n,
            step="implicit",
            step_size=0.5,
            bounds="geometric",
            state_scale=(1.0, 1.0, n, n),
            input_limit=0.2,
        ),
    )


def _thrust() -> System:
    p = DragRendezvous()
    n = p.mean_motion
    return System(
        "thrust-rendezvous",
        "same orbit, 3-axis thrust, full 6-state Hill model, p = 3: every assumption holds",
        thrust_rendezvous_problem(p),
        LearningConfig(
            interval=600.0,
            intervals=200,
            sample_period=2.0,
            command_period=60.0,
            exploration_amplitude=1e-3,
            exploration_frequencies=tuple(np.geomspace(0.3 * n, 30 * n, 6)),
            x0=(100.0, -200.0, 50.0, 0.0, 0.0, 0.0),
            v0=(1.0, 0.0) * 4,
            seed=1,
            time_unit=n,
            step="constant",
            step_size=0.02,
            bounds="geometric",
            state_scale=(1.0, 1.0, 1.0, n, n, n),
        ),
    )


def _paper() -> System:
    return System(
        "paper-printed",
        "the paper's matrices exactly as printed (fails its own assumptions: see `ddvi check`)",
        paper_printed_problem(),
    )


BUILTIN_SYSTEMS: dict[str, Callable[[], System]] = {
    "rendezvous": _rendezvous,
    "thrust-rendezvous": _thrust,
    "paper-printed": _paper,
}


@dataclass(frozen=True)
class SystemFile:
    """A system file's top-level table, as the table reader checks it (see the module
    docstring); :func:`system_from_table` turns it into a :class:`System`."""

    A: Matrix
    B: Matrix
    Q: Matrix
    R: Matrix
    C: Matrix | None = None
    D: Matrix | None = None
    E: Matrix | None = None
    F: Matrix | None = None
    name: str | None = None
    description: str = ""
    learning: LearningConfig = table_field(LearningConfig, keys=SYSTEM_FILE_LEARNING_KEYS)


def system_from_table(table: dict[str, Any], default_name: str = "system") -> System:
    """A System from a parsed TOML table (see the module docstring)."""
    spec = from_table(SystemFile, table, error=SystemFileError)
    matrices = {k: getattr(spec, k) for k in "ABQRCDEF" if getattr(spec, k) is not None}
    try:
        problem = RegulationProblem(
            **{k: np.asarray(m, dtype=float) for k, m in matrices.items()},
            name=default_name if spec.name is None else spec.name,
        )
    except ProblemError as exc:
        raise SystemFileError(str(exc)) from None
    given = table.get("learning", {})
    keys = frozenset(given) if isinstance(given, dict) else frozenset()
    learning, derived = derive_learning(problem, spec.learning, keys)
    learning.validate(problem)
    return System(problem.name, spec.description, problem, learning, derived, tuple(sorted(keys)))
