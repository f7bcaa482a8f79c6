"""services.interface.codec: round trips, every MessageError reason, plain-msgpack readability,
fuzzing."""

from __future__ import annotations

import contextlib
import math
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import services.interface.codec as codec_module
from services.interface import (
    MAX_PAYLOAD,
    REASONS,
    SCHEMAS,
    Array,
    Message,
    MessageError,
    decode,
    encode,
)

SAMPLES: dict[str, dict[str, Any]] = {
    "clock": {"step": 7, "dt": 60.0, "fsw": True, "mode": "lockstep", "final": False},
    "truth": {
        "sc": "deputy1",
        "r_N": np.array([6678136.0, 1.5, -2.0]),
        "v_N": [0.0, 7725.8, 0.1],
        "sigma_BN": np.zeros(3),
    },
    "exo": {"v": np.arange(5.0), "phase": 0.3},
    "nav": {
        "sc": "deputy1",
        "x_hill": np.linspace(-1, 1, 6),
        "z_hill": np.linspace(-1.1, 1.1, 6),
        "cov": np.eye(6),
        "altitude": 300e3,
        "valid": True,
    },
    "cmd": {"sc": "deputy1", "sigma": [0.0, 0.0, 0.15], "for_t": 120.0},
    "gains": {
        "sc": "deputy1",
        "K": np.arange(4.0).reshape(1, 4),
        "L": np.ones((1, 5)),
        "source": "ddvi",
        "iteration": 20000,
        "converged": True,
    },
    "status": {
        "sc": "deputy1",
        "mode": "ddvi",
        "phase": "learning",
        "samples": 120,
        "intervals": 40,
        "rank": 30,
        "rank_needed": 34,
        "counters": {"late_cmd": 0, "resets": 2},
    },
    "fault": {
        "kind": "panel_stuck",
        "target": "deputy1",
        "params": {"sigma": 0.1, "step": 3, "axis": "z", "on": True},
    },
    "stats": {"service": "nav-deputy1", "counters": {"sent": 10, "rejected.malformed": 1}},
    "log": {"service": "controller-deputy1", "level": "info", "text": "switched to ddvi gains"},
    "recorded": {"messages": 1234},
}


def raw(body: Any = None, **header: Any) -> bytes:
    """A hand-made payload: a valid nav message, with header keys overridden."""
    msg = {
        "schema": "nav",
        "version": SCHEMAS.get(header.get("schema"), SCHEMAS["nav"]).version,
        "seq": 0,
        "t": 0.0,
        "src": "test",
        "boot": 0,
        "body": {
            "sc": "d1",
            "x_hill": [0.0] * 6,
            "z_hill": [0.0] * 6,
            "cov": [[0.0] * 6] * 6,
            "altitude": 300e3,
            "valid": True,
        }
        if body is None
        else body,
    }
    msg.update(header)
    return msgpack.packb({k: v for k, v in msg.items() if v is not ...})


def reason_of(payload: bytes, expected: Any = None) -> str:
    with pytest.raises(MessageError) as info:
        decode(payload, expected)
    return info.value.reason


def test_samples_cover_every_schema() -> None:
    assert set(SAMPLES) == set(SCHEMAS)


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_round_trip(name: str) -> None:
    body = SAMPLES[name]
    payload = encode(name, body, seq=5, t=1234.5, src="svc")
    msg = decode(payload, name)
    assert isinstance(msg, Message)
    assert (msg.schema, msg.version, msg.seq, msg.t, msg.src) == (
        name,
        SCHEMAS[name].version,
        5,
        1234.5,
        "svc",
    )
    assert set(msg.body) == set(body)
    for key, field in SCHEMAS[name].fields.items():
        if isinstance(field, Array):
            assert isinstance(msg.body[key], np.ndarray)
            assert msg.body[key].dtype == np.float64
            np.testing.assert_array_equal(msg.body[key], np.asarray(body[key], dtype=float))
        else:
            assert msg.body[key] == body[key]


def _plain(value: Any) -> bool:
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    return type(value) in (int, float, str, bool)


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_plain_msgpack_reads_every_message(name: str) -> None:
    payload = encode(name, SAMPLES[name], seq=1, t=2.0, src="svc")
    msg = msgpack.unpackb(payload)  # no options, no ext hook
    assert set(msg) == {"schema", "version", "seq", "t", "src", "boot", "body"}
    assert msg["schema"] == name
    assert _plain(msg)


