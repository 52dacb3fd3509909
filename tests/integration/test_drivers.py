"""The example drivers in examples/drivers (pyzmq, msgpack and numpy only, written from docs/runtime.md and
docs/messages.md) replace a node of a shipped graph: the noise node of the exploration graph in lockstep,
where the run must come out exactly as with palpate's own node, and the contact source of the minimal
graph in real-time mode, as a clock source."""

from __future__ import annotations

import ast
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from palpate import jsonio
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch, parse_cli_args
from palpate.paths import LAUNCH_DIR, REPO_ROOT
from palpate.runtime.inprocess import InProcessGraph
from tests.integration.launch_helpers import kill_session, launched, node_pids, text, wait_for

DRIVERS = REPO_ROOT / "examples" / "drivers"
ALLOWED_IMPORTS = {"zmq", "msgpack", "numpy", "wire"}


def start_driver(script: str, bus_dir: Path, node: str, log: Path) -> subprocess.Popen[bytes]:
    """The driver in its own interpreter, with every palpate import made to fail."""
    code = (
        f"import runpy, sys; sys.modules['palpate'] = None; sys.path.insert(0, {str(DRIVERS)!r}); "
        f"sys.argv = [{script!r}, {str(bus_dir)!r}, {node!r}]; "
        f"runpy.run_path({str(DRIVERS / script)!r}, run_name='__main__')"
    )
    with log.open("wb") as out:
        return subprocess.Popen(
            [sys.executable, "-c", code], stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )


def test_drivers_import_only_pyzmq_msgpack_numpy_and_the_standard_library() -> None:
    scripts = sorted(DRIVERS.glob("*.py"))
    assert {p.name for p in scripts} >= {"wire.py", "noise_driver.py", "contacts_driver.py"}
    for path in scripts:
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                top = name.split(".")[0]
                assert top in ALLOWED_IMPORTS or top in sys.stdlib_module_names, f"{path.name} imports {name}"


def test_lockstep_driver_replaces_the_noise_node_of_the_exploration_graph(tmp_path: Path) -> None:
    bus_dir, results = tmp_path / "bus", tmp_path / "results.json"
    args = ["duration_s:=3", f"results:={results}", "--external", "noise"]  # the shipped file, unchanged
    with launched(LAUNCH_DIR / "explore.yaml", bus_dir, tmp_path / "launch.log", *args) as proc:
        driver = start_driver("noise_driver.py", bus_dir, "noise", tmp_path / "driver.log")
        try:
            assert proc.wait(timeout=240) == 0, text(tmp_path / "launch.log")
            assert driver.wait(timeout=60) == 0, text(tmp_path / "driver.log")
        finally:
            kill_session(driver)
    assert "[noise] stopped after 301 ticks" in text(tmp_path / "driver.log")
    assert f"[launch] waiting for external node 'noise': start its driver, which reads {bus_dir}" in text(
        tmp_path / "launch.log"
    )
    assert not (bus_dir / "external" / "noise.json").exists()  # the launcher removes what it wrote
    # the same graph with palpate's own noise node (sigma 0 passes contacts through, as the driver does)
    graph = resolve(load_launch(LAUNCH_DIR / "explore.yaml", parse_cli_args(["duration_s:=3", "results:="])))
    members = InProcessGraph(graph.in_process_members())
    members.run()
    own = members.node("eval").result
    theirs = json.loads(results.read_text())
    assert theirs["contacts"] == own["contacts"] >= 3
    assert theirs["touches"] == jsonio.strict(own["touches"])  # every touch, to the last bit


def test_lockstep_driver_leaves_when_the_clock_source_dies(tmp_path: Path) -> None:
    """A follower whose clock source vanished without a stop ends as a failed run (docs/runtime.md,
    External nodes, 9. Errors) instead of waiting for ticks that never come."""
    bus_dir = tmp_path / "bus"
    args = ["duration_s:=60", "--external", "noise"]
    with launched(LAUNCH_DIR / "explore.yaml", bus_dir, tmp_path / "launch.log", *args) as proc:
        driver = start_driver("noise_driver.py", bus_dir, "noise", tmp_path / "driver.log")
        try:
            driver_log = tmp_path / "driver.log"
            wait_for(lambda: "acknowledged tick -1" in text(driver_log), 120, "the driver", driver_log)
            wait_for(lambda: "sim" in node_pids(bus_dir), 60, "the simulator's manifest", tmp_path / "launch.log")
            os.kill(node_pids(bus_dir)["sim"], signal.SIGKILL)
            assert driver.wait(timeout=30) == 4, text(tmp_path / "driver.log")
            assert proc.wait(timeout=60) != 0
        finally:
            kill_session(driver)
    assert "the clock source 'sim' left without a stop" in text(tmp_path / "driver.log")


def test_realtime_driver_is_the_clock_source_of_the_minimal_graph(tmp_path: Path) -> None:
    bus_dir, args = tmp_path / "bus", ["duration_s:=1", "mode:=realtime", "--external", "cube"]
    with launched(LAUNCH_DIR / "demo_minimal.yaml", bus_dir, tmp_path / "launch.log", *args) as proc:
        driver = start_driver("contacts_driver.py", bus_dir, "cube", tmp_path / "driver.log")
        try:
            logs = lambda: text(tmp_path / "driver.log") + "\n---\n" + text(tmp_path / "launch.log")  # noqa: E731
            assert driver.wait(timeout=60) == 0, logs()
            assert proc.wait(timeout=60) == 0, logs()
        finally:
            kill_session(driver)
    assert "[cube] published 100 ticks; driver finished" in text(tmp_path / "driver.log")
    summary = next(line for line in text(tmp_path / "launch.log").splitlines() if "summary:" in line)
    sets = int(summary.split("summary: ")[1].split(" contact sets")[0])
    # real time: a reader that falls behind keeps only the newest contact set of a burst (how many it
    # skips depends on the machine's load)
    assert 0 < sets <= 100 and "decode errors 0" in summary
    # the driver's 5 cm cube: contacts on its faces (a reader that kept few sets may miss a face)
    box = re.search(r"bounding box ([\d.]+), ([\d.]+), ([\d.]+) mm", summary)
    assert box, summary
    assert all(0.0 < float(extent) <= 50.0 for extent in box.groups()), summary
