"""Every message type of the system, and the only encoder/decoder of bus payloads.

Wire format (DESIGN.md section 2): a msgpack map

    {"schema": str, "version": int, "seq": int, "t": float, "src": str, "body": {...}}

``t`` is simulation time in seconds and ``src`` the publishing service. Bodies hold only plain
msgpack values: ints, floats, bools, strings, maps with string keys, and (nested) lists of floats
for arrays. No ext types and no numpy, so any zenoh subscriber in any language decodes a payload
with a plain msgpack library.

A batch is several messages of one topic in one zenoh sample: a msgpack array of byte strings,
each one message's payload as above, in publication order (``pack_batch``, ``unpack_batch``).
A lock-step publisher sends the samples of one flight-software step that way: one zenoh
sample per topic and step instead of one per message, which is what the bus pays for.

Inputs/outputs:
    encode(schema, body, *, seq, t, src) -> bytes    validates, then packs
    decode(payload, expected=None) -> Message        unpacks (bounded), then validates
    schema_for_topic(topic) -> str | None            the schema a topic carries
    pack_batch(payloads) -> bytes                    several payloads in one sample
    unpack_batch(payload) -> list[bytes] | None      a batch's payloads; None: one message
    Both raise MessageError, whose ``reason`` is one of REASONS.

The schema table ``SCHEMAS`` is data: one ``Schema`` per message type, each a mapping of field
name to a field kind (``Int``, ``Float``, ``Bool``, ``Str``, ``Array``, ``IntMap``,
``ScalarMap``). Array fields travel as nested lists and come back from ``decode`` as float64
numpy arrays of the declared shape (``None`` = any length). This module has no state.

Two validators, one meaning: every schema is also compiled into msgspec types (``_Compiled``),
which check a well-formed message in C (types, lengths, finiteness) at a few microseconds; any
payload or body they refuse goes through the field kinds below, which are the definition: they
raise the ``MessageError`` that names what is wrong, or accept (and normalise) what the
compiled types are stricter about.  Either way the result is the same.
"""

from __future__ import annotations

import difflib
import functools
import math
import numbers
import sys
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import msgpack
import msgspec
import numpy as np

MAX_PAYLOAD = 60 * 1024
"""Largest accepted payload in bytes, checked before unpacking and after packing.  Below zenoh's
64 KiB transport batch, so that no bus message (and no refused oversized one) is ever
fragmented: a fragmented zenoh message can be lost whole under load (eclipse-zenoh/zenoh#1494),
and the garbage test lost 2 of 192 oversized payloads of 64 KiB that way."""

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

HEADER_KEYS = ("schema", "version", "seq", "t", "src", "body")

MAX_BATCH = 64
"""Most messages in one batch; a batch's whole payload is also at most ``MAX_PAYLOAD``."""


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


class Message(msgspec.Struct, frozen=True):
    """One decoded, validated message. Array fields of ``body`` are float64 numpy arrays.
    (An immutable msgspec struct: a bus builds one per message, at a tenth of a dataclass's
    cost.)"""

    schema: str
    version: int
    seq: int
    t: float
    src: str
    body: dict[str, Any]


# ---------------------------------------------------------------------------------------------
# Field kinds. Each ``check(where, value)`` returns the normalised value (Python scalars, numpy
# arrays) or raises MessageError; ``where`` is "schema.field" for the error text.


def _type_name(value: object) -> str:
    return type(value).__name__


def _is_int(value: object) -> bool:
    if type(value) is int:  # the common case, without the ABC machinery
        return True
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


def _is_real(value: object) -> bool:
    if type(value) is float or type(value) is int:
        return True
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


@dataclass(frozen=True)
class Int:
    """An integer (bools are not integers here)."""

    def check(self, where: str, value: object) -> int:
        if not _is_int(value):
            raise MessageError("bad_field", f"{where}: expected int, got {_type_name(value)}")
        return int(value)  # type: ignore[call-overload]


