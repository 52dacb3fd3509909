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
from palpate.evaluation.explore import ObjectCase, select_cases
from palpate.metrics.exploration import mesh_area

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
    config, eval_config = rescore.node_configs("tour", {})
    run = _run("tour")
    positions, normals = rescore.touches_at(run, "80", Path("runs.jsonl"))
    assert len(positions) == 40
    scores = rescore.rebuilt_scores(SPHERE.true_mesh(), np.array(positions), np.array(normals), config, eval_config)
    assert set(scores) == set(rescore.REBUILT)
    assert 0.0 < scores["rmse_symmetric_mm"] < 0.5  # 40 exact contacts all round a 3 cm ball
    assert 0.5 < scores["confident_fraction"] <= 1.0


def test_a_touch_the_estimator_refuses_is_left_out_as_the_node_leaves_it_out() -> None:
    config, _ = rescore.node_configs("tour", {})
    positions, normals = (np.array(x) for x in rescore.touches_at(_run("tour"), "80", Path("r.jsonl")))
    kept = rescore.rebuilt_scores(SPHERE.true_mesh(), positions, normals, config)
    refused = np.vstack([positions, [[0.0, 0.0, 0.03]]]), np.vstack([normals, [[0.0, 0.0, 0.0]]])  # no direction
    assert rescore.rebuilt_scores(SPHERE.true_mesh(), *refused, config) == kept


def test_the_worker_gives_an_error_row_where_the_estimator_cannot_mesh() -> None:
    configs = rescore.node_configs("tour", {"gpis.grow_kernel": False, "gpis.gp.R_m": 0.01})
    positions, normals = rescore.touches_at(_run("tour"), "80", Path("r.jsonl"))
    identity = {"object": "sphere", "strategy": "tour", "run": 0, "milestone": "80"}
    row = rescore.rescore_on_worker(SPHERE, positions, normals, configs, identity)
    assert row["error"].startswith("EstimationError: ") and "rebuilt" not in row


def test_the_runs_own_settings_and_the_sets_on_top_reach_the_rebuild() -> None:
    run = _run("gpv")
    run["params"] = {
        "gpis.gp.R_m": 1.0,
        "eval.eval.rmse_samples": 5000,
        "planner.candidate_step_m": 0.01,
        "gpis.variance_step_m": 0.01,
    }  # planner and gpis must agree on the step: both apply
    (task,) = rescore.tasks_of([run], {"sphere": SPHERE}, {"gpis.gp.gradient_noise": 0.03}, "80", Path("r.jsonl"))
    gpis, evaluation = task.args[3]
    assert (gpis.gp.R_m, gpis.gp.gradient_noise, gpis.variance_step_m) == (1.0, 0.03, 0.01)
    assert evaluation.rmse_samples == 5000
    (again,) = rescore.tasks_of([run], {"sphere": SPHERE}, {"gpis.gp.gradient_noise": 0.1}, "80", Path("r.jsonl"))
    assert again.key != task.key  # other settings, another run on --resume


def test_settings_a_rebuild_cannot_follow_are_refused() -> None:
    with pytest.raises(ConfigError, match="free space comes from the fingertip's path"):
        rescore.node_configs("tour", {"gpis.free_space": True})


def test_a_mesh_of_another_size_than_the_run_had_is_named() -> None:
    run = _run("gpv")
    run["area_m2"] = 4.0 * np.pi * 0.03**2 * 1e6  # the run's object was a thousand times larger (mm)
    with pytest.raises(ConfigError, match=r"sphere ran on a surface of 1?\d+(\.\d+)? m\^2, but sphere is"):
        rescore.tasks_of([run], {"sphere": SPHERE}, {}, "80", Path("r.jsonl"))
    run["area_m2"] = mesh_area(SPHERE.true_mesh())
    assert len(rescore.tasks_of([run], {"sphere": SPHERE}, {}, "80", Path("r.jsonl"))) == 1


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
    failed = {"object": "sphere", "strategy": "tour", "run": 2, "error": "EstimationError: ..."}
    runs.append(_run("tour", 2))
    summary = rescore.comparison(runs, rescore.with_rebuilt(runs, [*rebuilt, failed], "80"), ["igef", "tour"], "80")
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


@pytest.mark.slow
def test_the_command_rebuilds_writes_its_tables_and_reproduces_the_recorded_figures(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    import trimesh

    from palpate import jsonio

    objects = tmp_path / "objects"
    objects.mkdir()
    trimesh.creation.icosphere(subdivisions=3, radius=0.03).export(objects / "ball.stl")
    (case,) = select_cases([objects])
    runs = []
    for strategy in ("igef", "tour"):
        run = _run(strategy, count=30 if strategy == "igef" else 40)
        run["object"], run["area_m2"] = "ball", mesh_area(case.true_mesh())
        config, eval_config = rescore.node_configs(strategy, run["params"])
        positions, normals = rescore.touches_at(run, "80", tmp_path)
        truth = case.true_mesh()
        recorded = rescore.rebuilt_scores(truth, np.array(positions), np.array(normals), config, eval_config)
        run["milestones"]["80"].update(recorded)  # as the evaluation recorded them
        runs.append(run)
    runs.append({"object": "ball", "strategy": "tour", "run": 1, "error": "MeshError: ..."})
    source = tmp_path / "runs.jsonl"
    source.write_text("".join(jsonio.dumps(r) + "\n" for r in runs))
    parser = argparse.ArgumentParser()
    rescore.configure(parser)
    out = tmp_path / "out"
    args = parser.parse_args([str(source), "--objects", str(objects), "--out", str(out), "--workers", "1", "--json"])
    assert rescore.main(args) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for strategy in ("igef", "tour"):
        assert summary[strategy]["paired_runs"] == 1
        assert summary[strategy]["rmse_symmetric_mm"] == summary[strategy]["recorded_rmse_symmetric_mm"]
    assert summary["igef"]["rmse_symmetric_mm"] != summary["tour"]["rmse_symmetric_mm"]  # 30 contacts against 40
    assert "| tour | 1 |" in (out / "tables.md").read_text()
    assert len((out / "rescored.jsonl").read_text().splitlines()) == 2
