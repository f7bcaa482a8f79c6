"""The ``ddvi`` command: its parser and its dispatch.  Each command's arguments and work live in
its own module (``services.system_commands`` for scenarios, check and learn), imported only
when that command runs."""

from __future__ import annotations

import os

# before numpy is imported: BLAS threads would compete with the services for the cores
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import math
import sys
from typing import Any, NoReturn

from services.exit_status import EXIT_FAIL, EXIT_USAGE

ROS2_INSTALL = "pip install 'ddvi-fsw[ros2]'"
"""The command that adds what the ROS 2 gateway needs (rosbags, xxhash)."""


def ros2_missing() -> str | None:
    """Why the ROS 2 gateway cannot run here (its packages are not installed), in one line, or
    None: found before any process is started."""
    try:
        import rosbags.typesys  # noqa: F401 - only whether it is there
        import xxhash  # noqa: F401
    except ImportError as exc:
        return f"the ROS 2 gateway needs {exc.name}, which is not installed: {ROS2_INSTALL}"
    return None


def cmd_run(args: argparse.Namespace) -> int:
    from services.config import DeploymentError, check_ros2_endpoint, load_deployment, with_ros2
    from services.ground.launch.launcher import Launcher, Viewing

    if args.output is not None and not args.output.strip():
        print(
            "ddvi run: --output is empty; give the folder runs are written to "
            "(or leave it out for run.output)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    if args.ros2:
        try:
            check_ros2_endpoint(args.ros2)
        except ValueError as exc:
            print(f"ddvi run: --ros2: {exc}", file=sys.stderr)
            return EXIT_USAGE
    table = None  # the deployment's table when --ros2 changes it from its file's
    try:
        if args.ros2 is None:
            dep = load_deployment(args.deployment)
        else:
            dep, table = with_ros2(args.deployment, args.ros2 or None)
    except DeploymentError as exc:
        print(f"ddvi run: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if dep.ros2.enabled and (why := ros2_missing()) is not None:
        print(f"ddvi run: {why}", file=sys.stderr)
        return EXIT_USAGE
    if dep.ros2.enabled:
        from services.ground.monitoring.live_address import loopback

        host = dep.ros2.endpoint.removeprefix("tcp/").rpartition(":")[0]
        if not loopback(host):
            print(
                f"ddvi run: warning: the ROS 2 side at {dep.ros2.endpoint} reaches beyond this "
                "machine: ROS 2 has no authentication there, anyone who reaches it reads what "
                "the gateway carries",
                file=sys.stderr,
            )
    from services.model import backend_missing

    if (why := backend_missing(dep)) is not None:  # bad input, found before any launch
        print(f"ddvi run: {args.deployment or 'rendezvous'}: {why}", file=sys.stderr)
        return EXIT_USAGE
    live = None
    if args.live is not None:
        from services.ground.monitoring.live_address import LiveError, check_live, exposure_warning

        try:
            address = check_live(args.live)
        except LiveError as exc:
            print(f"ddvi run: {exc}", file=sys.stderr)
            return EXIT_USAGE
        if warning := exposure_warning(address):
            print(f"ddvi run: warning: {warning}", file=sys.stderr)
        live = str(address)
    if (why := _pace_refused(args, dep.run.mode, dep.run.rate)) is not None:
        print(f"ddvi run: {why}", file=sys.stderr)
        return EXIT_USAGE
    viewing = Viewing(live, args.rate or 0.0, args.wait_for_client and live is not None)
    launcher = Launcher(
        dep,
        out_root=args.output,
        quiet=args.quiet,
        folder_mode=args.folder_mode,
        viewing=viewing,
        table=table,
    )
    return launcher.execute()


def _pace_refused(args: argparse.Namespace, mode: str, rate: float) -> str | None:
    """Why ``--rate`` or ``--wait-for-client`` cannot be, in one line, or None."""
    if args.wait_for_client and args.live is None:
        return "--wait-for-client waits for a client of the live view: add --live"
    if args.rate is not None and mode != "lockstep":
        return (
            f"--rate paces lock-step; this deployment flies in real time at run.rate = {rate:g} "
            "(set run.rate there instead)"
        )
    return None


def pace(text: str) -> float:
    """``--rate``: simulated seconds per wall second, a positive number."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(
            f"expected simulated seconds per wall second, a positive number such as 3000, "
            f"got {text!r}"
        )
    return value


def cmd_monitor(args: argparse.Namespace) -> int:
    from services.ground.monitoring.tap import monitor_command

    return int(monitor_command(args) or 0)


def _scenarios_arguments(p: argparse.ArgumentParser) -> None:
    from services.system_commands import cmd_scenarios

    p.set_defaults(func=cmd_scenarios)


def _check_arguments(p: argparse.ArgumentParser) -> None:
    from services.system_commands import add_check_arguments

    add_check_arguments(p)


def _learn_arguments(p: argparse.ArgumentParser) -> None:
    from services.system_commands import add_learn_arguments

    add_learn_arguments(p)


def _run_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.monitoring.live_address import LIVE_DEFAULT

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
        help=f"serve every message to Foxglove as it flies (default {LIVE_DEFAULT}, or "
        "ws://HOST:PORT; needs foxglove-sdk; docs/live.md)",
    )
    p.add_argument(
        "--rate",
        type=pace,
        default=None,
        metavar="R",
        help="fly lock-step no faster than R times real time, for a person to watch (3000: "
        "the default mission in about 75 s); the mission flown is the same (default: as fast "
        "as it goes)",
    )
    p.add_argument(
        "--wait-for-client",
        action="store_true",
        help="with --live: the first step waits until a client (Foxglove) subscribes",
    )
    p.add_argument(
        "--ros2",
        nargs="?",
        const="",
        metavar="ENDPOINT",
        help="show the run to ROS 2 Jazzy over rmw_zenoh: join the Zenoh router at ENDPOINT, "
        "or serve it (default: the deployment's [ros2] endpoint, tcp/127.0.0.1:7447; needs "
        f"{ROS2_INSTALL}; docs/ros2.md)",
    )
    p.set_defaults(func=cmd_run)


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
    from services.ground.monitoring.tap import add_monitor_arguments

    add_monitor_arguments(p)
    p.set_defaults(func=cmd_monitor)


def _sweep_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.sweeps.sweep import add_sweep_arguments, sweep_command

    add_sweep_arguments(p)
    p.set_defaults(func=sweep_command)


def _campaign_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.campaign import add_campaign_arguments, campaign_command

    add_campaign_arguments(p)
    p.set_defaults(func=campaign_command)


def _fault_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.launch.faults import add_fault_arguments, fault_command

    add_fault_arguments(p)
    p.set_defaults(func=fault_command)


def _report_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.analysis.recover import add_report_arguments, report_command

    add_report_arguments(p)
    p.set_defaults(func=report_command)


def _netns_arguments(p: argparse.ArgumentParser) -> None:
    from services.ground.launch.netns import add_netns_arguments, netns_command

    add_netns_arguments(p)
    p.set_defaults(func=netns_command)


# command: (help, what adds its arguments); the latter imports what the command needs, so a
# command starts without the others' imports (``ddvi fault`` lands sooner without scipy)
COMMANDS: dict[str, tuple[str, Any]] = {
    "scenarios": ("list the built-in scenarios", _scenarios_arguments),
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
    """argparse's parser, whose usage error is one line on stderr (and exit 2), said by the
    innermost command given: an argument it does not take is named by it (``ddvi sweep delay:
    unrecognized arguments: --mismatch 2``), not by ``ddvi``."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: {message} (see {self.prog} --help)\n")

    def parse_known_args(  # type: ignore[override]
        self, args: list[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        parsed, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed, extras


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


def _run_command(args: argparse.Namespace) -> int:
    """The command's exit status; Ctrl-C is one line (no traceback)."""
    try:
        if args.command in ("check", "learn"):
            from services.system_commands import run_system_command

            return run_system_command(args)
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
