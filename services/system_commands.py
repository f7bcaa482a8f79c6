"""``ddvi scenarios``, ``ddvi check`` and ``ddvi learn``: the commands on a system (a built-in
scenario, a system file or a shipped example; ``ddvi_core.systems``), no bus and no services."""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from typing import Any

import numpy as np

from services.exit_status import EXIT_FAIL, EXIT_OK, EXIT_USAGE


def _rows(M: np.ndarray) -> list[list[float]]:
    return np.asarray(M, dtype=float).tolist()


def seed(text: str) -> int:
    """A seed argument: an integer in 0 .. 2**32 - 1 (numpy's seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"a seed lies in 0 .. 2**32 - 1, got {value}")
    return value


def _load(args: argparse.Namespace) -> Any:
    """The system ``args.system`` names: a built-in scenario, a system file, or a shipped
    example by name (``cart-pole``); one line and exit 2 when it names none."""
    from ddvi_core.systems import SystemFileError
    from services.config.files import load_system

    try:
        return load_system(args.system)
    except SystemFileError as exc:
        print(f"ddvi {args.command}: {exc}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE) from None


def cmd_scenarios(args: argparse.Namespace) -> int:
    from ddvi_core.systems import BUILTIN_SYSTEMS

    for name, build in BUILTIN_SYSTEMS.items():
        s = build()
        pr = s.problem
        print(f"{name:<18} n={pr.n} m={pr.m} p={pr.p} q={pr.q}  {s.description}")
    return EXIT_OK


def cmd_check(args: argparse.Namespace) -> int:
    system = _load(args)
    report = system.problem.check_assumptions()
    if args.json:
        print(json.dumps({"system": system.name, **report.as_dict()}))
    else:
        print(
            f"{system.name}: n={system.problem.n} m={system.problem.m} "
            f"p={system.problem.p} q={system.problem.q}"
        )
        for c in report.checks:
            print(f"  [{'ok' if c.holds else 'FAIL'}] {c.name}: {c.detail}")
        print("all assumptions hold" if report.ok else f"{len(report.failures)} assumption(s) fail")
    return EXIT_OK if report.ok else EXIT_FAIL


# the learning settings each method uses (ddvi_core.learning_config.LearningConfig)
_ITERATION_KEYS = (
    "time_unit",
    "state_scale",
    "step",
    "step_size",
    "bounds",
    "bound_base",
    "stopping",
    "tol",
    "max_iterations",
)
_SETTINGS_USED = {
    "lqr": (),
    "pi": ("K0",),
    "vi": _ITERATION_KEYS,
}


def learning_settings(system: Any, method: str) -> dict[str, dict[str, Any]]:
    """Every learning setting ``method`` uses on ``system``: {key: {"value", "source"}}, the
    source "given" (the system file's [learning]), "derived" (from the system,
    ddvi_core.defaults), "default" or "scenario" (a built-in's tuned table)."""
    from ddvi_core.learning_config import SYSTEM_FILE_LEARNING_KEYS
    from ddvi_core.systems import BUILTIN_SYSTEMS

    keys = _SETTINGS_USED.get(method, SYSTEM_FILE_LEARNING_KEYS)
    builtin = system.name in BUILTIN_SYSTEMS and not system.derived
    out = {}
    for key in keys:
        value = getattr(system.learning, key)
        if key in system.derived:
            source = "derived"
        elif builtin:
            source = "scenario"
        else:
            source = "given" if key in system.given else "default"
        if isinstance(value, tuple):
            value = np.asarray(value, dtype=float).tolist()
        out[key] = {"value": value, "source": source}
    return out


def _print_learned(system: Any, sol: Any, out: dict[str, Any]) -> None:
    """The human form of ``ddvi learn``'s result ``out``."""
    np.set_printoptions(precision=6, linewidth=110)
    timing = f"in {out['wall_s']:.3f} s"
    if "learning_s" in out:
        timing = f"in {out['learning_s']:.3f} s of learning ({out['data_s']:.3f} s of data)"
    state = "converged" if sol.converged else "NOT converged"
    print(f"{system.name} by {sol.method}: {state} after {sol.iterations} iterations {timing}")
    print("K =\n" + str(sol.K))
    if sol.L.size:
        print("L =\n" + str(sol.L))
    print("P =\n" + str(sol.P))
    for key in ("K_error", "L_error"):
        if key in out:
            print(f"{key} against the Riccati solution: {out[key]:.3e}")
    keys = (
        "resets",
        "rank",
        "rank_needed",
        "condition",
        "residual",
        "intervals",
        "initial_gain",
        "message",
    )
    for key in keys:
        if key in out:
            print(f"{key}: {out[key]}")
    if out["settings"]:
        print("settings (learning.KEY = value, source):")
        for key, setting in out["settings"].items():
            value = setting["value"]
            if isinstance(value, list):
                value = np.array2string(np.asarray(value), precision=6, separator=", ")
            elif isinstance(value, float):
                value = f"{value:.6g}"
            print(f"  {key} = {value} ({setting['source']})")


def cmd_learn(args: argparse.Namespace) -> int:
    from ddvi_core.learning import LearningError
    from ddvi_core.lqr import NotStabilisingError
    from ddvi_core.regulator import InfeasibleError
    from ddvi_core.solve import reference_errors, solve

    system = _load(args)
    t0 = time.perf_counter()
    try:
        sol = solve(system, args.method, seed=args.seed)
    except (LearningError, NotStabilisingError, InfeasibleError) as exc:
        print(f"ddvi learn {system.name} --method {args.method}: {exc}", file=sys.stderr)
        return EXIT_FAIL
    wall = time.perf_counter() - t0
    out: dict[str, Any] = {
        "system": system.name,
        "method": sol.method,
        "K": _rows(sol.K),
        "L": _rows(sol.L) if sol.L.size else [],
        "P": _rows(sol.P),
        "iterations": sol.iterations,
        "converged": sol.converged,
        "wall_s": wall,
    }
    if args.method != "lqr":
        out.update(reference_errors(system, sol))
    for key, val in sol.details.items():
        if isinstance(val, np.ndarray):
            val = [str(v) for v in val] if np.iscomplexobj(val) else val.tolist()
        out[key] = val
    out["settings"] = learning_settings(system, args.method)
    if args.seed is not None and "seed" in out["settings"]:
        out["settings"]["seed"] = {"value": args.seed, "source": "--seed"}
    if args.json:
        print(json.dumps(out))
    else:
        _print_learned(system, sol, out)
    return EXIT_OK if sol.converged else EXIT_FAIL


SYSTEM_HELP = (
    "a built-in scenario (ddvi scenarios), a TOML system file, or an example's name "
    "(cart-pole: docs/examples/systems)"
)


def add_learn_arguments(p: argparse.ArgumentParser) -> None:
    from ddvi_core.solve import METHODS

    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = METHOD_HELP
    p.add_argument("system", help=SYSTEM_HELP)
    p.add_argument(
        "--method",
        choices=METHODS,
        default="ddvi",
        help="how the gains are computed (default: ddvi); the methods are listed below",
    )
    p.add_argument("--seed", type=seed, default=None, help="exploration seed (ddvi)")
    p.add_argument("--json", action="store_true", help="the result as one JSON object on stdout")
    p.set_defaults(func=cmd_learn)


METHOD_HELP = """methods (docs/methods.md):
  lqr     the algebraic Riccati equation, from the model (the reference)
  pi      Kleinman's policy iteration on the model; starts from learning.K0, or a detuned
          LQR gain when K0 does not stabilise
  vi      value iteration on the model (the paper's Algorithm 1)
  ddvi    data-driven value iteration (Algorithm 2): learns from simulated, explored data
          alone, never reading A or B (the default)
  dpi     policy iteration on the same data; needs a stabilising learning.K0
  hybrid  value iteration on the data until the gain stabilises, then policy iteration"""


def add_check_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("system", help=SYSTEM_HELP)
    p.add_argument("--json", action="store_true", help="the checks as one JSON object on stdout")
    p.set_defaults(func=cmd_check)


NUMERIC_ERRORS = (ArithmeticError, ValueError)
"""What a system's numbers can raise in ``ddvi check`` and ``ddvi learn`` (an overflow, a
singular matrix: numpy's LinAlgError is a ValueError): bad input, said in one line."""


def run_system_command(args: argparse.Namespace) -> int:
    """``ddvi check`` or ``ddvi learn``: a system whose numbers cannot be used is one line
    (the numeric warnings on the way there are dropped; a command that succeeds shows them)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            status = int(args.func(args))
        except NUMERIC_ERRORS as exc:
            print(
                f"ddvi {args.command}: {args.system}: its numbers cannot be used "
                f"({type(exc).__name__}: {exc}); give finite entries of moderate size",
                file=sys.stderr,
            )
            return EXIT_USAGE
    for w in caught:
        warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return status
