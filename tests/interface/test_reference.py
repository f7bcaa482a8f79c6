"""docs/interface.md is what ``python -m services.interface.reference`` generates from the
interface's tables, and every field of every message type is documented."""

from __future__ import annotations

from pathlib import Path

from services.interface import HEADER, HEADER_KEYS, SCHEMAS, TOPOLOGY
from services.interface.reference import COMMAND, DOCUMENT, main, render


def test_docs_interface_md_is_up_to_date() -> None:
    written = DOCUMENT.read_text(encoding="utf-8") if DOCUMENT.is_file() else ""
    assert written == render(), f"{DOCUMENT} is out of date; regenerate it with: {COMMAND}"


def test_every_field_has_a_unit_column_and_a_description() -> None:
    for spec in SCHEMAS.values():
        assert spec.doc, spec.name
        for name, field in spec.fields.items():
            assert field.doc, f"{spec.name}.{name}"
            assert "\n" not in field.doc and "\n" not in field.unit
    assert HEADER_KEYS == ("schema", "version", "seq", "t", "src", "boot", "body")
    assert all(h.doc for h in HEADER)


def test_the_reference_names_every_topic_field_and_key_layout() -> None:
    text = render()
    for route in TOPOLOGY:
        assert f"| `{route.topic}` |" in text
    for spec in SCHEMAS.values():
        assert f"### {spec.name}\n" in text
        for name in spec.fields:
            assert f"| `{name}` |" in text
    assert "ddvi/<run>/<topic>" in text and "ddvi/<run>/alive/<service>" in text


def test_check_mode(tmp_path: Path) -> None:
    out = tmp_path / "interface.md"
    assert main(["--check", "--out", str(out)]) == 1  # missing
    assert main(["--out", str(out)]) == 0
    assert main(["--check", "--out", str(out)]) == 0
    out.write_text("stale\n", encoding="utf-8")
    assert main(["--check", "--out", str(out)]) == 1