@dataclass(frozen=True)
class Float:
    """A finite float; ints are accepted and converted."""

    def check(self, where: str, value: object) -> float:
        if type(value) is float and math.isfinite(value):
            return value
        if not _is_real(value):
            raise MessageError("bad_field", f"{where}: expected float, got {_type_name(value)}")
        try:
            result = float(value)  # type: ignore[arg-type]
        except OverflowError:
            result = math.inf
        if not math.isfinite(result):
            raise MessageError("non_finite", f"{where}: expected a finite float, got {result}")
        return result


@dataclass(frozen=True)
class Bool:
    """A boolean."""

    def check(self, where: str, value: object) -> bool:
        if not isinstance(value, bool | np.bool_):
            raise MessageError("bad_field", f"{where}: expected bool, got {_type_name(value)}")
        return bool(value)


@dataclass(frozen=True)
class Str:
    """A string, optionally restricted to ``choices``."""

    choices: tuple[str, ...] | None = None

    def check(self, where: str, value: object) -> str:
        if not isinstance(value, str):
            raise MessageError("bad_field", f"{where}: expected str, got {_type_name(value)}")
        if self.choices is not None and value not in self.choices:
            options = "|".join(self.choices)
            raise MessageError("bad_field", f"{where}: expected one of {options}, got {value!r}")
        return str(value)  # a str subclass (numpy's) as a plain str


@dataclass(frozen=True)
class Array:
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
            raise MessageError("bad_field", f"{expected}, got {_type_name(value)}")
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


@dataclass(frozen=True)
class IntMap:
    """A map of string keys to ints (counters)."""

    def check(self, where: str, value: object) -> dict[str, int]:
        if not isinstance(value, Mapping):
            raise MessageError(
                "bad_field", f"{where}: expected map str->int, got {_type_name(value)}"
            )
        out: dict[str, int] = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise MessageError(
                    "bad_field", f"{where}: expected str keys, got {_type_name(key)}"
                )
            out[str(key)] = Int().check(f"{where}[{key!r}]", item)
        return out


@dataclass(frozen=True)
class ScalarMap:
    """A map of string keys to scalars: float (finite), int, str or bool."""

    def check(self, where: str, value: object) -> dict[str, float | int | str | bool]:
        if not isinstance(value, Mapping):
            raise MessageError("bad_field", f"{where}: expected map, got {_type_name(value)}")
        out: dict[str, float | int | str | bool] = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise MessageError(
                    "bad_field", f"{where}: expected str keys, got {_type_name(key)}"
                )
            inner = f"{where}[{key!r}]"
            key = str(key)
            if isinstance(item, bool | np.bool_):
                out[key] = bool(item)
            elif _is_int(item):
                out[key] = int(item)  # type: ignore[call-overload]
            elif isinstance(item, str):
                out[key] = str(item)
            elif _is_real(item):
                out[key] = Float().check(inner, item)
            else:
                raise MessageError(
                    "bad_field", f"{inner}: expected float|int|str|bool, got {_type_name(item)}"
                )
        return out


Field = Int | Float | Bool | Str | Array | IntMap | ScalarMap


@dataclass(frozen=True)
class Schema:
    """One message type: its name, version and body fields (all required, no extras)."""

    name: str
    version: int
    fields: Mapping[str, Field]


def _schemas(*items: Schema) -> dict[str, Schema]:
    return {s.name: s for s in items}


