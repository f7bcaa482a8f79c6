"""The ``ddvi`` command: scenarios, check, learn (and, as the flight system grows, more)."""

from __future__ import annotations

import os

# before numpy is imported: BLAS threads would compete with the services for the cores
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import math
import sys
import time
import warnings
from typing import Any, NoReturn

import numpy as np

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2


def _rows(M: np.ndarray) -> list[list[float]]:
    return np.asarray(M, dtype=float).tolist()


def _load(name: str):
    """A built-in scenario, a system file, or a shipped example by name (``cart-pole``)."""
    from ddvi_core.systems import BUILTIN_SYSTEMS, SystemFileError, load_system
    from services.config.files import system_example

    if name not in BUILTIN_SYSTEMS and (example := system_example(name)) is not None:
        name = str(example)
    try:
        return load_system(name)
    except SystemFileError as exc:
        print(f"ddvi: {exc}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE) from None


def cmd_scenarios(args: argparse.Namespace) -> int:
    from ddvi_core.systems import BUILTIN_SYSTEMS

    for name, build in BUILTIN_SYSTEMS.items():
        s = build()
        pr = s.problem
        print(f"{name:<18} n={pr.n} m={pr.m} p={pr.p} q={pr.q}  {s.description}")
    return EXIT_OK


def cmd_check(args: argparse.Namespace) -> int:
    system = _load(args.system)
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
_ITERATION_KEYS = ("time_unit", "state_scale", "step", "step_size", "bounds", "bound_base",
                   "stopping", "tol", "max_iterations")  # fmt: skip
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
    keys = ("resets", "rank", "rank_needed", "condition", "residual", "intervals",
            "initial_gain", "message")  # fmt: skip
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

    system = _load(args.system)
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


def cmd_run(args: argparse.Namespace) -> int:
    from services.config import DeploymentError, load_deployment
    from services.ground.launcher import Launcher

    if args.output is not None and not args.output.strip():
        print("ddvi run: --output is empty; give the folder runs are written to "
              "(or leave it out for run.output)", file=sys.stderr)  # fmt: skip
        return EXIT_USAGE
    try:
        dep = load_deployment(args.deployment)
    except DeploymentError as exc:
        print(f"ddvi run: {exc}", file=sys.stderr)
        return EXIT_USAGE
    from services.model import backend_missing

    if (why := backend_missing(dep)) is not None:  # bad input, found before any launch
        print(f"ddvi run: {args.deployment or 'rendezvous'}: {why}", file=sys.stderr)
        return EXIT_USAGE
    live = None
    if args.live is not None:
        from services.ground.live_address import LiveError, check_live, exposure_warning

        try:
            address = check_live(args.live)
        except LiveError as exc:
            print(f"ddvi run: {exc}", file=sys.stderr)
            return EXIT_USAGE
        if warning := exposure_warning(address):
            print(f"ddvi run: warning: {warning}", file=sys.stderr)
        live = str(address)
    launcher = Launcher(
        dep, out_root=args.output, quiet=args.quiet, folder_mode=args.folder_mode, live=live
    )
    return launcher.execute()


def cmd_monitor(args: argparse.Namespace) -> int:
    from services.ground.tap import monitor_command

    return int(monitor_command(args) or 0)


SYSTEM_HELP = (
    "a built-in scenario (ddvi scenarios), a TOML system file, or an example's name "
    "(cart-pole: docs/examples/systems)"
)


def _learn_arguments(p: argparse.ArgumentParser) -> None:
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


def _run_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.live_address import LIVE_DEFAULT

    p.add_argument(
        "deployment",
        nargs="?",
        default=None,
        help="deployment file or name in deployments/ (default: rendezvous)",
    )
    p.add_argument("--output", default=None, help="override run.output (the runs folder)")
    p.add_argument("--quiet", action="store_true", help="no progress on the terminal")
    p.add_argument(
        "--folder-mode",
        type=folder_mode,
        default=None,
        help="the run folder's permissions, octal (default 0700, or run.folder_mode): 0750 "
        "lets the folder's group read the recording and the report (docs/security.md)",
    )
    p.add_argument(
        "--live",
        nargs="?",
        const=LIVE_DEFAULT,
        metavar="HOST:PORT",
        help=f"serve every message to Foxglove as it flies (default {LIVE_DEFAULT}; needs "
        "foxglove-sdk; docs/live.md)",
    )
    p.set_defaults(func=cmd_run)


def _check_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("system", help=SYSTEM_HELP)
    p.add_argument("--json", action="store_true", help="the checks as one JSON object on stdout")
    p.set_defaults(func=cmd_check)


def _benchmarks_missing() -> str | None:
    """Why ``ddvi bench`` cannot run, in one line, or None: the benchmarks are the top-level
    ``benchmarks`` package (the repository's ``benchmarks/`` folder), which an installation
    from a checkout provides and others may not."""
    try:
        import benchmarks.run  # noqa: F401
    except ImportError as exc:
        return (
            f"ddvi bench: cannot import the benchmarks ({exc}); they are the benchmarks/ folder "
            "of the repository: install ddvi-fsw from a checkout (pip install -e .)"
        )
    return None


def _bench_arguments(p: argparse.ArgumentParser) -> None:
    try:
        from benchmarks.run import build_parser as bench_parser
        from benchmarks.run import run as bench_run
    except ImportError:
        return  # listed by name alone; ``ddvi bench`` itself says why (see main)
    bench_parser(p)
    p.set_defaults(func=bench_run)


def _monitor_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.tap import add_monitor_arguments

    add_monitor_arguments(p)
    p.set_defaults(func=cmd_monitor)


def _sweep_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.sweep import add_sweep_arguments, sweep_command

    add_sweep_arguments(p)
    p.set_defaults(func=sweep_command)


def _campaign_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.campaign import add_campaign_arguments, campaign_command

    add_campaign_arguments(p)
    p.set_defaults(func=campaign_command)


def _fault_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.faults import add_fault_arguments, fault_command

    add_fault_arguments(p)
    p.set_defaults(func=fault_command)


def _report_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.recover import add_report_arguments, report_command

    add_report_arguments(p)
    p.set_defaults(func=report_command)


def _netns_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.netns import add_netns_arguments, netns_command

    add_netns_arguments(p)
    p.set_defaults(func=netns_command)


# command: (help, what adds its arguments); the latter imports what the command needs, so a
# command starts without the others' imports (``ddvi fault`` lands sooner without scipy)
COMMANDS: dict[str, tuple[str, Any]] = {
    "scenarios": ("list the built-in scenarios", lambda p: p.set_defaults(func=cmd_scenarios)),
    "check": ("check the assumptions of a system (exit 1 if one fails)", _check_arguments),
    "learn": ("compute the optimal gains of a system by one method", _learn_arguments),
    "run": ("run a deployment: every service its own process on Zenoh", _run_arguments),
    "bench": ("benchmarks, each against its baseline in the same run", _bench_arguments),
    "monitor": ("print decoded messages of a running deployment", _monitor_arguments),
    "sweep": (
        "the mission over link delays, loss rates, or navigation noise and model mismatch: "
        "a table and a plot",
        _sweep_arguments,
    ),
    "campaign": (
        "a Monte Carlo campaign of missions on Dask: a table and a report",
        _campaign_arguments,
    ),
    "fault": ("inject a fault into a running deployment", _fault_arguments),
    "netns": ("create or remove a deployment's [[host]] network namespaces", _netns_arguments),
    "report": (
        "write a run's report again from its recording, recovering one cut short",
        _report_arguments,
    ),
}


class Parser(argparse.ArgumentParser):
    """argparse's parser, whose usage error is one line on stderr (and exit 2)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: {message} (see {self.prog} --help)\n")


def seed(text: str) -> int:
    """A seed argument: an integer in 0 .. 2**32 - 1 (numpy's seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"a seed lies in 0 .. 2**32 - 1, got {value}")
    return value


def folder_mode(text: str) -> int:
    """A run folder's mode, octal: its owner's rwx, its group's at most, nothing for others."""
    try:
        value = int(text, 8)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an octal mode such as 0750, got {text!r}"
        ) from None
    if value & ~0o777 or value & 0o700 != 0o700 or value & 0o007:
        raise argparse.ArgumentTypeError(
            f"a run folder's mode gives its owner rwx and others nothing (0700, 0750, 0770), "
            f"got {text}"
        )
    return value


def non_finite_argument(args: argparse.Namespace) -> str | None:
    """The first option given a non-finite number (nan, inf), said in one line, or None."""
    for key, value in vars(args).items():
        values = value if isinstance(value, list | tuple) else [value]
        bad = [v for v in values if isinstance(v, float) and not math.isfinite(v)]
        if bad:
            return f"--{key.replace('_', '-')}: expected finite numbers, got {bad[0]}"
    return None


NUMERIC_ERRORS = (ArithmeticError, ValueError)
"""What a system's numbers can raise in ``ddvi check`` and ``ddvi learn`` (an overflow, a
singular matrix: numpy's LinAlgError is a ValueError): bad input, said in one line."""


def _run_system_command(args: argparse.Namespace) -> int:
    """``ddvi check`` or ``ddvi learn``: a system whose numbers cannot be used is one line
    (the numeric warnings on the way there are dropped; a command that succeeds shows them)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            status = int(args.func(args))
        except NUMERIC_ERRORS as exc:
            print(f"ddvi {args.command}: {args.system}: its numbers cannot be used "
                  f"({type(exc).__name__}: {exc}); give finite entries of moderate size",
                  file=sys.stderr)  # fmt: skip
            return EXIT_USAGE
    for w in caught:
        warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return status


def _run_command(args: argparse.Namespace) -> int:
    """The command's exit status; Ctrl-C is one line (no traceback)."""
    try:
        if args.command in ("check", "learn"):
            return _run_system_command(args)
        return int(args.func(args))
    except KeyboardInterrupt:
        print(f"ddvi {args.command}: interrupted", file=sys.stderr)
        return 130


def package_version() -> str:
    """The installed ddvi-fsw's version ("unknown" when run from a tree never installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ddvi-fsw")
    except PackageNotFoundError:
        return "unknown"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``ddvi`` parser; with ``command``, only that command's arguments are built (the
    others are listed by name and help alone)."""
    parser = Parser(
        prog="ddvi", description="Data-driven value iteration for spacecraft rendezvous."
    )
    parser.add_argument("--version", action="version", version=f"ddvi {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (text, add_arguments) in COMMANDS.items():
        p = sub.add_parser(name, help=text)
        if command is None or command == name:
            add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(sys.argv[1:] if argv is None else argv)
    except BrokenPipeError:
        # stdout's reader left (``ddvi scenarios | head -1``): end quietly, as a pipe's
        # writer does; stdout goes to /dev/null so that the interpreter's last flush is quiet
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_FAIL


def _main(argv: list[str]) -> int:
    command = next((a for a in argv if not a.startswith("-")), None)
    if command == "bench" and (why := _benchmarks_missing()):
        print(why, file=sys.stderr)
        return EXIT_USAGE
    # only the command's own arguments are built (none for ``ddvi --version``)
    args = build_parser(command if command in COMMANDS else "").parse_args(argv)
    if (why := non_finite_argument(args)) is not None:
        print(f"ddvi {args.command}: {why}", file=sys.stderr)
        return EXIT_USAGE
    return _run_command(args)


if __name__ == "__main__":
    sys.exit(main())
