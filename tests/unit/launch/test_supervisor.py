"""The launcher's supervisor (palpate.launch.supervisor), without starting node processes."""

from __future__ import annotations

import io
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


def external_stats(tmp_path: Path) -> tuple[Supervisor, io.StringIO]:
    """A supervisor of demo_minimal.yaml with its node 'stats' external (a driver's), on the bus directory
    ``tmp_path``, and what it says."""
    from palpate.launch.loader import with_external

    launch = with_external(load_launch(REPO_ROOT / "launch" / "demo_minimal.yaml"), ["stats"])
    graph = resolve(launch, bus_dir=tmp_path)
    out = io.StringIO()
    return Supervisor(graph, graph.process_specs(), out=out), out


def test_an_external_node_without_a_manifest_is_named_once_after_a_while(tmp_path: Path) -> None:
    """An outside driver in C that wrote no manifest: a recorded launch then waited, and the log blamed the
    driver's acknowledgements; the launch names the missing file."""
    supervisor, out = external_stats(tmp_path)
    try:
        supervisor.started_at = 100.0
        supervisor._note_missing_manifests(105.0)  # too early to say
        assert out.getvalue() == ""
        supervisor._note_missing_manifests(111.0)
        supervisor._note_missing_manifests(120.0)  # once
        assert out.getvalue() == (
            f"[launch] external node 'stats' has written no manifest {tmp_path / 'stats.json'} after 10 s: its driver "
            "has not started, or writes none (docs/runtime.md, External nodes, 3. Manifest); the recorder and "
            "palpate topic find a node's topics there\n"
        )
    finally:
        supervisor.shutdown()


def test_a_manifest_that_came_and_went_before_the_note_is_not_called_missing(tmp_path: Path) -> None:
    """An outside walkthrough: a driver of a short run wrote its manifest, removed it at its clean exit, and
    the launch then said it had written none."""
    supervisor, out = external_stats(tmp_path)
    try:
        supervisor.started_at = 100.0
        manifest = tmp_path / "stats.json"
        manifest.write_text("{}")
        supervisor._note_missing_manifests(103.0)
        manifest.unlink()  # the driver's clean exit
        supervisor._note_missing_manifests(111.0)
        assert out.getvalue() == ""
    finally:
        supervisor.shutdown()


def test_a_second_driver_of_an_external_node_is_named(tmp_path: Path) -> None:
    """An outside driver in C, started twice: the second took the endpoint and the manifest over without a
    word (`palpate topic hz` then counted 0 messages while the run went on)."""
    import os
    import subprocess
    import sys

    supervisor, out = external_stats(tmp_path)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a driver that died left its manifest (a review: it masked the second driver)
    try:
        for pid in (gone.pid, os.getpid(), os.getpid(), other.pid, other.pid):
            bus.Manifest("stats", "ipc://x", pid, {}, {}).write(tmp_path)
            supervisor._note_second_drivers()
        assert out.getvalue() == (
            f"[launch] two drivers play external node 'stats' (pids {os.getpid()} and {other.pid}, both alive): the "
            "second took its endpoint and manifest over; stop one\n"
        )
    finally:
        other.kill()
        other.wait()
        supervisor.shutdown()