SCHEMAS: Mapping[str, Schema] = _schemas(
    Schema(
        "clock",
        1,
        {
            "step": Int(),
            "dt": Float(),
            "fsw": Bool(),
            "mode": Str(("lockstep", "realtime")),
            "final": Bool(),
        },
    ),
    Schema(
        "truth",
        1,
        {"sc": Str(), "r_N": Array((3,)), "v_N": Array((3,)), "sigma_BN": Array((3,))},
    ),
    Schema("exo", 1, {"v": Array((None,)), "phase": Float()}),
    # altitude: the deputy's own, from its absolute navigation (m above R_E)
    Schema("nav", 1, {"sc": Str(), "x_hill": Array((6,)), "altitude": Float(), "valid": Bool()}),
    Schema("cmd", 1, {"sc": Str(), "sigma": Array((3,)), "for_t": Float()}),
    Schema(
        "gains",
        1,
        {
            "sc": Str(),
            "K": Array((None, None)),
            "L": Array((None, None)),
            "source": Str(("initial", "lqr", "ddvi", "fallback")),
            "iteration": Int(),
            "converged": Bool(),
        },
    ),
    Schema(
        "status",
        1,
        {
            "sc": Str(),
            "mode": Str(),
            "phase": Str(),
            "samples": Int(),
            "intervals": Int(),
            "rank": Int(),
            "rank_needed": Int(),
            "counters": IntMap(),
        },
    ),
    Schema("fault", 1, {"kind": Str(), "target": Str(), "params": ScalarMap()}),
    Schema("stats", 1, {"service": Str(), "counters": IntMap()}),
    Schema("log", 1, {"service": Str(), "level": Str(), "text": Str()}),
)
"""Every message type of the system, by name."""

TOPIC_SCHEMAS: tuple[tuple[str, str], ...] = (
    ("clock", "clock"),
    ("exo/state", "exo"),
    ("truth/*", "truth"),
    ("nav/*/state", "nav"),
    ("cmd/*/att", "cmd"),
    ("ctrl/*/gains", "gains"),
    ("ctrl/*/status", "status"),
    ("fault/**", "fault"),
    ("stats/*", "stats"),
    ("log/*", "log"),
)
"""Which schema each topic (below ``ddvi/<run>/``) carries (DESIGN.md section 2): ``*`` is one
key chunk, ``**`` the rest of the key."""


@functools.lru_cache(maxsize=4096)  # a run has a few dozen topics; garbage may add more
def schema_for_topic(topic: str) -> str | None:
    """The schema a topic carries (``TOPIC_SCHEMAS``), None for a topic outside the table."""
    chunks = topic.split("/")
    for pattern, schema in TOPIC_SCHEMAS:
        want = pattern.split("/")
        if want[-1] == "**":  # the rest of the key, at least one chunk
            want, chunks_ = want[:-1], chunks[: len(want) - 1]
            if len(chunks) < len(want) + 1:
                continue
        else:
            chunks_ = chunks
        if len(want) == len(chunks_) and all(
            w in ("*", c) for w, c in zip(want, chunks_, strict=True)
        ):
            return schema
    return None


# ---------------------------------------------------------------------------------------------


def _lookup(name: object) -> Schema:
    if not isinstance(name, str) or name not in SCHEMAS:
        raise MessageError(
            "unknown_schema", f"unknown schema {name!r}; known: {', '.join(sorted(SCHEMAS))}"
        )
    return SCHEMAS[name]


