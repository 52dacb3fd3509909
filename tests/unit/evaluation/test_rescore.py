"""palpate.evaluation.rescore: an evaluation's whole estimate rebuilt from its recorded touches."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from palpate.errors import ConfigError
from palpate.evaluation import rescore
from palpate.evaluation.explore import ObjectCase

SPHERE = ObjectCase(name="sphere", kind="sphere", size_m=(0.03,))  # a 3 cm radius ball of the sim


def _touches(count: int, radius_m: float = 0.03) -> list[dict[str, Any]]:
    """Touches spread over the whole sphere (a Fibonacci lattice), their normals exact."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = np.pi * (1.0 + 5.0**0.5) * k
    normals = np.column_stack([np.sqrt(1.0 - z**2) * np.cos(phi), np.sqrt(1.0 - z**2) * np.sin(phi), z])
    return [{"position_m": list(radius_m * n), "normal": list(n)} for n in normals]


def _run(strategy: str, run: int = 0, count: int = 40, symmetric_mm: float = 9.0) -> dict[str, Any]:
    milestone = {"reached": True, "contacts": count, "rmse_symmetric_mm": symmetric_mm}
    return {
        "object": "sphere",
        "strategy": strategy,
        "run": run,
        "milestones": {"80": milestone},
        "touches": _touches(count + 5),  # touches after the milestone are not the estimate's
        "params": {"eval.report": False},
    }


def test_a_rebuild_of_contacts_over_a_sphere_finds_the_sphere() -> None:
    config = rescore.gpis_config("tour", {})
    run = _run("tour")
    positions, normals = rescore.touches_at(run, "80", Path("runs.jsonl"))
    assert len(positions) == 40
    scores = rescore.rebuilt_scores(SPHERE.true_mesh(), np.array(positions), np.array(normals), config)
    assert set(scores) == set(rescore.REBUILT)
    assert 0.0 < scores["rmse_symmetric_mm"] < 0.5  # 40 exact contacts all round a 3 cm ball
    assert 0.5 < scores["confident_fraction"] <= 1.0


def test_a_gpis_setting_reaches_the_rebuild_and_refuses_what_it_cannot_follow() -> None:
    assert rescore.gpis_config("gpv", {"gpis.gp.R_m": 2.0}).gp.R_m == 2.0
    assert rescore.gpis_config("gpv", {}).gp.R_m == 0.5
    with pytest.raises(ConfigError, match="free space comes from the fingertip's path"):
        rescore.gpis_config("tour", {"gpis.free_space": True})


def test_runs_without_touch_normals_are_named() -> None:
    run = _run("igef")
    run["touches"][3]["normal"] = None
    with pytest.raises(ConfigError, match=r"^runs.jsonl: sphere igef run 0 has no touch normals"):
        rescore.touches_at(run, "80", Path("runs.jsonl"))


def test_tasks_skip_runs_short_of_the_milestone_and_name_an_unknown_object() -> None:
    short = _run("gpv", run=1)
    short["milestones"]["80"]["reached"] = False
    failed = {"object": "sphere", "strategy": "gpv", "run": 2, "error": "MeshError: ..."}
    tasks = rescore.tasks_of([_run("gpv"), short, failed], {"sphere": SPHERE}, {}, "80", Path("r.jsonl"))
    assert [t.label for t in tasks] == ["sphere gpv run 0"]
    with pytest.raises(ConfigError, match="object 'sphere' is not among --objects"):
        rescore.tasks_of([_run("gpv")], {}, {}, "80", Path("r.jsonl"))


def test_the_comparison_pairs_the_runs_every_strategy_rebuilt() -> None:
    runs = [_run("igef", 0, symmetric_mm=4.0), _run("tour", 0, symmetric_mm=2.0), _run("tour", 1, symmetric_mm=8.0)]
    rebuilt = [
        {"object": "sphere", "strategy": "igef", "run": 0, "rebuilt": {"rmse_symmetric_mm": 3.0}},
        {"object": "sphere", "strategy": "tour", "run": 0, "rebuilt": {"rmse_symmetric_mm": 1.0}},
        {"object": "sphere", "strategy": "tour", "run": 1, "rebuilt": {"rmse_symmetric_mm": 5.0}},
    ]
    summary = rescore.comparison(runs, rescore.with_rebuilt(runs, rebuilt, "80"), ["igef", "tour"], "80")
    assert summary["tour"]["paired_runs"] == 1  # igef has no run 1
    assert summary["tour"]["recorded_rmse_symmetric_mm"] == 2.0
    assert summary["tour"]["rmse_symmetric_mm"] == 1.0
    assert summary["igef"]["rmse_symmetric_mm"] == 3.0
    assert math.isnan(summary["igef"]["rmse_mm"])  # not rebuilt in this made-up row
    assert "| tour | 1 | 2.000 | 1.000 | - |" in rescore.table(summary, "80")


def test_other_nodes_settings_are_refused_before_any_work(tmp_path: Path) -> None:
    args = argparse.Namespace(set=["planner.tour_sites=6"], runs=tmp_path / "runs.jsonl")
    with pytest.raises(ConfigError, match=r"^--set planner\.tour_sites: a rescore rebuilds the GPIS estimate only"):
        rescore.main(args)
