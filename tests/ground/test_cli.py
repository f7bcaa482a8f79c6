"""The `ddvi` command line: scenarios, check, learn, and every bad-input path of a system file."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from services.cli import main

ROOT = Path(__file__).resolve().parents[2]

DOUBLE_INTEGRATOR = """
name = "double-integrator"
A = [[0.0, 1.0], [0.0, 0.0]]
B = [[0.0], [1.0]]
Q = [[1.0, 0.0], [0.0, 1.0]]
R = [[1.0]]
[learning]
interval = 0.5
intervals = 40
sample_period = 0.01
command_period = 0.05
exploration_amplitude = 1.0
exploration_frequencies = [0.7, 1.9, 3.1, 5.3]
x0 = [1.0, -0.5]
time_unit = 1.0
step = "constant"
step_size = 0.05
"""


def run(capsys, *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse or _load
        code = int(exc.code)
    out, err = capsys.readouterr()
    return code, out, err


def write(tmp_path: Path, text: str) -> str:
    p = tmp_path / "system.toml"
    p.write_text(text)
    return str(p)


def test_scenarios_lists_the_builtins(capsys):
    code, out, _ = run(capsys, "scenarios")
    assert code == 0
    for name in ("rendezvous", "thrust-rendezvous", "paper-printed"):
        assert name in out


def test_check_paper_printed_fails_and_names_each_assumption(capsys):
    code, out, _ = run(capsys, "check", "paper-printed", "--json")
    assert code == 1
    report = json.loads(out)
    failing = {c["name"]: c["detail"] for c in report["checks"] if not c["holds"]}
    assert "stabilisable (A, B)" in failing and "0.00108" in failing["stabilisable (A, B)"]
    assert "regulator equations solvable" in failing
    assert "rank B = 1 < p = 3" in failing["regulator equations solvable"]


def test_check_rendezvous_holds(capsys):
    code, out, _ = run(capsys, "check", "rendezvous")
    assert code == 0 and "all assumptions hold" in out


@pytest.mark.parametrize("method", ["lqr", "pi", "vi", "ddvi"])
def test_learn_json_on_a_system_file_matches_riccati(capsys, tmp_path, method):
    path = write(tmp_path, DOUBLE_INTEGRATOR)
    code, out, _ = run(capsys, "learn", path, "--method", method, "--json")
    assert code == 0, out
    d = json.loads(out)
    for key in ("method", "K", "L", "P", "iterations", "converged", "wall_s"):
        assert key in d
    assert d["method"] == method and d["converged"] is True and d["L"] == []
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    P = scipy.linalg.solve_continuous_are(A, B, np.eye(2), np.eye(1))
    K_star = B.T @ P
    assert np.linalg.norm(np.array(d["K"]) - K_star) / np.linalg.norm(K_star) < 1e-3


def test_learn_rendezvous_ddvi_reaches_the_riccati_gain(capsys):
    code, out, _ = run(capsys, "learn", "rendezvous", "--method", "ddvi", "--json")
    assert code == 0
    d = json.loads(out)
    assert d["converged"] and d["K_error"] < 1e-3 and d["rank"] == d["rank_needed"] == 34


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        (DOUBLE_INTEGRATOR.replace("R = [[1.0]]", "RR = [[1.0]]"), "RR: unknown key"),
        (DOUBLE_INTEGRATOR.replace("step_size", "step_sise"), "learning.step_sise: unknown key"),
        (
            DOUBLE_INTEGRATOR.replace("B = [[0.0], [1.0]]", "B = [[0.0], [1.0], [2.0]]"),
            "B: expected shape 2x?",
        ),
        (DOUBLE_INTEGRATOR.replace("[0.0, 0.0]]\nB", "[0.0, nan]]\nB"), "A[1][1]: must be finite"),
        (
            DOUBLE_INTEGRATOR.replace(
                "Q = [[1.0, 0.0], [0.0, 1.0]]", "Q = [[1.0, 0.5], [0.0, 1.0]]"
            ),
            "Q: must be symmetric",
        ),
        (DOUBLE_INTEGRATOR.replace("x0 = [1.0, -0.5]", "x0 = [1.0]"), "learning.x0: expected 2"),
        (
            DOUBLE_INTEGRATOR.replace("intervals = 40", 'intervals = "many"'),
            "learning.intervals: expected an integer",
        ),
        ("A = [[0.0", "not valid TOML"),
    ],
)
def test_bad_system_file_gets_one_line_and_exit_2(capsys, tmp_path, text, needle):
    code, _, err = run(capsys, "learn", write(tmp_path, text), "--method", "lqr")
    assert code == 2
    assert needle in err, err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_unknown_system_name_suggests_the_builtin(capsys):
    code, _, err = run(capsys, "check", "rendezvus")
    assert code == 2 and "did you mean 'rendezvous'" in err


EXAMPLES = sorted(p.stem for p in (ROOT / "docs" / "examples" / "systems").glob("*.toml"))


@pytest.mark.parametrize(
    ("command", "given"),
    [
        ("check", "cartpole"),
        ("learn", "cartpole"),
        ("check", "docs/examples/cartpole.toml"),
        ("learn", "docs/examples/systems/cartpole.toml"),
    ],
)
def test_a_system_not_found_is_one_line_with_a_did_you_mean_and_every_example(
    capsys, command, given
):
    """A name or a path one typo off an example: exit 2, one line naming the command, the
    example meant and every example system by name."""
    code, _, err = run(capsys, command, given)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"ddvi {command}: {given}: no such built-in scenario, example or file")
    assert "(did you mean 'cart-pole'?)" in err
    assert f"an example by its name ({', '.join(EXAMPLES)})" in err
    assert len(EXAMPLES) == 8


def test_the_examples_readme_lists_every_example_system():
    readme = (ROOT / "docs" / "examples" / "README.md").read_text()
    listed = sorted(re.findall(r"^\| `([a-z0-9-]+)\.toml` \|", readme, flags=re.MULTILINE))
    assert listed == EXAMPLES
    assert "holds eight linear regulation problems" in readme


def test_rank_deficient_data_prints_the_report_not_a_gain(capsys, tmp_path):
    path = write(
        tmp_path,
        DOUBLE_INTEGRATOR.replace("exploration_amplitude = 1.0", "exploration_amplitude = 0.0"),
    )
    code, out, err = run(capsys, "learn", path, "--method", "ddvi")
    assert code == 1 and out == ""
    assert "rank" in err and "input terms" in err


@pytest.mark.integration
def test_console_script_runs_as_a_process():
    r = subprocess.run(
        [sys.executable, "-m", "services.cli", "scenarios"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0 and "rendezvous" in r.stdout


@pytest.mark.integration
def test_a_command_imports_only_what_it_needs():
    """`ddvi fault` parses its arguments without scipy or any part of the monitor (recording,
    status, report, tap), so it lands sooner in a running mission: of the ground, only itself
    and the run folder it reads the run's deployment from."""
    code = (
        "import sys; from services.cli import build_parser; "
        "a = build_parser('fault').parse_args(['fault', 'r', 'panel', 'd', '--stuck-angle', '30']);"
        "ground = sorted(m for m in sys.modules if m.startswith('services.ground.'));"
        "print(a.stuck_angle, 'scipy' in sys.modules, ','.join(ground))"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    ground = "services.ground.launch,services.ground.launch.faults,services.ground.launch.runfolder"
    assert r.returncode == 0 and r.stdout.split() == ["30.0", "False", ground], r.stdout + r.stderr


def test_the_monitor_starts_without_the_mathematics():
    """The monitor records from its start with the bus, the codec and MCAP; scipy (the report's
    reference gains) loads only when it scores, at the end: a process of the mission each
    library would cost."""
    code = "import sys, services.ground.monitoring.monitor; print('scipy' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.split() == ["False"], r.stdout + r.stderr


def test_the_whole_parser_has_every_commands_arguments():
    """Built for no command in particular, the parser still has every command's arguments."""
    from services.cli import build_parser

    args = build_parser().parse_args(["sweep", "delay", "rendezvous", "--values", "0", "60"])
    assert args.func.__name__ == "sweep_command"
