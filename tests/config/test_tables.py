"""ddvi_core.tables: the one strict TOML-table reader (system files and deployments use it)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest

from ddvi_core.systems import LearningConfig, SystemFileError, system_from_table
from ddvi_core.tables import FlatRowMatrix, Matrix, TableError, from_table, table_field
from services.config import DeploymentError, deployment_from_table


@dataclass(frozen=True)
class Inner:
    rate: float = 1.0
    count: int = 2
    on: bool = False
    label: str = "x"
    values: tuple[float, ...] = ()
    names: list[str] = field(default_factory=list)
    gain: Matrix | None = None
    row: FlatRowMatrix | None = None
    limit: float | None = None


@dataclass(frozen=True)
class Outer:
    needed: float
    inner: Inner = field(default_factory=Inner)
    items: list[Inner] = field(default_factory=list)
    tuned: Inner = table_field(Inner, keys=("rate", "label"), defaults={"rate": 5.0})


def read(table: dict) -> Outer:
    return from_table(Outer, {"needed": 1.0, **table})


def test_a_valid_table_converts_every_type() -> None:
    out = read(
        {
            "inner": {
                "rate": 2,
                "count": 3,
                "on": True,
                "label": "y",
                "values": [1, 2.5],
                "names": ["a"],
                "gain": [[1, 0], [0, 1]],
                "row": [1.0, 2.0],
                "limit": 0.5,
            },
            "items": [{"rate": 3.0}],
        }
    )
    assert out.inner == Inner(
        2.0, 3, True, "y", (1.0, 2.5), ["a"], ((1.0, 0.0), (0.0, 1.0)), ((1.0, 2.0),), 0.5
    )
    assert isinstance(out.inner.rate, float) and out.items == [Inner(rate=3.0)]


def test_defaults_table_is_overridden_key_by_key() -> None:
    assert read({}).tuned == Inner(rate=5.0)
    assert read({"tuned": {"label": "z"}}).tuned == Inner(rate=5.0, label="z")
    assert read({"tuned": {"rate": 1.5}}).tuned == Inner(rate=1.5)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        # a typo names the full key path and suggests the key meant
        ({"inner": {"rat": 1.0}}, "inner.rat: unknown key (did you mean 'rate'?); allowed: rate,"),
        ({"items": [{}, {"cuont": 1}]}, "items[1].cuont: unknown key (did you mean 'count'?)"),
        # a field table_field leaves out is refused as unknown there
        (
            {"tuned": {"count": 1}},
            "tuned.count: unknown key; allowed: rate, label",
        ),
        ({"tuned": {"labl": "z"}}, "tuned.labl: unknown key (did you mean 'label'?)"),
        # wrong types
        ({"inner": {"rate": "fast"}}, "inner.rate: expected a number, got 'fast' (str)"),
        ({"inner": {"rate": True}}, "inner.rate: expected a number, got True (bool)"),
        ({"inner": {"count": 1.5}}, "inner.count: expected an integer, got 1.5 (float)"),
        ({"inner": {"on": 1}}, "inner.on: expected true or false, got 1 (int)"),
        ({"inner": {"label": 3}}, "inner.label: expected a string, got 3 (int)"),
        ({"inner": {"values": 3}}, "inner.values: expected a list, got 3 (int)"),
        ({"inner": {"names": [1]}}, "inner.names[0]: expected a string, got 1 (int)"),
        ({"inner": 3}, "inner: expected a table, got 3 (int)"),
        # wrong shapes
        ({"inner": {"gain": [1.0, 2.0]}}, "inner.gain[0]: expected a row (a list of numbers)"),
        ({"inner": {"gain": []}}, "inner.gain: expected a matrix as a non-empty list of rows"),
        (
            {"inner": {"gain": [[1.0], [1.0, 2.0]]}},
            "inner.gain: rows have different lengths [1, 2]",
        ),
        ({"inner": {"row": [1.0, "a"]}}, "inner.row[1]: expected a number, got 'a' (str)"),
        # non-finite numbers, however deep
        ({"inner": {"rate": math.inf}}, "inner.rate: must be finite, got inf"),
        ({"items": [{"values": [0.0, math.nan]}]}, "items[0].values[1]: must be finite, got nan"),
        ({"inner": {"gain": [[1.0, -math.inf]]}}, "inner.gain[0][1]: must be finite, got -inf"),
    ],
)
def test_every_error_is_one_line_naming_the_key_path(table: dict, message: str) -> None:
    with pytest.raises(TableError) as info:
        read(table)
    text = str(info.value)
    assert text.startswith(message), text
    assert "\n" not in text


def test_a_missing_required_key_and_a_non_table_are_named() -> None:
    with pytest.raises(TableError, match=r"^needed: required, not given$"):
        from_table(Outer, {})
    with pytest.raises(TableError, match=r"^\(top level\): expected a table, got \[\] \(list\)$"):
        from_table(Outer, [])


def test_the_callers_exception_type_is_raised() -> None:
    with pytest.raises(SystemFileError, match=r"^inner\.rat: unknown key"):
        from_table(Outer, {"needed": 1.0, "inner": {"rat": 1}}, error=SystemFileError)


def test_a_class_check_is_reported_at_the_key_path() -> None:
    @dataclass(frozen=True)
    class Checked:
        size: float = 1.0

        def __post_init__(self) -> None:
            if self.size <= 0:
                raise ValueError(f"Checked.size: must be positive, got {self.size}")

    with pytest.raises(TableError, match=r"^part\[2\]\.size: must be positive, got -1\.0$"):
        from_table(Checked, {"size": -1}, "part[2]")


def test_system_file_and_deployment_read_the_same_learning_config() -> None:
    """One LearningConfig: a system file's [learning] and a deputy's learning table; each file
    gives only its own keys, a deputy's others following from the mission."""
    base = {"A": [[0.0, 1.0], [0.0, 0.0]], "B": [[0.0], [1.0]], "Q": [[1.0, 0.0], [0.0, 1.0]]}
    system = system_from_table({**base, "R": [[1.0]], "learning": {"step_size": 0.5}})
    assert isinstance(system.learning, LearningConfig) and system.learning.step_size == 0.5
    assert system.given == ("step_size",) and "step_size" not in system.derived  # rest derived
    dep = deployment_from_table({"deputy": [{"name": "a", "learning": {"relearn": True}}]})
    learning = dep.deputy[0].learning
    assert isinstance(learning, LearningConfig) and learning.relearn
    assert (learning.step, learning.step_size, learning.seed) == ("implicit", 0.5, 1)
    assert learning.K0 == ((0.0, 0.0, 0.0, 0.0),) and learning.exploration_amplitude == 0.1
    assert learning.stopping == LearningConfig.stopping  # a key the mission leaves alone
    with pytest.raises(SystemFileError, match=r"^learning\.relearn: unknown key"):
        system_from_table({**base, "R": [[1.0]], "learning": {"relearn": True}})
    with pytest.raises(DeploymentError, match=r"^deputy\[0\]\.learning\.x0: unknown key"):
        deployment_from_table({"deputy": [{"name": "a", "learning": {"x0": [0.0]}}]})


