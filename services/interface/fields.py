"""Field kinds: what one field of a message body may hold, and the check that says so.

Each kind's ``check(where, value)`` returns the normalised value (Python scalars, float64 numpy
arrays) or raises ``MessageError``; ``where`` is "schema.field" for the error text.  These
checks are the definition of a valid body: the codec's compiled fast path
(``services.interface.codec``) only ever agrees with them, faster.

Every kind also carries the field's ``unit`` and a one-line ``doc`` (keyword-only, for the
catalogue in ``services.interface.messages`` and the generated ``docs/interface.md``); the
checks never read them.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import KW_ONLY, dataclass

import numpy as np

REASONS = frozenset(
    {
        "oversized",
        "malformed",
        "bad_header",
        "unknown_schema",
        "wrong_schema",
        "version",
        "bad_field",
        "non_finite",
    }
)
"""Every value ``MessageError.reason`` can take."""


class MessageError(ValueError):
    """A payload or body that does not conform to its schema.

    ``reason`` is a short code from ``REASONS`` (for counters); ``str(err)`` names the schema,
    the field, what was expected and what was found.
    """

    def __init__(self, reason: str, text: str) -> None:
        if reason not in REASONS:
            raise ValueError(f"unknown MessageError reason {reason!r}")
        super().__init__(text)
        self.reason = reason


def type_name(value: object) -> str:
    """The name of ``value``'s type, for error texts."""
    return type(value).__name__


def is_int(value: object) -> bool:
    """An integer that is not a bool."""
    if type(value) is int:  # the common case, without the ABC machinery
        return True
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


def is_real(value: object) -> bool:
    """A real number that is not a bool."""
    if type(value) is float or type(value) is int:
        return True
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


@dataclass(frozen=True)
class Described:
    """What every field kind says about its field: ``unit`` ("" for none, "1" for a pure
    number) and ``doc``, one line on what the field means."""

    _: KW_ONLY
    unit: str = ""
    doc: str = ""


@dataclass(frozen=True)
class Int(Described):
    """An integer (bools are not integers here)."""

    def check(self, where: str, value: object) -> int:
        if not is_int(value):
            raise MessageError("bad_field", f"{where}: expected int, got {type_name(value)}")
        return int(value)  # type: ignore[call-overload]


@dataclass(frozen=True)
class Float(Described):
    """A finite float; ints are accepted and converted."""

    def check(self, where: str, value: object) -> float:
        if type(value) is float and math.isfinite(value):
            return value
        if not is_real(value):
            raise MessageError("bad_field", f"{where}: expected float, got {type_name(value)}")
        try:
            result = float(value)  # type: ignore[arg-type]
        except OverflowError:
            result = math.inf
        if not math.isfinite(result):
            raise MessageError("non_finite", f"{where}: expected a finite float, got {result}")
        return result


@dataclass(frozen=True)
class Bool(Described):
    """A boolean."""

    def check(self, where: str, value: object) -> bool:
        if not isinstance(value, bool | np.bool_):
            raise MessageError("bad_field", f"{where}: expected bool, got {type_name(value)}")
        return bool(value)


@dataclass(frozen=True)
class Str(Described):
    """A string, optionally restricted to ``choices``."""

    choices: tuple[str, ...] | None = None

    def check(self, where: str, value: object) -> str:
        if not isinstance(value, str):
            raise MessageError("bad_field", f"{where}: expected str, got {type_name(value)}")
        if self.choices is not None and value not in self.choices:
            options = "|".join(self.choices)
            raise MessageError("bad_field", f"{where}: expected one of {options}, got {value!r}")
        return str(value)  # a str subclass (numpy's) as a plain str


