"""services.config.files: named deployments resolve from the source tree or the installed
package's data files; every named deployment loads."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.config import DeploymentError, files, load_deployment, resolve


def test_the_default_is_rendezvous_from_the_source_tree() -> None:
    assert resolve(None) == files.DEPLOYMENTS_DIR.resolve() / "rendezvous.toml"
    assert resolve("swarm").name == "swarm.toml"


def test_a_path_is_taken_as_given(tmp_path: Path) -> None:
    path = tmp_path / "mine.toml"
    path.write_text('[[deputy]]\nname = "a"\n')
    assert resolve(str(path)) == path
    assert load_deployment(str(path)).path == str(path)


def test_an_unknown_name_suggests_the_nearest() -> None:
    with pytest.raises(DeploymentError, match=r"rendezvus: .*did you mean 'rendezvous'"):
        resolve("rendezvus")


@pytest.mark.parametrize("name", sorted(p.stem for p in files.DEPLOYMENTS_DIR.glob("*.toml")))
def test_every_named_deployment_loads(name: str) -> None:
    assert load_deployment(name).deputy


def test_the_installed_location_is_searched_after_the_source_tree(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without a source tree (an installed package), names resolve from the data files."""
    installed = tmp_path / files.INSTALLED_SUBDIR
    installed.mkdir(parents=True)
    (installed / "rendezvous.toml").write_text('[[deputy]]\nname = "a"\n')
    monkeypatch.setattr(files, "DEPLOYMENTS_DIR", tmp_path / "no-source-tree")
    monkeypatch.setattr(files.sysconfig, "get_path", lambda _name, _scheme=None: str(tmp_path))
    assert files.deployment_dirs() == [installed.resolve()]
    assert resolve(None) == installed.resolve() / "rendezvous.toml"
    with pytest.raises(DeploymentError, match=r"known: rendezvous$"):
        resolve("swarm")


def test_the_source_tree_comes_first(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    installed = tmp_path / files.INSTALLED_SUBDIR
    installed.mkdir(parents=True)
    (installed / "rendezvous.toml").write_text('[[deputy]]\nname = "a"\n')
    monkeypatch.setattr(files.sysconfig, "get_path", lambda _name, _scheme=None: str(tmp_path))
    assert files.deployment_dirs()[0] == files.DEPLOYMENTS_DIR.resolve()
    assert resolve(None).parent == files.DEPLOYMENTS_DIR.resolve()