def test_arrays_travel_as_lists_of_floats() -> None:
    payload = encode("gains", SAMPLES["gains"], seq=0, t=0.0, src="c")
    body = msgpack.unpackb(payload)["body"]
    assert body["K"] == [[0.0, 1.0, 2.0, 3.0]]
    assert all(type(x) is float for x in body["K"][0])


def test_decode_accepts_expected_collection() -> None:
    payload = encode("cmd", SAMPLES["cmd"], seq=0, t=0.0, src="c")
    assert decode(payload, ["nav", "cmd"]).schema == "cmd"
    assert decode(payload, None).schema == "cmd"


# --- every reason ---------------------------------------------------------------------------


def test_oversized() -> None:
    assert reason_of(b"\x80" + b"\x00" * MAX_PAYLOAD) == "oversized"
    with pytest.raises(MessageError) as info:
        encode("exo", {"v": np.zeros(10_000), "phase": 0.0}, seq=0, t=0.0, src="e")
    assert info.value.reason == "oversized"


def test_malformed() -> None:
    good = encode("nav", SAMPLES["nav"], seq=0, t=0.0, src="n")
    assert reason_of(good[:-3]) == "malformed"  # truncated
    assert reason_of(b"\xc1\xc1garbage") == "malformed"  # 0xc1 is never valid msgpack
    assert reason_of(b"") == "malformed"
    assert reason_of(good + b"\x00") == "malformed"  # trailing bytes
    assert reason_of(msgpack.packb([1, 2, 3])) == "malformed"  # not a map
    assert reason_of(msgpack.packb({1: 2})) == "malformed"  # non-string key
    assert reason_of(msgpack.packb({"a": msgpack.ExtType(1, b"x")})) == "malformed"
    assert reason_of(msgpack.packb({"a": b"bytes"}, use_bin_type=True)) == "malformed"


def test_bad_header() -> None:
    assert reason_of(raw(seq=...)) == "bad_header"  # missing
    assert reason_of(raw(extra=1)) == "bad_header"
    assert reason_of(raw(seq=-1)) == "bad_header"
    assert reason_of(raw(seq=1.5)) == "bad_header"
    assert reason_of(raw(t="now")) == "bad_header"
    assert reason_of(raw(src="")) == "bad_header"
    assert reason_of(raw(schema=3)) == "bad_header"
    assert reason_of(raw(version="1")) == "bad_header"
    assert reason_of(raw(body=[1, 2])) == "bad_header"
    with pytest.raises(MessageError) as info:
        encode("nav", SAMPLES["nav"], seq=-1, t=0.0, src="n")
    assert info.value.reason == "bad_header"


def test_unknown_and_wrong_schema_and_version() -> None:
    assert reason_of(raw(schema="navx")) == "unknown_schema"
    with pytest.raises(MessageError) as info:
        encode("navx", {}, seq=0, t=0.0, src="n")
    assert info.value.reason == "unknown_schema"
    assert reason_of(raw(), expected="cmd") == "wrong_schema"
    assert reason_of(raw(), expected=["cmd", "truth"]) == "wrong_schema"
    assert reason_of(raw(version=SCHEMAS["nav"].version + 1)) == "version"


def nav(**fields: Any) -> dict[str, Any]:
    """A nav body with fields replaced (a value of ... removes the field)."""
    body = {
        "sc": "d",
        "x_hill": [0.0] * 6,
        "z_hill": [0.0] * 6,
        "cov": [[0.0] * 6] * 6,
        "altitude": 300e3,
        "valid": True,
        **fields,
    }
    return {k: v for k, v in body.items() if v is not ...}


X6 = "nav.x_hill: expected 6 finite floats, got"


