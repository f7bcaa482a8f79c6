"""The strict reader of parsed TOML tables: a ``dict`` from ``tomllib`` into a frozen dataclass.

Every key is checked against the dataclass's fields and every value against the field's type;
the first problem raises one line naming the full key path and the problem, e.g.
``deputy[1].learning.intervl: unknown key (did you mean 'interval'?); allowed: ...`` or
``A[1][1]: must be finite, got nan``.  Pure functions on dicts: no file I/O.

Field types understood (``from __future__ import annotations`` is fine):

- ``float`` (an integer is taken as a float; booleans, NaN and infinities are refused),
  ``int`` (not a boolean), ``bool``, ``str``;
- ``list[T]`` and ``tuple[T, ...]``: a TOML array, each item a ``T``;
- :data:`Matrix`: a non-empty array of rows of numbers, every row the same length;
  :data:`FlatRowMatrix`: the same, where a single row may also be written flat (``[1.0, 2.0]``
  is the matrix ``[[1.0, 2.0]]``);
- ``T | None``: a value of type ``T`` (TOML has no null: a key given is a value);
- another dataclass: a TOML table read by the same rules.  A field made by :func:`table_field`
  says which keys a file may give and which defaults the file's table overrides.

A dataclass's own ``__post_init__`` may refuse a value by raising
``ValueError("<ClassName>.<field>: <problem>")``; the reader reports it as
``<path>.<field>: <problem>``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Callable, Mapping
from typing import Annotated, Any, TypeVar

__all__ = [
    "FlatRowMatrix",
    "Matrix",
    "TableError",
    "from_table",
    "table_field",
]

T = TypeVar("T")

Matrix = tuple[tuple[float, ...], ...]
"""A matrix as a TOML array of rows: non-empty, every row the same length."""

FlatRowMatrix = Annotated[Matrix, "a single row may be written flat"]
"""A :data:`Matrix` whose single row may be written as a flat array of numbers."""

_TABLE = "ddvi_core.tables"  # the key of a table_field's metadata


class TableError(ValueError):
    """A table that does not fit its dataclass; the message is one line naming the key."""


@dataclasses.dataclass(frozen=True)
class _TableRules:
    """What a file may give for one dataclass-typed field (see :func:`table_field`)."""

    keys: tuple[str, ...] | None  # the keys a file may give; None: every field
    defaults: Mapping[str, Any]  # the values the file's table overrides, key by key


def table_field(
    cls: type[T],
    *,
    keys: tuple[str, ...] | None = None,
    defaults: Mapping[str, Any] | None = None,
) -> Any:
    """A dataclass field of dataclass type ``cls`` read from a TOML table.

    Parameters
    ----------
    cls : a dataclass type.
    keys : the keys a file may give (default: every field of ``cls``).
    defaults : a table of values (TOML-shaped, read by the same rules) that the file's table
        overrides key by key; the field's value when the file gives no table at all.
    """
    rules = _TableRules(None if keys is None else tuple(keys), dict(defaults or {}))
    return dataclasses.field(
        default_factory=lambda: from_table(cls, rules.defaults),
        metadata={_TABLE: rules},
    )


def _show(value: Any) -> str:
    """A value's repr, cut to one short line, and its type: ``'35' (str)``."""
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _number(where: str, value: Any, error: type[ValueError]) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise error(f"{where}: expected a number, got {_show(value)}")
    if not math.isfinite(value):
        raise error(f"{where}: must be finite, got {value!r}")
    return float(value)


