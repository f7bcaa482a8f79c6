"""Built-in scenarios and system files: a regulation problem plus how to learn it.

A system file is TOML with matrices ``A``, ``B``, ``Q``, ``R`` (lists of rows), optionally
``C``, ``D``, ``E``, ``F``, ``name``, ``description``, and a ``[learning]`` table (see
:class:`LearningConfig`).  Every error names the key and the problem in one line.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ddvi_core.models import (
    DragRendezvous,
    paper_printed_problem,
    rendezvous_problem,
    thrust_rendezvous_problem,
)
from ddvi_core.problem import ProblemError, RegulationProblem
from ddvi_core.value_iteration import BoundSchedule, StepSequence

__all__ = ["BUILTIN_SYSTEMS", "LearningConfig", "System", "SystemFileError", "load_system"]


class SystemFileError(ValueError):
    """A system file or name that cannot be used; the message names the key."""


@dataclass(frozen=True)
class LearningConfig:
    """How the data-driven learner explores and iterates (all SI units, seconds, rad/s).

    interval: seconds per data interval; intervals: how many to collect;
    sample_period: navigation sample period; command_period: flight-software period (the input
    is held over it); exploration_amplitude / exploration_frequencies: the multi-sine
    exploration; x0, v0: initial state and exostate; K0: initial gain (zero by default, need
    not stabilise); seed: exploration phases; time_unit: the iteration's time unit (1/s; by
    default A's fastest rate / 100); step / step_size: 'harmonic' (step_size / k) or
    'constant'; bounds / bound_base: 'linear' base (r+1) or 'geometric' base 2^r;
    state_scale: the states' units in the iteration; input_limit: actuator saturation;
    tol, max_iterations: the stopping rule.
    """

    interval: float = 600.0
    intervals: int = 200
    sample_period: float = 10.0
    command_period: float = 60.0
    exploration_amplitude: float = 1.0
    exploration_frequencies: tuple[float, ...] = ()
    x0: tuple[float, ...] | None = None
    v0: tuple[float, ...] | None = None
    K0: tuple[tuple[float, ...], ...] | None = None
    seed: int = 0
    time_unit: float | None = None
    step: str = "harmonic"
    step_size: float = 1.0
    bounds: str = "linear"
    bound_base: float = 10.0
    state_scale: tuple[float, ...] | None = None
    input_limit: float | None = None
    tol: float = 1e-6
    max_iterations: int = 200_000

    def steps(self) -> StepSequence:
        return StepSequence(self.step, self.step_size)

    def bound_schedule(self) -> BoundSchedule:
        return BoundSchedule(self.bounds, self.bound_base)

    def validate(self, problem: RegulationProblem) -> None:
        def bad(key: str, why: str) -> SystemFileError:
            return SystemFileError(f"learning.{key}: {why}")

        for key in (
            "interval",
            "sample_period",
            "command_period",
            "step_size",
            "bound_base",
            "tol",
        ):
            val = getattr(self, key)
            if not (isinstance(val, int | float) and math.isfinite(val) and val > 0):
                raise bad(key, f"must be a positive number, got {val!r}")
        if self.interval < self.sample_period:
            raise bad("interval", "must be at least one sample_period")
        ratio = self.command_period / self.sample_period
        if abs(ratio - round(ratio)) > 1e-9:
            raise bad("command_period", "must be a whole multiple of sample_period")
        for key in ("intervals", "max_iterations"):
            if not (isinstance(getattr(self, key), int) and getattr(self, key) > 0):
                raise bad(key, f"must be a positive integer, got {getattr(self, key)!r}")
        if not (math.isfinite(self.exploration_amplitude) and self.exploration_amplitude >= 0):
            raise bad("exploration_amplitude", "must be a non-negative number")
        if any(not (math.isfinite(w) and w > 0) for w in self.exploration_frequencies):
            raise bad("exploration_frequencies", "must be positive numbers (rad/s)")
        if self.time_unit is not None and not (
            math.isfinite(self.time_unit) and self.time_unit > 0
        ):
            raise bad("time_unit", "must be a positive rate in 1/s")
        if self.step not in ("harmonic", "constant"):
            raise bad("step", f"must be 'harmonic' or 'constant', got {self.step!r}")
        if self.bounds not in ("linear", "geometric"):
            raise bad("bounds", f"must be 'linear' or 'geometric', got {self.bounds!r}")
        sizes = {"x0": problem.n, "v0": problem.q, "state_scale": problem.n}
        for key, size in sizes.items():
            val = getattr(self, key)
            if val is not None and len(val) != size:
                raise bad(key, f"expected {size} values, got {len(val)}")
        if self.state_scale is not None and any(s <= 0 for s in self.state_scale):
            raise bad("state_scale", "must be positive")
        if self.K0 is not None:
            K0 = np.asarray(self.K0, dtype=float)
            if K0.shape != (problem.m, problem.n):
                raise bad(
                    "K0",
                    f"expected shape {problem.m}x{problem.n}, got {'x'.join(map(str, K0.shape))}",
                )
        if self.input_limit is not None and not self.input_limit > 0:
            raise bad("input_limit", "must be positive")

    def K0_matrix(self, problem: RegulationProblem) -> NDArray[np.float64]:
        if self.K0 is None:
            return np.zeros((problem.m, problem.n))
        return np.asarray(self.K0, dtype=float)


@dataclass(frozen=True)
class System:
    name: str
    description: str
    problem: RegulationProblem
    learning: LearningConfig = field(default_factory=LearningConfig)


def _rendezvous() -> System:
    p = DragRendezvous()
    n = p.mean_motion
    u0 = math.radians(30.0 + 20.0)  # the chief's argument of latitude at t0
    return System(
        "rendezvous",
        "differential-drag rendezvous, in-plane Hill state, u = sigma3 (DESIGN.md section 5)",
        rendezvous_problem(p),
        LearningConfig(
            interval=600.0,
            intervals=135,
            sample_period=10.0,
            command_period=60.0,
            exploration_amplitude=0.1,
            exploration_frequencies=tuple(np.geomspace(0.3 * n, 30 * n, 6)),
            # the deputy of DESIGN.md section 5 seen in the chief's Hill frame at t0
            x0=(176.4, -29139.8, 0.0, -0.4165),
            v0=(1.0, math.cos(u0), math.sin(u0), math.cos(2 * u0), math.sin(2 * u0)),
            seed=1,
            time_unit=n,
            step="constant",
            step_size=0.01,
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

_MATRIX_KEYS = ("A", "B", "Q", "R", "C", "D", "E", "F")
_TOP_KEYS = (*_MATRIX_KEYS, "name", "description", "learning")
_LEARNING_KEYS = tuple(f.name for f in fields(LearningConfig))


def _unknown_key(key: str, allowed: tuple[str, ...], where: str) -> SystemFileError:
    close = difflib.get_close_matches(key, allowed, n=1)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    return SystemFileError(f"{where}{key}: unknown key{hint}; allowed: {', '.join(allowed)}")


def _number(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SystemFileError(f"{key}: expected a number, got {type(value).__name__} {value!r}")
    if not math.isfinite(value):
        raise SystemFileError(f"{key}: must be finite, got {value!r}")
    return float(value)


def _vector(key: str, value: Any) -> tuple[float, ...]:
    if not isinstance(value, list):
        raise SystemFileError(f"{key}: expected a list of numbers, got {type(value).__name__}")
    return tuple(_number(f"{key}[{i}]", v) for i, v in enumerate(value))


def _rows(key: str, value: Any) -> list[list[float]]:
    if not isinstance(value, list) or not value:
        raise SystemFileError(
            f"{key}: expected a matrix as a non-empty list of rows, "
            f"for example {key} = [[1.0, 0.0], [0.0, 1.0]]"
        )
    rows = []
    for i, row in enumerate(value):
        if not isinstance(row, list):
            raise SystemFileError(f"{key}[{i}]: expected a row (a list of numbers)")
        rows.append([_number(f"{key}[{i}][{j}]", v) for j, v in enumerate(row)])
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        raise SystemFileError(f"{key}: rows have different lengths {sorted(widths)}")
    return rows


def _learning(table: Any) -> LearningConfig:
    if not isinstance(table, dict):
        raise SystemFileError("learning: expected a table [learning]")
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key not in _LEARNING_KEYS:
            raise _unknown_key(key, _LEARNING_KEYS, "learning.")
        name = f"learning.{key}"
        if key in ("x0", "v0", "exploration_frequencies", "state_scale"):
            kwargs[key] = _vector(name, value)
        elif key == "K0":
            kwargs[key] = tuple(tuple(r) for r in _rows(name, value))
        elif key in ("intervals", "seed", "max_iterations"):
            if isinstance(value, bool) or not isinstance(value, int):
                raise SystemFileError(f"{name}: expected an integer, got {value!r}")
            kwargs[key] = value
        elif key in ("step", "bounds"):
            if not isinstance(value, str):
                raise SystemFileError(f"{name}: expected a string, got {value!r}")
            kwargs[key] = value
        else:
            kwargs[key] = _number(name, value)
    return LearningConfig(**kwargs)


def system_from_table(table: dict[str, Any], default_name: str = "system") -> System:
    """A System from a parsed TOML table (see the module docstring)."""
    for key in table:
        if key not in _TOP_KEYS:
            raise _unknown_key(key, _TOP_KEYS, "")
    missing = [k for k in ("A", "B", "Q", "R") if k not in table]
    if missing:
        raise SystemFileError(f"{missing[0]}: required matrix is missing")
    mats = {k: _rows(k, table[k]) for k in _MATRIX_KEYS if k in table}
    try:
        problem = RegulationProblem(**mats, name=str(table.get("name", default_name)))
    except ProblemError as exc:
        raise SystemFileError(str(exc)) from None
    learning = _learning(table["learning"]) if "learning" in table else LearningConfig()
    learning.validate(problem)
    return System(problem.name, str(table.get("description", "")), problem, learning)


def load_system(name_or_path: str) -> System:
    """A built-in scenario by name, or a system file (TOML) by path."""
    if name_or_path in BUILTIN_SYSTEMS:
        return BUILTIN_SYSTEMS[name_or_path]()
    path = Path(name_or_path)
    if not path.is_file():
        close = difflib.get_close_matches(name_or_path, list(BUILTIN_SYSTEMS), n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise SystemFileError(
            f"{name_or_path}: no such built-in scenario or file{hint}; built-ins: "
            + ", ".join(BUILTIN_SYSTEMS)
        )
    try:
        table = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SystemFileError(f"{path}: not valid TOML ({exc})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SystemFileError(f"{path}: cannot be read ({exc})") from None
    return system_from_table(table, default_name=path.stem)