def test_a_deputys_exploration_amplitude_is_half_its_attitude_limit_unless_given() -> None:
    """The mission's rule (``mission_learning``): the multi-sine takes half the attitude range."""
    table = {
        "deputy": [
            {"name": "a", "attitude_limit": 0.3},
            {"name": "b", "attitude_limit": 0.3, "learning": {"exploration_amplitude": 0.25}},
            {"name": "c", "attitude_limit": 0.3, "learning": {"seed": 4}},
        ]
    }
    a, b, c = (d.learning for d in deployment_from_table(table).deputy)
    assert (a.exploration_amplitude, b.exploration_amplitude) == (0.15, 0.25)
    assert (c.exploration_amplitude, c.seed, a.seed) == (0.15, 4, 1)


def test_deployment_errors_name_the_nested_path() -> None:
    table = {"deputy": [{"name": "a"}, {"name": "b", "learning": {"intervl": 600.0}}]}
    with pytest.raises(DeploymentError) as info:
        deployment_from_table(table)
    assert str(info.value).startswith(
        "deputy[1].learning.intervl: unknown key (did you mean 'interval'?)"
    )
    table = {"deputy": [{"name": "a", "learning": {"K0": [0.0, 0.0, math.nan, 0.0]}}]}
    with pytest.raises(DeploymentError, match=r"^deputy\[0\]\.learning\.K0\[2\]: must be finite"):
        deployment_from_table(table)
    table = {"deputy": [{"name": "a"}], "link": [{"publisher": "nav-*", "loss": 2.0}]}
    with pytest.raises(DeploymentError, match=r"^link\[0\]\.loss: expected a probability"):
        deployment_from_table(table)