@dataclass(frozen=True)
class Array(Described):
    """A float array of the given shape; a ``None`` dimension accepts any length."""

    shape: tuple[int | None, ...]

    def describe(self) -> str:
        if len(self.shape) == 1:
            n = self.shape[0]
            return "a list of finite floats" if n is None else f"{n} finite floats"
        dims = "x".join("N" if d is None else str(d) for d in self.shape)
        return f"a {dims} nested list of finite floats"

    def check(self, where: str, value: object) -> np.ndarray:
        if len(self.shape) == 1:
            # fast paths for what the bus carries (a list of floats off the wire, a float64
            # vector from a service); anything else takes the general path and its messages
            n = self.shape[0]
            if (
                type(value) is list
                and (n is None or len(value) == n)
                and all(type(v) is float and math.isfinite(v) for v in value)
            ):
                return np.array(value, dtype=np.float64)
            if (
                type(value) is np.ndarray
                and value.dtype == np.float64
                and value.ndim == 1
                and (n is None or value.shape[0] == n)
                and np.isfinite(value).all()
            ):
                return value
        expected = f"{where}: expected {self.describe()}"
        if not isinstance(value, list | tuple | np.ndarray):
            raise MessageError("bad_field", f"{expected}, got {type_name(value)}")
        try:
            arr = np.asarray(value)
        except (ValueError, TypeError, OverflowError) as exc:
            raise MessageError("bad_field", f"{expected}, got a ragged or mixed list") from exc
        if arr.size == 0 and arr.ndim == 1 and len(self.shape) > 1:
            # An empty nested list carries no inner dimensions: rebuild them from the spec.
            arr = np.empty((0, *(d or 0 for d in self.shape[1:])))
        if arr.dtype.kind not in "fiu":
            raise MessageError("bad_field", f"{expected}, got elements of type {arr.dtype}")
        if len(self.shape) == 1 and arr.ndim == 1 and self.shape[0] is not None:
            if arr.shape[0] != self.shape[0]:
                raise MessageError("bad_field", f"{expected}, got {arr.shape[0]}")
        elif arr.ndim != len(self.shape) or any(
            d is not None and d != n for d, n in zip(self.shape, arr.shape, strict=True)
        ):
            raise MessageError("bad_field", f"{expected}, got shape {arr.shape}")
        out = arr.astype(np.float64)
        if not np.all(np.isfinite(out)):
            bad = np.argwhere(~np.isfinite(out))[0]
            index = tuple(int(i) for i in bad)
            shown = index[0] if len(index) == 1 else index
            raise MessageError("non_finite", f"{expected}, got {out[index]} at index {shown}")
        return out


_AN_INT = Int()  # the check of one IntMap value
_A_FLOAT = Float()  # the check of one real ScalarMap value


@dataclass(frozen=True)
class IntMap(Described):
    """A map of string keys to ints (counters)."""

    def check(self, where: str, value: object) -> dict[str, int]:
        if not isinstance(value, Mapping):
            raise MessageError(
                "bad_field", f"{where}: expected map str->int, got {type_name(value)}"
            )
        out: dict[str, int] = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise MessageError("bad_field", f"{where}: expected str keys, got {type_name(key)}")
            out[str(key)] = _AN_INT.check(f"{where}[{key!r}]", item)
        return out


@dataclass(frozen=True)
class ScalarMap(Described):
    """A map of string keys to scalars: float (finite), int, str or bool."""

    def check(self, where: str, value: object) -> dict[str, float | int | str | bool]:
        if not isinstance(value, Mapping):
            raise MessageError("bad_field", f"{where}: expected map, got {type_name(value)}")
        out: dict[str, float | int | str | bool] = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise MessageError("bad_field", f"{where}: expected str keys, got {type_name(key)}")
            inner = f"{where}[{key!r}]"
            key = str(key)
            if isinstance(item, bool | np.bool_):
                out[key] = bool(item)
            elif is_int(item):
                out[key] = int(item)  # type: ignore[call-overload]
            elif isinstance(item, str):
                out[key] = str(item)
            elif is_real(item):
                out[key] = _A_FLOAT.check(inner, item)
            else:
                raise MessageError(
                    "bad_field", f"{inner}: expected float|int|str|bool, got {type_name(item)}"
                )
        return out


Field = Int | Float | Bool | Str | Array | IntMap | ScalarMap
"""Any field kind."""
