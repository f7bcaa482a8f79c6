"""Run folders nobody can plant: another user who can write the output root pre-creates the
run's folder (credentials files open to all, a bus.json link to a file of theirs); the launcher
never writes into or through them, flies in a folder of a new name, private to its owner.  A
run that cannot start (its network namespaces missing) makes no folder at all."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest

from services.bus.security import SECURITY_DIR, issue_credentials, write_private
from services.config import load_deployment
from services.ground.launch.launcher import Launcher
from services.ground.launch.runfolder import make_run_folder

MISSION = """
[run]
name = "plant"
orbits = 0.2
[[deputy]]
name = "lqr"
controller = "lqr"
"""


def _plant(folder: Path, target: Path) -> dict[Path, bytes]:
    """What another user leaves at ``folder``: security files open to all, bus.json a link to
    ``target``.  Returns every planted file's content."""
    (folder / SECURITY_DIR).mkdir(parents=True)
    os.chmod(folder, 0o777)
    os.chmod(folder / SECURITY_DIR, 0o777)
    planted = {}
    for name in ("ctrl-lqr.json", "users.txt", "router.json"):
        path = folder / SECURITY_DIR / name
        path.write_text("theirs\n")
        os.chmod(path, 0o666)
        planted[path] = path.read_bytes()
    (folder / "bus.json").symlink_to(target)
    return planted


def test_a_planted_name_is_never_reused_and_nothing_written_through_it(tmp_path: Path) -> None:
    """Unit level: the name taken is a new one; a file written new refuses a planted file and
    a planted link; a security folder that is not the owner's private one is refused."""
    root = tmp_path / "runs"
    target = tmp_path / "their-file"
    target.write_text("theirs\n")
    planted = _plant(root / "run-1", target)
    name, folder = make_run_folder(root, "run-1")
    assert (name, folder) == ("run-1-2", root / "run-1-2")
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert make_run_folder(root, "run-1", 0o750)[0] == "run-1-3"
    assert stat.S_IMODE((root / "run-1-3").stat().st_mode) == 0o750
    with pytest.raises(FileExistsError):
        write_private(root / "run-1" / "bus.json", "{}")  # the link is not followed
    with pytest.raises(FileExistsError):
        write_private(root / "run-1" / SECURITY_DIR / "ctrl-lqr.json", "{}")
    with pytest.raises(PermissionError, match="not this user's private folder"):
        issue_credentials(root / "run-1", ["ctrl-lqr"])
    assert target.read_text() == "theirs\n"
    assert all(path.read_bytes() == text for path, text in planted.items())
    (root / "file").write_text("")
    with pytest.raises(NotADirectoryError):
        make_run_folder(root / "file", "run")


@pytest.mark.integration
def test_the_launcher_flies_in_a_new_private_folder_beside_a_planted_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A real run whose predictable folder another user planted: it completes in a new one
    (0700, its own credentials 0600), and leaves the planted files and the link's target as
    they were."""
    dep_file = tmp_path / "plant.toml"
    dep_file.write_text(MISSION)
    root = tmp_path / "runs"
    launcher = Launcher(load_deployment(str(dep_file)), out_root=str(root), quiet=True)
    target = tmp_path / "their-file"
    target.write_text("theirs\n")
    planted = _plant(root / launcher.run, target)
    predicted = launcher.run

    assert launcher.execute() == 0
    out = Path(capsys.readouterr().out.strip())
    assert out == root / f"{predicted}-2" and launcher.run == f"{predicted}-2"
    assert json.loads((out / "summary.json").read_text())["completed"] is True
    assert json.loads((out / "bus.json").read_text())["run"] == launcher.run
    assert stat.S_IMODE(out.stat().st_mode) == 0o700
    assert stat.S_IMODE((out / SECURITY_DIR).stat().st_mode) == 0o700
    assert all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in (out / SECURITY_DIR).iterdir())
    assert target.read_text() == "theirs\n"
    assert all(path.read_bytes() == text for path, text in planted.items())
    assert sorted(p.name for p in (root / predicted).iterdir()) == ["bus.json", SECURITY_DIR]


def test_a_run_whose_network_namespaces_are_missing_says_so_and_leaves_no_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A deployment placing services in namespaces that do not exist is refused before its
    folder (and its credentials) is made."""
    dep_file = tmp_path / "hosts.toml"
    hosts = '[bus]\nmode = "client"\nport = 7461\n'
    hosts += '[[host]]\nnetns = "ddvi-absent"\nservices = ["nav-*"]\n'
    dep_file.write_text(MISSION + hosts)
    root = tmp_path / "runs"
    launcher = Launcher(load_deployment(str(dep_file)), out_root=str(root), quiet=True)
    assert launcher.execute() == 1
    err = capsys.readouterr().err
    assert "network namespaces ['ddvi-absent'] do not exist" in err
    assert "ddvi netns up" in err
    assert not root.exists() or not any(root.iterdir())