@pytest.mark.parametrize(
    ("body", "text"),
    [
        (nav(x_hill=[0.0] * 5), f"{X6} 5"),
        (nav(x_hill=[[0.0] * 6]), f"{X6} shape (1, 6)"),
        (nav(x_hill=["a"] * 6), f"{X6} elements of type"),
        (nav(x_hill=[0.0, [1.0]] * 3), f"{X6} a ragged"),
        (nav(x_hill=3.0), f"{X6} float"),
        (nav(x_hil=1), "nav.x_hil: unknown field (did you mean 'x_hill'?)"),
        (nav(valid=...), "nav.valid: missing field"),
        (nav(valid="yes"), "nav.valid: expected bool, got str"),
        (nav(sc=1), "nav.sc: expected str, got int"),
    ],
)
def test_bad_field(body: dict[str, Any], text: str) -> None:
    with pytest.raises(MessageError) as info:
        decode(raw(body))
    assert info.value.reason == "bad_field"
    assert str(info.value).startswith(text)
    with pytest.raises(MessageError) as info:
        encode("nav", body, seq=0, t=0.0, src="n")
    assert info.value.reason == "bad_field"


def test_bad_field_other_kinds() -> None:
    clock = dict(SAMPLES["clock"], mode="turbo")
    with pytest.raises(MessageError, match=r"clock.mode: expected one of lockstep\|realtime"):
        encode("clock", clock, seq=0, t=0.0, src="e")
    with pytest.raises(MessageError, match=r"clock.step: expected int, got bool"):
        encode("clock", dict(SAMPLES["clock"], step=True), seq=0, t=0.0, src="e")
    with pytest.raises(MessageError, match=r"stats.counters\['x'\]: expected int, got float"):
        encode("stats", {"service": "s", "counters": {"x": 1.5}}, seq=0, t=0.0, src="e")
    with pytest.raises(MessageError, match=r"fault.params\['a'\]: expected float\|int\|str\|bool"):
        encode("fault", {"kind": "k", "target": "t", "params": {"a": [1]}}, seq=0, t=0.0, src="e")
    with pytest.raises(MessageError, match=r"gains.K: expected a NxN nested list"):
        encode("gains", dict(SAMPLES["gains"], K=[1.0, 2.0]), seq=0, t=0.0, src="c")


def test_non_finite() -> None:
    nan_nav = nav(x_hill=[0.0, 0.0, math.nan, 0.0, 0.0, 0.0])
    with pytest.raises(MessageError) as info:
        decode(raw(nan_nav))
    assert info.value.reason == "non_finite"
    assert str(info.value) == "nav.x_hill: expected 6 finite floats, got nan at index 2"
    with pytest.raises(MessageError) as info:
        encode("nav", dict(nan_nav, x_hill=np.array(nan_nav["x_hill"])), seq=0, t=0.0, src="n")
    assert info.value.reason == "non_finite"
    assert reason_of(raw(t=math.inf)) == "non_finite"
    inf_cmd = {"sc": "d", "sigma": [0.0] * 3, "for_t": -math.inf}
    assert reason_of(raw(inf_cmd, schema="cmd")) == "non_finite"
    nan_param = {"kind": "k", "target": "t", "params": {"bias": math.nan}}
    assert reason_of(raw(nan_param, schema="fault")) == "non_finite"


def test_reasons_are_the_documented_set() -> None:
    assert {
        "oversized",
        "malformed",
        "bad_header",
        "unknown_schema",
        "wrong_schema",
        "version",
        "bad_field",
        "non_finite",
    } == REASONS


# --- fuzzing --------------------------------------------------------------------------------


def _decode_is_total(payload: bytes) -> None:
    try:
        msg = decode(payload)
    except MessageError as err:
        assert err.reason in REASONS
    else:
        assert isinstance(msg, Message) and msg.schema in SCHEMAS


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=512))
def test_decode_arbitrary_bytes(payload: bytes) -> None:
    _decode_is_total(payload)


_scalars = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8)
)
_values = st.recursive(
    _scalars,
    lambda inner: (
        st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=6), inner, max_size=6)
    ),
    max_leaves=20,
)


@st.composite
def _messages(draw: st.DrawFn) -> bytes:
    """Maps near the real format: a real schema and header, each part possibly perturbed."""
    name = draw(st.sampled_from(sorted(SCHEMAS)))
    body: dict[str, Any] = {}
    for key, value in SAMPLES[name].items():
        body[key] = value.tolist() if isinstance(value, np.ndarray) else value
    for key in draw(st.lists(st.sampled_from(sorted(body)), max_size=3)):
        body[key] = draw(_values)
    if draw(st.booleans()):
        body[draw(st.text(max_size=6))] = draw(_values)
    msg: dict[str, Any] = {
        "schema": name,
        "version": SCHEMAS[name].version,
        "seq": 0,
        "t": 0.0,
        "src": "s",
        "boot": 0,
        "body": body,
    }
    for key in draw(st.lists(st.sampled_from(sorted(msg)), max_size=2)):
        msg[key] = draw(_values)
    return msgpack.packb(msg)


