"""The layering the packages' docstrings state: each layer imports only the layers before it."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

ALLOWED: dict[str, set[str]] = {
    "ddvi_core": set(),
    "services.interface": set(),
    "services.bus": {"services.interface"},
    "services.config": {"services.interface"},
    "services.model": {"services.interface", "services.config"},
    "services.flight": {
        "services.interface",
        "services.bus",
        "services.config",
        "services.model",
    },
    "services.ground": {
        "services.interface",
        "services.bus",
        "services.config",
        "services.model",
        "services.flight",
    },
    "services.ros2": set(),
    # the service that carries a run to ROS 2: hosted as a flight service is, with the wire
    # format of the layer it lives in
    "services.ros2.gateway": {
        "services.interface",
        "services.bus",
        "services.config",
        "services.model",
        "services.flight",
        "services.ros2",
    },
}
"""Which project packages each layer may import (besides itself and ``ddvi_core``); a layer
may be a sub-package of another (``services.ros2.gateway``): a module belongs to the deepest."""


def _layer(module: str) -> str | None:
    if module == "ddvi_core" or module.startswith("ddvi_core."):
        return "ddvi_core"
    parts = module.split(".")
    for depth in range(len(parts), 1, -1):
        if (candidate := ".".join(parts[:depth])) in ALLOWED:
            return candidate
    return None


def _imports(path: Path) -> set[str]:
    """Every project module a file imports, at module level or inside a function."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return {m for m in found if m.split(".")[0] in ("ddvi_core", "services", "benchmarks")}


def _sources() -> list[Path]:
    files = sorted((ROOT / "ddvi_core").rglob("*.py"))
    for layer in ALLOWED:
        if layer.count(".") == 1:  # a sub-package's files are in its package's folder
            files += sorted((ROOT / layer.replace(".", "/")).rglob("*.py"))
    return files


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(ROOT)))
def test_a_module_imports_only_the_layers_before_its_own(path: Path) -> None:
    module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    own = _layer(module)
    assert own is not None
    allowed = ALLOWED[own] | {own} | ({"ddvi_core"} if own != "ddvi_core" else set())
    wrong = sorted(m for m in _imports(path) if _layer(m) not in allowed)
    assert not wrong, f"{module} ({own}) imports {wrong}; allowed: {sorted(allowed)}"


def test_every_services_package_is_a_known_layer() -> None:
    packages = {f"services.{p.name}" for p in (ROOT / "services").iterdir() if p.is_dir()}
    packages.discard("services.__pycache__")
    assert packages == {layer for layer in ALLOWED if layer.count(".") == 1}


@pytest.mark.parametrize(
    "package", ["ddvi_core", "services.interface", "services.config", "services.ros2"]
)
def test_a_data_layer_loads_without_zenoh(package: str) -> None:
    """Configuration and the mathematics are data: reading a deployment needs no bus."""
    code = f"import sys, {package}; print('zenoh' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False", f"importing {package} loads zenoh"
