"""docs/nodes.md is generated from the node types and must match them."""

from __future__ import annotations

from pathlib import Path

from palpate.cli import main
from palpate.commands.node_reference import render_nodes
from palpate.config import describe
from palpate.launch.node_types import NODE_TYPES, load_node_type
from palpate.paths import REPO_ROOT

DOC = REPO_ROOT / "docs" / "nodes.md"


def test_committed_node_reference_is_up_to_date() -> None:
    assert DOC.read_text() == render_nodes(), "docs/nodes.md is stale: run `make docs`"


def section(name: str) -> str:
    """The part of docs/nodes.md (freshly rendered) about node type `name`."""
    return render_nodes().split(f"\n## {name}\n", 1)[1].split("\n## ", 1)[0]


def test_every_node_type_its_ports_and_parameters_are_documented() -> None:
    """An outside driver author (C) had to guess the noise node's parameters: a spec holds only those the
    launch file gives."""
    for name in NODE_TYPES:
        spec = load_node_type(name)
        text = section(name)
        assert spec.doc in text
        missing = [f.key for f in describe(spec.config) if f"| `{f.key}` |" not in text]
        assert not missing, (name, missing)
    expected = {
        "noise": [
            "| `sigma_deg` | float (>= 0 and <= 90) | `1.5` |",
            "| `per_joint_sigma_deg` | mapping of str to float | `{}` |",
            "| `joint_states` | [JointState](messages.md#jointstate) | `sensors/joint_states` |",
        ],
        # a description from the config's docstring, a nested key dotted
        "gpis": ["| `gp.R_m` | float (> 0) | `0.5` | thin-plate R; must be >= every contact-contact"],
    }
    for name, rows in expected.items():
        assert all(row in section(name) for row in rows), name


def test_cli_writes_and_checks_the_file(tmp_path: Path) -> None:
    out = tmp_path / "nodes.md"
    assert main(["docs", "nodes", "-o", str(out), "--check"]) == 1  # missing: out of date
    assert main(["docs", "nodes", "-o", str(out)]) == 0
    assert main(["docs", "nodes", "-o", str(out), "--check"]) == 0