@pytest.mark.integration  # hundreds of generated payloads
@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.text(max_size=8), _values, max_size=8))
def test_decode_arbitrary_maps(value: dict[str, Any]) -> None:
    _decode_is_total(msgpack.packb(value))


@pytest.mark.integration  # hundreds of generated payloads
@settings(max_examples=300, deadline=None)
@given(_messages())
def test_decode_perturbed_messages(payload: bytes) -> None:
    _decode_is_total(payload)


# --- the compiled validators agree with the field kinds ------------------------------------


def _same_message(a: Message, b: Message) -> bool:
    if (a.schema, a.version, a.seq, a.t, a.src) != (b.schema, b.version, b.seq, b.t, b.src):
        return False
    if set(a.body) != set(b.body):
        return False
    for key, value in a.body.items():
        other = b.body[key]
        if isinstance(value, np.ndarray) or isinstance(other, np.ndarray):
            if not (
                isinstance(value, np.ndarray)
                and isinstance(other, np.ndarray)
                and value.dtype == other.dtype == np.float64
                and value.shape == other.shape
                and np.array_equal(value, other)
            ):
                return False
        elif value != other or type(value) is not type(other):
            return False
    return True


def _by_field_kinds(call: Any) -> Any:
    """``call()`` with the compiled validators switched off: what the field kinds say."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(codec_module, "_fast_decode", lambda *_: None)
        mp.setattr(codec_module, "_COMPILED", {})
        try:
            return call()
        except MessageError as err:
            return err.reason


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_compiled_validators_take_every_sample(name: str) -> None:
    """A plain, valid message never needs the slow path, either way."""
    payload = encode(name, SAMPLES[name], seq=1, t=2.0, src="svc")
    fast = codec_module._fast_decode(payload, name)
    assert fast is not None
    assert _same_message(fast, _by_field_kinds(lambda: decode(payload, name)))
    plain = {
        k: np.asarray(v, dtype=float) if isinstance(v, list) else v
        for k, v in SAMPLES[name].items()
    }
    assert codec_module._COMPILED[name].wire(plain) is not None
    assert encode(name, plain, seq=1, t=2.0, src="svc") == _by_field_kinds(
        lambda: encode(name, plain, seq=1, t=2.0, src="svc")
    )


def _assert_decode_agrees(payload: bytes, expected: Any) -> None:
    """What the compiled types accept, the field kinds accept as the same message; what they
    refuse, ``decode`` refuses with the field kinds' reason."""
    reference = _by_field_kinds(lambda: decode(payload, expected))
    fast = codec_module._fast_decode(payload, expected)
    if fast is not None:
        assert isinstance(reference, Message) and _same_message(fast, reference)
    try:
        got = decode(payload, expected)
    except MessageError as err:
        assert err.reason == reference
    else:
        assert isinstance(reference, Message) and _same_message(got, reference)


@pytest.mark.integration  # hundreds of generated payloads
@settings(max_examples=400, deadline=None)
@given(_messages(), st.sampled_from([None, "nav", ("truth", "exo")]))
def test_compiled_decode_agrees_with_field_kinds(payload: bytes, expected: Any) -> None:
    """Whatever the compiled types accept, the field kinds accept as the same message; what
    they refuse, the field kinds decide (and name)."""
    _assert_decode_agrees(payload, expected)


def _edges() -> list[tuple[str, dict[str, Any]]]:
    """Each schema's sample as it goes on the wire, and near misses of it: a header key more
    or less, a header value out of its range, another version or schema name, and (for array
    fields) empty, ragged, nested and flat lists."""
    cases = []
    for name in sorted(SCHEMAS):
        body = {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in SAMPLES[name].items()}
        version = SCHEMAS[name].version
        msg = {"schema": name, "version": version, "seq": 0, "t": 0.0, "src": "s", "boot": 7}
        msg["body"] = body
        cases += [(name, msg), (name, {**msg, "extra": 1}), (name, {**msg, "version": version + 1})]
        cases += [(name, {k: v for k, v in msg.items() if k != "src"})]
        cases += [(name, {k: v for k, v in msg.items() if k != "boot"})]
        bad_values = [("seq", -1), ("seq", 2.0), ("t", math.nan), ("t", -math.inf), ("t", 3)]
        bad_values += [("src", ""), ("src", 5), ("boot", -1), ("boot", "b")]
        for key, value in bad_values:
            cases.append((name, {**msg, key: value}))
        cases += [(name, {**msg, "schema": "clock" if name != "clock" else "exo"})]
        for key, field in SCHEMAS[name].fields.items():
            if isinstance(field, Array):
                for value in ([], [[]], [[], []], [[1.0], []], [[1.0, 2.0]], [1.0], [[[1.0]]]):
                    cases.append((name, {**msg, "body": {**body, key: value}}))
    return cases


