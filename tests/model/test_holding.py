"""The model layer's slot-holding check (``holding_warnings``) and its module layout: the
truth backends apart from the mission model, the Basilisk backend imported only on demand."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import services.model
from services.config import deployment_from_table, read_table
from services.model import holding_warnings

MODEL = Path(services.model.__file__).parent


def _imports(module: str) -> set[str]:
    """The ``services.model`` modules one of its modules imports, at any depth of its code."""
    tree = ast.parse((MODEL / f"{module}.py").read_text())
    return {
        node.module.rsplit(".", 1)[-1]
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom)
        and node.module
        and node.module.startswith("services.model.")
    }


def _with(table: dict, faults: list[dict] | None = None, area_factor: float | None = None):
    if area_factor is not None:
        table["deputy"][0]["area_factor"] = area_factor
    if faults is not None:
        table["fault"] = faults
    return deployment_from_table(table, "test")


def test_the_default_mission_holds_every_slot() -> None:
    assert holding_warnings(_with(read_table(None))) == []


def test_a_deputy_with_half_the_area_is_warned_of() -> None:
    table = read_table(None)
    name = table["deputy"][0]["name"]
    warnings = holding_warnings(_with(table, area_factor=0.5))
    assert warnings == [
        f"deputy {name!r} cannot hold a slot: its largest drag (area factor 0.5, |sigma3| "
        "<= 0.2) is 29% below the chief's, so its along-track error will grow"
    ]


def test_panel_faults_add_up_before_the_margin_is_checked() -> None:
    """A stuck hinge alone (10 deg) still holds; the area lost in a later fault on top of it
    does not, and the warning names that later fault's orbit."""
    table = read_table(None)
    name = table["deputy"][0]["name"]
    faults = [
        {"at_orbits": 30.0, "kind": "panel", "deputy": name, "area_factor": 0.5},
        {"at_orbits": 10.0, "kind": "panel", "deputy": name, "normal_angle": 10.0},
    ]
    warnings = holding_warnings(_with(table, faults))
    assert len(warnings) == 1
    assert warnings[0].startswith(f"after its panel fault at orbit 30 deputy {name!r} cannot")


def test_truth_backends_do_not_import_each_other_in_a_cycle() -> None:
    assert _imports("mission") == set()
    assert _imports("msis") == set()
    assert _imports("decay") == {"mission", "msis"}
    assert _imports("reference") == {"mission", "decay"}
    assert _imports("truth") == {"mission", "msis"}
    assert _imports("basilisk") == {"mission", "truth"}
    assert _imports("backends") == {"truth", "basilisk"}


@pytest.mark.parametrize("name", services.model.__all__)
def test_the_facade_exports_each_name(name: str) -> None:
    assert getattr(services.model, name) is not None
