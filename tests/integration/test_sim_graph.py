"""The sim graph as processes: `palpate launch launch/probe.yaml` runs to the end and exits 0."""

from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import time
from pathlib import Path

import pytest

from palpate.launch import placement
from palpate.paths import REPO_ROOT
from palpate.runtime.timing import TIMING_ENV, breakdown
from tests.integration.launch_helpers import launched, node_pids, text


def test_probe_graph_runs_to_completion(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    bus_dir, log, timing = tmp_path / "bus", tmp_path / "launch.log", tmp_path / "timing.json"
    monkeypatch.setenv(TIMING_ENV, str(tmp_path / "ticks"))  # every node records its ticks
    args = ("duration_s:=1", "start:=[0.0, 0.0, 0.03]", f"timing:={timing}")
    with launched(REPO_ROOT / "launch" / "probe.yaml", bus_dir, log, *args) as proc:
        placed = _placements_while_running(proc, bus_dir, {"sim", "driver", "noise"})
        assert proc.wait(timeout=180) == 0, text(log)
    out = text(log)
    found = re.search(r"\[driver\] INFO probe driver: (\d+) contacts in (\d+) of (\d+) ticks", out)
    assert found, out
    contacts, touching, ticks = (int(g) for g in found.groups())
    assert ticks == 101  # ticks 0..100 of 10 ms in 1 s
    assert contacts == touching > 50  # one contact per tick while pressing and sliding on the box
    if placement.supported():  # launch/probe.yaml asks for placement: loop, and the nodes run so
        cpus = re.search(r"\[launch\] placement loop: CPU (\d+): sim, driver", out)
        assert cpus and int(cpus.group(1)) in os.sched_getaffinity(0), out
        assert "placement" not in out.replace(cpus.group(0), ""), out  # no refusal reported
        loop_cpu = {int(cpus.group(1))}
        assert placed["sim"] == placed["driver"] == (loop_cpu, os.SCHED_BATCH)
        others = os.sched_getaffinity(0) - loop_cpu or loop_cpu
        assert placed["noise"] == (others, os.SCHED_BATCH)  # it trails the clock
    data = json.loads(timing.read_text())
    assert data["stamps_ns"] == [k * 10_000_000 for k in range(101)]
    assert all(b >= a for a, b in zip(data["wall_s"], data["wall_s"][1:], strict=False))
    assert node_pids(bus_dir) == {}  # every node exited and removed its manifest
    parts = breakdown(tmp_path / "ticks", first_tick=10)  # ticks 10-100 (the step after 100 ends the run)
    assert parts["ticks"] == 91 and set(parts["handle_ms"]) == {"driver", "noise"}
    # the parts of a tick fit in it: the clock source's step and its round trip
    assert 0 < parts["step_ms"] + parts["round_trip_ms"] <= parts["tick_ms"]
    assert all(v >= 0 for v in (*parts["clock_hop_ms"].values(), *parts["handle_ms"].values(), parts["encode_ms"]))


def _placements_while_running(
    proc: subprocess.Popen[bytes], bus_dir: Path, names: set[str]
) -> dict[str, tuple[set[int], int]]:
    """CPUs and scheduling policy of each node process, read while the launch runs ({} without Linux
    affinity)."""
    if not placement.supported():
        return {}
    deadline = time.monotonic() + 30
    placed: dict[str, tuple[set[int], int]] = {}
    while set(placed) < names and proc.poll() is None and time.monotonic() < deadline:
        for name, pid in node_pids(bus_dir).items():
            with contextlib.suppress(ProcessLookupError):
                placed.setdefault(name, (os.sched_getaffinity(pid), os.sched_getscheduler(pid)))
        time.sleep(0.005)
    return placed