def check_body(schema: str, body: Mapping[str, Any]) -> dict[str, Any]:
    """Validate ``body`` against ``schema``; return it normalised (arrays as float64 ndarrays)."""
    spec = _lookup(schema)
    if not isinstance(body, Mapping):
        raise MessageError("bad_field", f"{schema}: expected body map, got {_type_name(body)}")
    for key in body:
        if key not in spec.fields:
            near = difflib.get_close_matches(str(key), list(spec.fields), n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise MessageError("bad_field", f"{schema}.{key}: unknown field{hint}")
    out: dict[str, Any] = {}
    for name, field in spec.fields.items():
        if name not in body:
            raise MessageError("bad_field", f"{schema}.{name}: missing field")
        out[name] = field.check(f"{schema}.{name}", body[name])
    return out


def _to_wire(value: Any) -> Any:
    return value.tolist() if isinstance(value, np.ndarray) else value


def _check_header(schema: str, seq: object, t: object, src: object) -> tuple[int, float, str]:
    if not _is_int(seq) or int(seq) < 0:  # type: ignore[call-overload]
        raise MessageError("bad_header", f"{schema} header.seq: expected int >= 0, got {seq!r}")
    if not _is_real(t):
        raise MessageError("bad_header", f"{schema} header.t: expected float, got {_type_name(t)}")
    t_f = Float().check(f"{schema} header.t", t)
    if not isinstance(src, str) or not src:
        raise MessageError(
            "bad_header", f"{schema} header.src: expected non-empty str, got {src!r}"
        )
    return int(seq), t_f, src  # type: ignore[call-overload]


def encode(schema: str, body: Mapping[str, Any], *, seq: int, t: float, src: str) -> bytes:
    """Validate ``body`` against ``schema`` and pack the full message.

    Numpy arrays and numpy scalars are accepted and converted to plain lists/floats.
    Raises MessageError (``unknown_schema``, ``bad_field``, ``non_finite``, ``bad_header``,
    ``oversized``).
    """
    compiled = _COMPILED.get(schema)  # type: ignore[arg-type]
    wire = None if compiled is None else compiled.wire(body)
    if (
        wire is not None
        and type(seq) is int
        and seq >= 0
        and type(t) is float
        and math.isfinite(t)
        and type(src) is str
        and src
    ):
        message = {"schema": schema, "version": compiled.version, "seq": seq, "t": t, "src": src}
    else:  # the field kinds name what is wrong, or normalise what the fast path refused
        spec = _lookup(schema)
        seq_i, t_f, src_s = _check_header(schema, seq, t, src)
        clean = check_body(schema, body)
        wire = {k: _to_wire(v) for k, v in clean.items()}
        message = {"schema": schema, "version": spec.version, "seq": seq_i, "t": t_f, "src": src_s}
    message["body"] = wire
    payload = _ENCODER.encode(message)
    if len(payload) > MAX_PAYLOAD:
        raise MessageError(
            "oversized", f"{schema}: encoded size {len(payload)} B exceeds {MAX_PAYLOAD} B"
        )
    return payload


def _checked_size(payload: bytes) -> int:
    """len(payload); MessageError ``oversized`` past MAX_PAYLOAD (checked before unpacking)."""
    size = len(payload)
    if size > MAX_PAYLOAD:
        raise MessageError("oversized", f"payload of {size} B exceeds {MAX_PAYLOAD} B")
    return size


def _unpack(payload: bytes, what: str, **limits: Any) -> Any:
    """msgpack.unpackb of untrusted bytes within ``limits`` (no ext types); any failure is
    MessageError ``malformed``, naming ``what`` was expected."""
    try:
        return msgpack.unpackb(payload, raw=False, use_list=True, max_ext_len=0, **limits)
    except Exception as exc:
        raise MessageError("malformed", f"not a msgpack {what}: {exc}") from exc


def decode(payload: bytes, expected: str | Collection[str] | None = None) -> Message:
    """Unpack and validate a payload; ``expected`` restricts the accepted schema name(s).

    Never raises anything but MessageError for any input bytes.
    """
    size = _checked_size(payload)
    message = _fast_decode(payload, expected)
    if message is not None:
        return message
    raw = _unpack(
        payload, "message", strict_map_key=True, max_str_len=size, max_bin_len=0,
        max_array_len=size, max_map_len=size,
    )  # fmt: skip
    if not isinstance(raw, dict):
        raise MessageError("malformed", f"expected a msgpack map, got {_type_name(raw)}")
    keys = set(raw)
    if keys != set(HEADER_KEYS):
        missing = sorted(set(HEADER_KEYS) - keys)
        extra = sorted(str(k) for k in keys - set(HEADER_KEYS))
        raise MessageError("bad_header", f"header: missing {missing}, unexpected {extra}")
    name = raw["schema"]
    if not isinstance(name, str):
        raise MessageError("bad_header", f"header.schema: expected str, got {_type_name(name)}")
    spec = _lookup(name)
    if expected is not None:
        allowed = {expected} if isinstance(expected, str) else set(expected)
        if name not in allowed:
            raise MessageError(
                "wrong_schema", f"expected schema {'|'.join(sorted(allowed))}, got {name!r}"
            )
    version = raw["version"]
    if not _is_int(version):
        raise MessageError(
            "bad_header", f"{name} header.version: expected int, got {_type_name(version)}"
        )
    if version != spec.version:
        raise MessageError("version", f"{name}: expected version {spec.version}, got {version}")
    seq, t, src = _check_header(name, raw["seq"], raw["t"], raw["src"])
    body = raw["body"]
    if not isinstance(body, dict):
        raise MessageError(
            "bad_header", f"{name} header.body: expected map, got {_type_name(body)}"
        )
    return Message(name, version, seq, t, src, check_body(name, body))


def pack_batch(payloads: Collection[bytes]) -> bytes:
    """Several encoded messages (of one topic, in order) as one payload: a msgpack array of
    byte strings.  Raises MessageError (``oversized``) past ``MAX_BATCH`` messages or
    ``MAX_PAYLOAD`` bytes, and ValueError for an empty batch."""
    if not payloads:
        raise ValueError("a batch needs at least one message")
    if len(payloads) > MAX_BATCH:
        raise MessageError("oversized", f"batch of {len(payloads)} messages exceeds {MAX_BATCH}")
    packed = _ENCODER.encode(list(payloads))
    if len(packed) > MAX_PAYLOAD:
        raise MessageError("oversized", f"batch of {len(packed)} B exceeds {MAX_PAYLOAD} B")
    return packed


_ARRAY_MARKERS = frozenset(range(0x90, 0xA0)) | {0xDC, 0xDD}  # fixarray, array 16, array 32


def unpack_batch(payload: bytes) -> list[bytes] | None:
    """The messages of a batch payload, in order; None when ``payload`` is not a batch (a
    single message, or garbage for ``decode`` to name).  Raises MessageError (``oversized``,
    ``malformed``) for a batch that is too large or not an array of 1 to ``MAX_BATCH`` byte
    strings.  Each part is still to be ``decode``d: a batch vouches for nothing inside it."""
    size = _checked_size(payload)
    if not size or payload[0] not in _ARRAY_MARKERS:
        return None
    parts = _unpack(
        payload, "batch", max_str_len=0, max_bin_len=size, max_array_len=MAX_BATCH, max_map_len=0
    )
    if not parts or not all(type(p) is bytes for p in parts):
        raise MessageError(
            "malformed", f"a batch is an array of 1 to {MAX_BATCH} byte strings (messages)"
        )
    return parts


# ---------------------------------------------------------------------------------------------
# The compiled validators: each schema as msgspec types (see the module docstring).

_DBL_MAX = sys.float_info.max
_Finite = Annotated[float, msgspec.Meta(ge=-_DBL_MAX, le=_DBL_MAX)]  # NaN and inf fail both
_ENCODER = msgspec.msgpack.Encoder()
_FLOAT64 = np.dtype(np.float64)
_PLAIN = frozenset({str, float, int, bool, list, dict})  # what needs no numpy conversion


def _compiled_type(field: Field) -> Any:
    """The msgspec type that accepts what ``field.check`` accepts from the wire (or less)."""
    if isinstance(field, Int):
        return int
    if isinstance(field, Float):
        return _Finite
    if isinstance(field, Bool):
        return bool
    if isinstance(field, Str):
        return str if field.choices is None else Literal[field.choices]  # type: ignore[valid-type]
    if isinstance(field, Array):
        inner: Any = _Finite
        for n in reversed(field.shape):
            inner = (
                list[inner]
                if n is None
                else Annotated[list[inner], msgspec.Meta(min_length=n, max_length=n)]
            )
        return inner
    if isinstance(field, IntMap):
        return dict[str, int]
    return dict[str, bool | int | _Finite | str]  # ScalarMap


class _Header(msgspec.Struct, forbid_unknown_fields=True):
    schema: str
    version: int
    seq: Annotated[int, msgspec.Meta(ge=0)]
    t: _Finite
    src: Annotated[str, msgspec.Meta(min_length=1)]
    body: msgspec.Raw


_HEADER = msgspec.msgpack.Decoder(_Header)


class _Compiled:
    """One schema's msgspec body type, and the two fast paths over it."""

    def __init__(self, spec: Schema) -> None:
        self.version = spec.version
        self.fields = tuple(spec.fields)
        self.arrays = tuple(
            (name, f.shape) for name, f in spec.fields.items() if isinstance(f, Array)
        )
        self.body = msgspec.defstruct(
            f"{spec.name}_body",
            [(name, _compiled_type(f)) for name, f in spec.fields.items()],
            forbid_unknown_fields=True,
        )
        self.decoder = msgspec.msgpack.Decoder(self.body)
        # the whole message of this schema in one pass, for a receiver that expects it
        self.message = msgspec.msgpack.Decoder(
            msgspec.defstruct(
                f"{spec.name}_message",
                [
                    ("schema", Literal[spec.name]),  # type: ignore[valid-type]
                    ("version", Literal[spec.version]),  # type: ignore[valid-type]
                    *[  # seq, t and src with the header's limits
                        (f.name, f.type)
                        for f in msgspec.structs.fields(_Header)
                        if f.name in ("seq", "t", "src")
                    ],
                    ("body", self.body),
                ],
                forbid_unknown_fields=True,
            )
        )
        # 1-D fixed-length arrays come off the compiled types as flat float lists, always
        self.any_shape = any(len(shape) > 1 or None in shape for _, shape in self.arrays)

    def arrays_of(self, body: dict[str, Any]) -> dict[str, Any] | None:
        """``body`` with its array fields as float64 ndarrays; None if one is ragged, or an
        empty nested list (whose inner dimensions the field kind rebuilds)."""
        if not self.any_shape:
            for name, _ in self.arrays:
                body[name] = np.array(body[name], dtype=np.float64)
            return body
        for name, shape in self.arrays:
            try:
                body[name] = np.array(body[name], dtype=np.float64)
            except ValueError:
                return None
            if body[name].ndim != len(shape):
                return None
        return body

    def wire(self, body: Any) -> msgspec.Struct | None:
        """``body`` as the compiled type (plain msgpack values in field order, packed as a
        map); None when anything is not plainly right (the field kinds then decide)."""
        if type(body) is not dict or len(body) != len(self.fields):
            return None
        out: dict[str, Any] = {}
        try:
            for name in self.fields:
                value = body[name]  # a missing field: KeyError
                kind = type(value)
                if kind is np.ndarray:
                    if value.dtype is not _FLOAT64 or not value.ndim:  # 0-d: no scalar field
                        return None
                    value = value.tolist()
                elif kind not in _PLAIN and isinstance(value, np.generic):
                    value = value.item()  # a numpy scalar, as the field kinds take it
                out[name] = value
            # the converted values: an int where a float is declared goes out as a float
            return msgspec.convert(out, self.body)
        except Exception:
            return None


_COMPILED: dict[str, _Compiled] = {name: _Compiled(spec) for name, spec in SCHEMAS.items()}


def _fast_decode(payload: bytes, expected: str | Collection[str] | None) -> Message | None:
    """``decode`` by the compiled types; None for anything they refuse."""
    if type(expected) is str and (compiled := _COMPILED.get(expected)) is not None:
        try:  # one pass: header and body of the one schema the receiver takes
            whole = compiled.message.decode(payload)
            body = compiled.arrays_of(msgspec.structs.asdict(whole.body))
        except Exception:
            return None
        if body is None:
            return None
        return Message(whole.schema, whole.version, whole.seq, whole.t, whole.src, body)
    try:
        head = _HEADER.decode(payload)
        compiled = _COMPILED.get(head.schema)
        if compiled is None or head.version != compiled.version:
            return None
        if (
            expected is not None
            and head.schema != expected
            and (isinstance(expected, str) or head.schema not in expected)
        ):
            return None
        body = compiled.arrays_of(msgspec.structs.asdict(compiled.decoder.decode(head.body)))
    except Exception:  # anything odd (bad UTF-8 in a key, ...): the field kinds name it
        return None
    if body is None:
        return None
    return Message(head.schema, head.version, head.seq, head.t, head.src, body)
