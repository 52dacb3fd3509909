"""docs/messages.md is generated from the schemas and must match them."""

from __future__ import annotations

from pathlib import Path

from palpate.cli import main
from palpate.commands.docs import documented_types, render_messages
from palpate.messages import REGISTRY
from palpate.paths import REPO_ROOT

DOC = REPO_ROOT / "docs" / "messages.md"


def test_committed_message_reference_is_up_to_date() -> None:
    assert DOC.read_text() == render_messages(), "docs/messages.md is stale: run `make docs`"


def test_reference_documents_every_type_field_unit_and_version() -> None:
    text = render_messages()
    assert {cls.TYPE for cls in documented_types()} == set(REGISTRY)
    for cls in documented_types():
        section = text.split(f"### {cls.TYPE}\n", 1)[1].split("\n### ", 1)[0]
        assert f"- version: {cls.VERSION}" in section
        assert f"- default topic: `{cls.TOPIC}`" in section
        for name, spec in cls.field_specs().items():
            row = next(line for line in section.splitlines() if line.startswith(f"| `{name}` |"))
            assert spec.doc in row and (spec.unit or "-") in row
            if spec.dtype is not None:
                assert f"`{spec.dtype}`" in row
    contacts = text.split("### ContactSet\n", 1)[1].split("\n### ", 1)[0]
    assert "| `positions_m` | array | `<f8` (float64) | (n, 3) | m | yes |" in contacts
    assert "`n` = length of `positions_m`, `local_positions_m`, `normals`, `forces_n`, `links`" in contacts
    event = text.split("### TouchEvent\n", 1)[1].split("\n### ", 1)[0]
    assert "| `predicted_contact_m` | array | `<f8` (float64) | (3,) | m | no (NaN allowed) |" in event


def test_cli_writes_and_checks_the_file(tmp_path: Path) -> None:
    out = tmp_path / "messages.md"
    assert main(["docs", "messages", "-o", str(out), "--check"]) == 1  # missing: out of date
    assert main(["docs", "messages", "-o", str(out)]) == 0
    assert out.read_text() == render_messages()
    assert main(["docs", "messages", "-o", str(out), "--check"]) == 0
    out.write_text(out.read_text().replace("version: 1", "version: 7", 1))
    assert main(["docs", "messages", "-o", str(out), "--check"]) == 1
