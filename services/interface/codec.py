"""The codec: the only encoder/decoder of bus payloads (docs/design.md, "The bus").

Wire format: a msgpack map

    {"schema": str, "version": int, "seq": int, "t": float, "src": str, "boot": int,
     "body": {...}}

``t`` is simulation time in seconds, ``src`` the publishing service and ``boot`` its bus's
random boot number (a receiver's sequence window is per publisher, topic and boot). Bodies hold
only plain msgpack values: ints, floats, bools, strings, maps with string keys, and (nested)
lists of floats for arrays. No ext types and no numpy, so any zenoh subscriber in any language
decodes a payload with a plain msgpack library.

A batch is several messages of one topic in one zenoh sample: a msgpack array of byte strings,
each one message's payload as above, in publication order (``pack_batch``, ``unpack_batch``).
A lock-step publisher sends the samples of one flight-software step that way: one zenoh
sample per topic and step instead of one per message, which is what the bus pays for.

Inputs/outputs:
    encode(schema, body, *, seq, t, src, boot) -> bytes    validates, then packs
    decode(payload, expected=None) -> Message        unpacks (bounded), then validates
    pack_batch(payloads) -> bytes                    several payloads in one sample
    unpack_batch(payload) -> list[bytes] | None      a batch's payloads; None: one message
    All raise MessageError, whose ``reason`` is one of REASONS.

The message types are ``SCHEMAS`` (``services.interface.messages``).  Array fields travel as
nested lists and come back from ``decode`` as float64 numpy arrays of the declared shape
(``None`` = any length). This module has no state.

Two validators, one meaning: every schema is also compiled into msgspec types (``_Compiled``),
which check a well-formed message in C (types, lengths, finiteness); any payload or body they
refuse goes through the field kinds (``services.interface.fields``), which are the definition:
they raise the ``MessageError`` that names what is wrong, or accept (and normalise) what the
compiled types are stricter about.  Either way the result is the same.
"""

from __future__ import annotations

import difflib
import math
import sys
from collections.abc import Collection, Mapping
from typing import Annotated, Any, Literal

import msgpack
import msgspec
import numpy as np

from services.interface.fields import (
    Array,
    Bool,
    Field,
    Float,
    Int,
    IntMap,
    MessageError,
    Str,
    is_int,
    is_real,
    type_name,
)
from services.interface.messages import HEADER_KEYS, SCHEMAS, Message, Schema

MAX_PAYLOAD = 60 * 1024
"""Largest accepted payload in bytes, checked before unpacking and after packing.  Below zenoh's
64 KiB transport batch, so that no bus message (and no refused oversized one) is ever
fragmented: a fragmented zenoh message can be lost whole under load (eclipse-zenoh/zenoh#1494),
and the garbage test lost 2 of 192 oversized payloads of 64 KiB that way."""

MAX_BATCH = 64
"""Most messages in one batch; a batch's whole payload is also at most ``MAX_PAYLOAD``."""

_HEADER_T = Float()  # the check of header.t
MAX_UINT = 2**64 - 1  # seq and boot are msgpack's unsigned 64-bit integers


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
        raise MessageError("bad_field", f"{schema}: expected body map, got {type_name(body)}")
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


def _check_header(
    schema: str, seq: object, t: object, src: object, boot: object
) -> tuple[int, float, str, int]:
    for name, value in (("seq", seq), ("boot", boot)):
        if not is_int(value) or not 0 <= int(value) <= MAX_UINT:  # type: ignore[call-overload]
            raise MessageError(
                "bad_header", f"{schema} header.{name}: expected int in [0, 2^64), got {value!r}"
            )
    if not is_real(t):
        raise MessageError("bad_header", f"{schema} header.t: expected float, got {type_name(t)}")
    t_f = _HEADER_T.check(f"{schema} header.t", t)
    if not isinstance(src, str) or not src:
        raise MessageError(
            "bad_header", f"{schema} header.src: expected non-empty str, got {src!r}"
        )
    return int(seq), t_f, src, int(boot)  # type: ignore[call-overload]


def encode(
    schema: str, body: Mapping[str, Any], *, seq: int, t: float, src: str, boot: int = 0
) -> bytes:
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
        and 0 <= seq <= MAX_UINT
        and type(boot) is int
        and 0 <= boot <= MAX_UINT
        and type(t) is float
        and math.isfinite(t)
        and type(src) is str
        and src
    ):
        message = {
            "schema": schema,
            "version": compiled.version,
            "seq": seq,
            "t": t,
            "src": src,
            "boot": boot,
        }
    else:  # the field kinds name what is wrong, or normalise what the fast path refused
        spec = _lookup(schema)
        seq_i, t_f, src_s, boot_i = _check_header(schema, seq, t, src, boot)
        clean = check_body(schema, body)
        wire = {k: _to_wire(v) for k, v in clean.items()}
        message = {
            "schema": schema,
            "version": spec.version,
            "seq": seq_i,
            "t": t_f,
            "src": src_s,
            "boot": boot_i,
        }
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
        payload,
        "message",
        strict_map_key=True,
        max_str_len=size,
        max_bin_len=0,
        max_array_len=size,
        max_map_len=size,
    )
    if not isinstance(raw, dict):
        raise MessageError("malformed", f"expected a msgpack map, got {type_name(raw)}")
    keys = set(raw)
    if keys != set(HEADER_KEYS):
        missing = sorted(set(HEADER_KEYS) - keys)
        extra = sorted(str(k) for k in keys - set(HEADER_KEYS))
        raise MessageError("bad_header", f"header: missing {missing}, unexpected {extra}")
    name = raw["schema"]
    if not isinstance(name, str):
        raise MessageError("bad_header", f"header.schema: expected str, got {type_name(name)}")
    spec = _lookup(name)
    if expected is not None:
        allowed = {expected} if isinstance(expected, str) else set(expected)
        if name not in allowed:
            raise MessageError(
                "wrong_schema", f"expected schema {'|'.join(sorted(allowed))}, got {name!r}"
            )
    version = raw["version"]
    if not is_int(version):
        raise MessageError(
            "bad_header", f"{name} header.version: expected int, got {type_name(version)}"
        )
    if version != spec.version:
        raise MessageError("version", f"{name}: expected version {spec.version}, got {version}")
    seq, t, src, boot = _check_header(name, raw["seq"], raw["t"], raw["src"], raw["boot"])
    body = raw["body"]
    if not isinstance(body, dict):
        raise MessageError("bad_header", f"{name} header.body: expected map, got {type_name(body)}")
    return Message(name, version, seq, t, src, check_body(name, body), boot)


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
    seq: Annotated[int, msgspec.Meta(ge=0)]  # msgpack: < 2^64
    t: _Finite
    src: Annotated[str, msgspec.Meta(min_length=1)]
    boot: Annotated[int, msgspec.Meta(ge=0)]  # msgpack: < 2^64
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
                    *[  # seq, t, src and boot with the header's limits
                        (f.name, f.type)
                        for f in msgspec.structs.fields(_Header)
                        if f.name in ("seq", "t", "src", "boot")
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
        return Message(whole.schema, whole.version, whole.seq, whole.t, whole.src, body, whole.boot)
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
    return Message(head.schema, head.version, head.seq, head.t, head.src, body, head.boot)
