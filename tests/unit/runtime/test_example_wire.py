"""The example drivers' socket layer (examples/drivers/wire.py, no palpate import): what its manifest says."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

from palpate.paths import REPO_ROOT


def _wire() -> Any:
    spec = importlib.util.spec_from_file_location("wire", REPO_ROOT / "examples" / "drivers" / "wire.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_drivers_manifest_names_what_it_reads_and_publishes(tmp_path: Path) -> None:
    wire = _wire()
    spec = {
        "name": "noise",
        "mode": "lockstep",
        "endpoint": f"ipc://{tmp_path}/noise.pub",
        "subscribes": {"contacts": "sensors/contacts"},
        "connect": [],
        "bus_dir": str(tmp_path),
        "topic_types": {"sensors/contacts": "ContactSet", "sensors/contacts_noisy": "ContactSet"},
    }
    node = wire.Node(spec, {"sensors/contacts_noisy": "ContactSet"})
    try:
        manifest = json.loads((tmp_path / "noise.json").read_text())
    finally:
        node.close()
    assert manifest["subscribes"] == {"sensors/contacts": "ContactSet"}  # palpate node list shows it
    assert manifest["publishes"] == {"sensors/contacts_noisy": "ContactSet"}
    assert not (tmp_path / "noise.json").exists()