def _scalar(where: str, tp: Any, value: Any, error: type[ValueError]) -> Any:
    """A float, int, bool or str value, checked."""
    if tp is float:
        return _number(where, value, error)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise error(f"{where}: expected an integer, got {_show(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise error(f"{where}: expected true or false, got {_show(value)}")
        return value
    if not isinstance(value, str):
        raise error(f"{where}: expected a string, got {_show(value)}")
    return value


def _matrix(where: str, value: Any, error: type[ValueError], flat_row: bool) -> Matrix:
    """Rows of numbers, all the same length (``flat_row``: one row may be written flat)."""
    if flat_row and isinstance(value, list) and value and not isinstance(value[0], list):
        return (tuple(_number(f"{where}[{j}]", v, error) for j, v in enumerate(value)),)
    if not isinstance(value, list) or not value:
        raise error(
            f"{where}: expected a matrix as a non-empty list of rows, "
            f"for example [[1.0, 0.0], [0.0, 1.0]], got {_show(value)}"
        )
    rows = []
    for i, row in enumerate(value):
        if not isinstance(row, list):
            raise error(f"{where}[{i}]: expected a row (a list of numbers), got {_show(row)}")
        rows.append(tuple(_number(f"{where}[{i}][{j}]", v, error) for j, v in enumerate(row)))
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        raise error(f"{where}: rows have different lengths {sorted(widths)}")
    return tuple(rows)


def _sequence(where: str, tp: Any, value: Any, error: type[ValueError]) -> list | tuple:
    """A ``list[T]`` or ``tuple[T, ...]`` from a TOML array."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is tuple and (len(args) != 2 or args[1] is not Ellipsis):
        raise TypeError(f"{where}: fixed-length tuple types are not supported: {tp}")
    if not isinstance(value, list):
        raise error(f"{where}: expected a list, got {_show(value)}")
    items = [_convert(f"{where}[{i}]", args[0], v, error) for i, v in enumerate(value)]
    return items if origin is list else tuple(items)


def _convert(where: str, tp: Any, value: Any, error: type[ValueError]) -> Any:
    """``value`` as type ``tp`` (see the module docstring), or ``error`` naming ``where``."""
    if typing.get_origin(tp) is Annotated:
        base = typing.get_args(tp)[0]
        if base == Matrix:
            return _matrix(where, value, error, flat_row=tp == FlatRowMatrix)
        return _convert(where, base, value, error)
    if tp == Matrix:
        return _matrix(where, value, error, flat_row=False)
    if tp in (float, int, bool, str):
        return _scalar(where, tp, value, error)
    origin = typing.get_origin(tp)
    if origin in (list, tuple):
        return _sequence(where, tp, value, error)
    if dataclasses.is_dataclass(tp):
        return from_table(tp, value, where, error=error)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return _convert(where, args[0], value, error)
    raise TypeError(f"{where}: the table reader does not support the type {tp}")


def _unknown(where: str, key: str, allowed: tuple[str, ...]) -> str:
    near = difflib.get_close_matches(key, allowed, n=1)
    hint = f" (did you mean '{near[0]}'?)" if near else ""
    return f"{_join(where, key)}: unknown key{hint}; allowed: {', '.join(allowed)}"


def _construct(cls: Callable[..., T], kwargs: dict[str, Any], where: str, error: type) -> T:
    """``cls(**kwargs)``; a ValueError of the class's own checks becomes ``error`` at
    ``where`` (``"<ClassName>.<field>: ..."`` is reported at ``<where>.<field>: ...``)."""
    try:
        return cls(**kwargs)
    except ValueError as exc:
        text, own = str(exc), f"{getattr(cls, '__name__', '')}."
        if text.startswith(own):
            raise error(_join(where, text[len(own) :])) from None
        raise error(f"{where or '(top level)'}: {text}") from None


def from_table(
    cls: type[T],
    table: Any,
    where: str = "",
    *,
    keys: tuple[str, ...] | None = None,
    defaults: Mapping[str, Any] | None = None,
    error: type[ValueError] = TableError,
) -> T:
    """Build the dataclass ``cls`` from a parsed TOML table, checking every key and value.

    Parameters
    ----------
    cls : a dataclass type (frozen by convention); its fields' types say what each key holds.
    table : the parsed TOML value (a dict, or anything else: refused).
    where : the key path of ``table`` in its file ("" at the top level), prefixed to every
        message: ``deputy[0].learning``.
    keys : the keys the table may give (default: every field of ``cls``).
    defaults : a TOML-shaped table of values that ``table`` overrides key by key.
    error : the ValueError subclass raised.

    Returns
    -------
    An instance of ``cls``.  A field neither given nor defaulted takes its dataclass default;
    one without a default is required.

    Raises
    ------
    error : one line, ``<path>: <problem>``, for the first unknown key, wrong type, wrong
        shape, non-finite number, missing required key or value the class refuses.
    """
    if not isinstance(table, dict):
        raise error(f"{where or '(top level)'}: expected a table, got {_show(table)}")
    allowed = tuple(f.name for f in dataclasses.fields(cls)) if keys is None else keys
    for key in table:
        if key not in allowed:
            raise error(_unknown(where, key, allowed))
    hints = typing.get_type_hints(cls, include_extras=True)
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        rules = f.metadata.get(_TABLE)
        if f.name in table:
            value = table[f.name]
        elif f.name in (defaults or {}):
            value = defaults[f.name]
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise error(f"{_join(where, f.name)}: required, not given")
        else:
            continue
        path = _join(where, f.name)
        if rules is not None and dataclasses.is_dataclass(hints[f.name]):
            kwargs[f.name] = from_table(
                hints[f.name], value, path, keys=rules.keys, defaults=rules.defaults, error=error
            )
        else:
            kwargs[f.name] = _convert(path, hints[f.name], value, error)
    return _construct(cls, kwargs, where, error)