@pytest.mark.parametrize("expected, msg", _edges())
def test_one_pass_decode_agrees_with_field_kinds(expected: str, msg: dict[str, Any]) -> None:
    """A receiver that expects one schema decodes header and body in one pass: whatever that
    accepts, the field kinds accept as the same message; what it refuses, they name."""
    payload = msgpack.packb(msg)
    _assert_decode_agrees(payload, expected)


@pytest.mark.integration  # hundreds of generated payloads
@settings(max_examples=300, deadline=None)
@given(_messages())
def test_compiled_encode_agrees_with_field_kinds(payload: bytes) -> None:
    """encode gives the same bytes, or the same refusal, with or without the compiled types."""
    msg = msgpack.unpackb(payload, strict_map_key=False)
    name, body = msg.get("schema"), msg.get("body")
    if not isinstance(body, dict) or not isinstance(name, str) or name not in SCHEMAS:
        return
    for key, value in body.items():  # arrays as a service holds them, where they are arrays
        if isinstance(SCHEMAS[name].fields.get(key), Array) and isinstance(value, list):
            with contextlib.suppress(ValueError, TypeError):
                body[key] = np.asarray(value, dtype=float)
    reference = _by_field_kinds(lambda: encode(name, body, seq=3, t=4.0, src="svc"))
    try:
        got = encode(name, body, seq=3, t=4.0, src="svc")
    except MessageError as err:
        assert err.reason == reference
    else:
        assert got == reference


_NUMPY_VALUES = [
    np.zeros(6, dtype=object),
    np.arange(6).astype("m8[ns]"),
    np.arange(6),
    np.zeros(6, dtype=np.float32),
    np.zeros(6, dtype=">f8"),
    np.zeros(6, dtype=bool),
    np.zeros((6, 1)),
    np.zeros(12)[::2],
    np.array(5.0),
    np.float32(5.0),
    5,
    True,
]


@pytest.mark.parametrize("value", _NUMPY_VALUES, ids=repr)
@pytest.mark.parametrize("field", ["x_hill", "altitude"])
def test_compiled_encode_agrees_on_numpy_values(field: str, value: Any) -> None:
    """Arrays and scalars of every dtype and shape a service might hold, in an array field
    and in a float one: the same bytes, or the same refusal, with or without the compiled
    types."""
    body = {**SAMPLES["nav"], field: value}
    reference = _by_field_kinds(lambda: encode("nav", body, seq=1, t=2.0, src="svc"))
    try:
        got = encode("nav", body, seq=1, t=2.0, src="svc")
    except MessageError as err:
        assert err.reason == reference
    else:
        assert got == reference


def test_compiled_encode_takes_numpy_scalars() -> None:
    body = {
        "sc": np.str_("deputy1"),
        "x_hill": np.zeros(6),
        "z_hill": np.zeros(6),
        "cov": np.zeros((6, 6)),
        "altitude": np.float64(3e5),
        "valid": np.bool_(True),
    }
    assert codec_module._COMPILED["nav"].wire(body) is not None
    payload = encode("nav", body, seq=1, t=2.0, src="svc")
    assert payload == _by_field_kinds(lambda: encode("nav", body, seq=1, t=2.0, src="svc"))
    assert (
        _by_field_kinds(
            lambda: encode(
                "clock", {**SAMPLES["clock"], "step": np.bool_(True)}, seq=1, t=2.0, src="svc"
            )
        )
        == "bad_field"
    )
    with pytest.raises(MessageError, match=r"clock\.step: expected int, got bool"):
        encode("clock", {**SAMPLES["clock"], "step": np.bool_(True)}, seq=1, t=2.0, src="svc")
