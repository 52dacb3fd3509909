"""The exploration graph as processes (`palpate launch launch/explore.yaml`) and in-process
(InProcessGraph, what `palpate eval explore` runs) make the same touches for the same seed."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from palpate.evaluation.explore import EXPLORE_LAUNCH
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch, parse_cli_args
from palpate.runtime.inprocess import InProcessGraph
from tests.integration.launch_helpers import launched, text

# A 3 cm sphere approached from above: a few touches within 5 s of simulated time.
ARGS = [
    "object:=sphere",
    "start:=[0.01, 0.0, 0.07]",
    "target:=[0.0, 0.0, 0.027]",
    "duration_s:=5.0",
    "seed:=3",
]


def _touches(result: dict[str, Any]) -> list[tuple[list[float], float, float, bool]]:
    return [(t["position_m"], t["travel_cm"], t["prediction_miss_mm"], t["missed"]) for t in result["touches"]]


@pytest.mark.slow
def test_process_graph_and_in_process_graph_touch_the_same_points(tmp_path: Path) -> None:
    process_json = tmp_path / "process.json"
    log = tmp_path / "launch.log"
    with launched(EXPLORE_LAUNCH, tmp_path / "bus", log, *ARGS, f"results:={process_json}") as proc:
        assert proc.wait(timeout=240) == 0, text(log)
    assert process_json.is_file(), text(log)

    inproc_json = tmp_path / "inproc.json"
    overrides = parse_cli_args([*ARGS, f"results:={inproc_json}"])
    graph = InProcessGraph(
        resolve(load_launch(EXPLORE_LAUNCH, overrides), bus_dir=tmp_path / "bus2").in_process_members()
    )
    graph.run()

    from_processes = json.loads(process_json.read_text())
    in_process = json.loads(inproc_json.read_text())
    assert len(from_processes["touches"]) >= 3, "the run should make a few touches"
    # exact equality: same seed, same lockstep order, same arithmetic
    assert _touches(in_process) == _touches(from_processes)
    assert in_process["coverage"] == from_processes["coverage"]
    # the simulated clock ended both runs: no node stopped them (the clock's stop is no node's)
    assert from_processes["finished"] == in_process["finished"] == "clock"
    assert "stop_reason" not in from_processes
