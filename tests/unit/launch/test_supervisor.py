"""The launcher's supervisor (palpate.launch.supervisor), without starting node processes."""

from __future__ import annotations

from pathlib import Path

import pytest

from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch
from palpate.launch.supervisor import Supervisor
from palpate.paths import REPO_ROOT
from palpate.runtime import bus


def test_shutdown_removes_its_run_directory_even_when_cleaning_up_a_node_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    graph = resolve(load_launch(REPO_ROOT / "launch" / "demo_minimal.yaml"), bus_dir=tmp_path)
    supervisor = Supervisor(graph, graph.process_specs())
    assert supervisor.run_dir.is_dir()

    def refuse(endpoint: str) -> None:
        raise PermissionError(13, "refused", endpoint)

    monkeypatch.setattr(bus, "remove_ipc_file", refuse)
    with pytest.raises(PermissionError):
        supervisor.shutdown()
    assert not supervisor.run_dir.exists()
