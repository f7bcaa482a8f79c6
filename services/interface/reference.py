"""The interface reference, ``docs/interface.md``, generated from the tables of this package.

    python -m services.interface.reference            write docs/interface.md
    python -m services.interface.reference --check    exit 1 if it differs from the tables

``render()`` returns the document: the key layout, the participants (``SERVICES``), every topic
with its schema, publishers, subscribers and rate (``TOPOLOGY``), the header (``HEADER``) and
every message type's fields with type, shape, unit and description (``SCHEMAS``).  The output
depends on nothing but these tables, so a test can hold the file to them.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

from services.interface.codec import MAX_BATCH, MAX_PAYLOAD
from services.interface.fields import Array, Bool, Field, Float, Int, IntMap, ScalarMap, Str
from services.interface.messages import HEADER, SCHEMAS, Schema
from services.interface.topics import SERVICES, TOPOLOGY

DOCUMENT = Path(__file__).resolve().parents[2] / "docs" / "interface.md"
"""Where the reference lives in the repository."""

COMMAND = "python -m services.interface.reference"
"""The command that writes it."""


def _table(head: Sequence[str], rows: Iterable[Sequence[str]]) -> list[str]:
    """A Markdown table; ``|`` in a cell is escaped."""
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for row in rows:
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in row) + " |")
    return lines


def _code(names: Iterable[str]) -> str:
    return ", ".join(f"`{n}`" for n in names)


def _unit(unit: str) -> str:
    return unit or "-"


def field_type(field: Field) -> str:
    """What a field holds on the wire, in words: ``float``, ``str: a, b``, ``map str -> int``."""
    if isinstance(field, Int):
        return "int"
    if isinstance(field, Float):
        return "float (finite)"
    if isinstance(field, Bool):
        return "bool"
    if isinstance(field, Str):
        return "str" if field.choices is None else "str: " + ", ".join(field.choices)
    if isinstance(field, Array):
        return "float array (finite)"
    if isinstance(field, IntMap):
        return "map str -> int"
    assert isinstance(field, ScalarMap)
    return "map str -> float, int, str or bool"


def field_shape(field: Field) -> str:
    """An array field's shape, ``N`` for any length (``(3,)``, ``(N, N)``); ``-`` otherwise."""
    if not isinstance(field, Array):
        return "-"
    dims = ["N" if d is None else str(d) for d in field.shape]
    return f"({dims[0]},)" if len(dims) == 1 else "(" + ", ".join(dims) + ")"


def _keys_section() -> list[str]:
    return [
        "## Keys",
        "",
        "Every message of run `<run>` is published on the zenoh key `ddvi/<run>/<topic>`; the "
        "topics are below.",
        "A service that is up holds the liveliness token `ddvi/<run>/alive/<service>` (no "
        "payload): the services and the ground watch these tokens to know who is up.",
        "",
        "A payload is one message (a msgpack map: the header below, with the body in `body`), "
        f"or a batch: a msgpack array of 1 to {MAX_BATCH} messages of one topic, each a msgpack "
        f"byte string, in publication order. A payload is at most {MAX_PAYLOAD} bytes.",
        "",
    ]


def _services_section() -> list[str]:
    rows = [(f"`{s.name}`", f"`{s.module}`", s.doc) for s in SERVICES]
    return [
        "## Participants",
        "",
        "`<sc>` is a deputy's name, `<craft>` the chief or a deputy, `<service>` the publishing "
        "service's own name, `<pid>` a process id.",
        "",
        *_table(("name", "module", "job"), rows),
        "",
    ]


def _identity(pairs: tuple[tuple[str, str], ...]) -> str:
    """A route's identity fields: ``sc = <sc>``, or - for a body that names nobody."""
    return ", ".join(f"`{field} = <{name}>`" for field, name in pairs) or "-"


def _topics_section() -> list[str]:
    rows = [
        (
            f"`{r.topic}`",
            f"[`{r.schema}`](#{r.schema})",
            _code(r.publishers),
            _code(r.subscribers),
            _identity(r.identity),
            r.rate,
        )
        for r in TOPOLOGY
    ]
    return [
        "## Topics",
        "",
        "Below `ddvi/<run>/`. The monitor subscribes to every key of the run (`ddvi/<run>/**`) "
        "and records what it receives. Every receiver, the monitor included, refuses a message "
        "whose `src` is not one of its topic's publishers, or whose body's identity field is not "
        'what its topic names (a command on `cmd/lqr/att` naming `sc = "ddvi"`), before it '
        "touches any state; it counts the refusal (`rejected.src`, `rejected.identity`).",
        "",
        *_table(("topic", "schema", "publishers", "subscribers", "body names", "rate"), rows),
        "",
    ]


def _header_section() -> list[str]:
    rows = [(f"`{h.name}`", h.type, _unit(h.unit), h.doc) for h in HEADER]
    return [
        "## Header",
        "",
        "Every message is a msgpack map of exactly these keys.",
        "",
        *_table(("key", "type", "unit", "description"), rows),
        "",
    ]


def _schema_section(spec: Schema) -> list[str]:
    rows = [
        (f"`{name}`", field_type(f), field_shape(f), _unit(f.unit), f.doc)
        for name, f in spec.fields.items()
    ]
    return [
        f"### {spec.name}",
        "",
        f"Version {spec.version}: {spec.doc}.",
        "",
        *_table(("field", "type", "shape", "unit", "description"), rows),
        "",
    ]


def render() -> str:
    """The whole reference, as Markdown."""
    lines = [
        "# The interface",
        "",
        f"Generated by `{COMMAND}` from `services/interface/`; do not edit by hand.",
        "",
        *_keys_section(),
        *_services_section(),
        *_topics_section(),
        *_header_section(),
        "## Message types",
        "",
        "Units: SI; `1` is a pure number, `count` a number of things, `-` a name, flag or text. "
        "Every field is required and no other is accepted.",
        "",
    ]
    for spec in SCHEMAS.values():
        lines += _schema_section(spec)
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="services.interface.reference", description=__doc__)
    ap.add_argument("--out", type=Path, default=DOCUMENT, help="where to write it")
    ap.add_argument("--check", action="store_true", help="compare instead of writing")
    args = ap.parse_args(argv)
    text = render()
    if args.check:
        same = args.out.is_file() and args.out.read_text(encoding="utf-8") == text
        if not same:
            print(f"{args.out} is out of date; run: {COMMAND}", file=sys.stderr)
        return 0 if same else 1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text, encoding="utf-8")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
