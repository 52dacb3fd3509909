"""`placement: loop` (palpate.launch.placement): the plan, the choice of CPU, and a child placed by it."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

from palpate.launch import placement
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch
from palpate.launch.placement import CpuPlacement, busy_ticks, graph_placement, least_busy, plan_loop
from palpate.launch.supervisor import Child, Supervisor, _place_child
from palpate.paths import REPO_ROOT

STAT_BEFORE = """cpu  300 0 100 1000 0 0 0 0 0 0
cpu0 100 0 50 500 0 0 0 0 0 0
cpu1 200 0 50 500 0 0 0 0 0 0
intr 12345
"""
# over the interval cpu0 was busy 80 of 100 ticks, cpu1 10 of 100 (iowait counts as idle)
STAT_AFTER = """cpu  390 0 100 1110 0 0 0 0 0 0
cpu0 170 0 60 520 0 0 0 0 0 0
cpu1 210 0 50 580 10 0 0 0 0 0
"""


def test_the_loop_shares_one_cpu_and_the_trailing_nodes_get_the_others() -> None:
    plan = plan_loop(["sim", "driver"], ["noise"], {0, 1, 2, 3}, loop_cpu=2)
    assert plan == {
        "sim": CpuPlacement(frozenset({2})),
        "driver": CpuPlacement(frozenset({2})),
        "noise": CpuPlacement(frozenset({0, 1, 3})),
    }
    assert plan_loop(["sim"], ["noise"], {5}, loop_cpu=5)["noise"].cpus == {5}  # one CPU: all on it
    with pytest.raises(ValueError, match="loop CPU 4 is not among the allowed CPUs"):
        plan_loop(["sim"], [], {0, 1}, loop_cpu=4)


def test_the_least_busy_cpu_from_two_readings_of_proc_stat() -> None:
    before, after = busy_ticks(STAT_BEFORE), busy_ticks(STAT_AFTER)
    assert before == {0: (150, 650), 1: (250, 750)}
    assert least_busy(before, after, {0, 1}) == 1
    assert least_busy(before, after, {0}) == 0
    assert least_busy(before, before, {1, 0}) == 1  # no ticks passed: a tie, the highest number
    assert least_busy(before, after, {7, 0}) == 0  # a CPU the readings miss counts as busy


def test_probe_launch_places_sim_and_driver_together(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if not placement.supported():
        pytest.skip("no CPU affinity on this system")
    monkeypatch.setattr(placement, "least_busy_cpu", lambda allowed, sample_s=0.05: max(allowed))
    graph = resolve(load_launch(REPO_ROOT / "launch" / "probe.yaml"), bus_dir=tmp_path)
    assert graph.source.placement == "loop"
    plan = graph_placement(graph)
    allowed = os.sched_getaffinity(0)
    assert plan["sim"] == plan["driver"] == CpuPlacement(frozenset({max(allowed)}))
    assert plan["noise"].cpus == (allowed - {max(allowed)} or allowed)  # it trails the clock
    assert placement.describe(plan).startswith(f"CPU {max(allowed)}: sim, driver")
    external = tmp_path / "external.yaml"  # a node the launcher does not start gets no placement
    external.write_text(
        (REPO_ROOT / "launch" / "probe.yaml").read_text().replace("type: noise\n", "type: noise\n    external: true\n")
    )
    assert set(graph_placement(resolve(load_launch(external), bus_dir=tmp_path))) == {"sim", "driver"}
    demo = resolve(load_launch(REPO_ROOT / "launch" / "demo.yaml"), bus_dir=tmp_path)
    assert demo.source.placement == "os" and graph_placement(demo) == {}


def test_a_child_and_its_threads_run_where_its_placement_says(tmp_path: Path) -> None:
    allowed = os.sched_getaffinity(0) if placement.supported() else set()
    if len(allowed) < 2:
        pytest.skip("needs CPU affinity and two CPUs")
    place = CpuPlacement(frozenset({max(allowed)}))
    report = (
        "import os, threading\n"
        "def show():\n"
        "    tid = threading.get_native_id()\n"
        "    print(sorted(os.sched_getaffinity(tid)), os.sched_getscheduler(tid) == os.SCHED_BATCH)\n"
        "show(); t = threading.Thread(target=show); t.start(); t.join()"
    )
    out = subprocess.run(
        [sys.executable, "-c", report],
        preexec_fn=lambda: _place_child(place),
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert out.split("\n")[:2] == [f"[{max(allowed)}] True"] * 2


@pytest.mark.parametrize("refused", [False, True])
def test_the_launcher_says_when_a_child_runs_unplaced(
    refused: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    allowed = os.sched_getaffinity(0) if placement.supported() else set()
    if len(allowed) < 2:
        pytest.skip("needs CPU affinity and two CPUs")
    if refused:  # the forked child inherits the patch: the system "refuses" there
        monkeypatch.setattr(CpuPlacement, "apply", lambda self: (_ for _ in ()).throw(PermissionError(1, "refused")))
    graph = resolve(load_launch(REPO_ROOT / "launch" / "probe.yaml"), bus_dir=tmp_path)
    out = io.StringIO()
    supervisor = Supervisor(graph, [], out=out)
    place = CpuPlacement(frozenset({max(allowed)}))
    child = Child(node=graph.by_name["sim"], spec_path=tmp_path / "sim.json")
    child.proc = subprocess.Popen(["sleep", "10"], preexec_fn=lambda: _place_child(place))
    try:
        supervisor._check_placed(child, place)
    finally:
        child.proc.kill()
        child.proc.wait()
        supervisor.shutdown()
    refusal = f"[launch] node 'sim' runs without its placement (CPU {max(allowed)}, SCHED_BATCH): the system refused it"
    assert out.getvalue().strip() == (refusal if refused else "")
