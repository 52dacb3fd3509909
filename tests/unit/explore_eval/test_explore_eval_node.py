"""Exploration evaluator node: a true mesh it cannot measure against is refused naming the field (the
previous one stays); zero-area triangles are dropped; an estimate must index its own vertices."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from palpate.errors import InputError
from palpate.messages.schemas import ObjectTruth, SurfaceMesh, TouchEvent
from palpate.nodes.explore_eval.node import ExploreEvalNode, ExploreEvalNodeConfig
from palpate.runtime.node import NodeContext


def truth(vertices: np.ndarray, faces: np.ndarray, name: str = "box") -> ObjectTruth:
    return ObjectTruth(
        stamp_ns=0,
        name=name,
        source="primitive",
        position_m=np.zeros(3),
        quaternion_wxyz=np.array([1.0, 0.0, 0.0, 0.0]),
        vertices_m=vertices,
        faces=faces.astype(np.int32),
    )


def test_bad_true_meshes_are_refused_and_slivers_dropped() -> None:
    ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
    node = ExploreEvalNode(ExploreEvalNodeConfig(report=False), ctx)
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    with_sliver = np.vstack([F, [[0, 0, 1]]])
    node.on_truth_object(truth(V, with_sliver))
    assert node.evaluator is not None and len(node.evaluator.faces) == len(F)
    first = node.evaluator
    cases = [
        (truth(V, np.vstack([F, [[0, 1, len(V)]]])), rf"^faces: vertex index {len(V)} is outside 0..{len(V) - 1}"),
        (truth(V, np.zeros((3, 3))), r"^faces: none of the 3 triangles has an area"),
        (truth(V, np.zeros((0, 3))), r"^faces: none of the 0 triangles has an area"),
        (truth(V * 1e6, F), r"^vertices_m: coordinate -?25000 m lies beyond"),
    ]
    for message, reason in cases:
        with pytest.raises(InputError, match=reason):
            node.on_truth_object(message)
        assert node.evaluator is first
    estimate = SurfaceMesh(
        stamp_ns=0,
        region="global",
        num_contacts=1,
        vertices_m=V,
        faces=np.array([[0, 1, 99]], dtype=np.int32),
        vertex_normals=np.zeros_like(V),
        variance_vertices=np.arange(len(V), dtype=np.int32),
        vertex_variance=np.zeros(len(V)),
    )
    with pytest.raises(InputError, match=r"^faces: vertex index 99 is outside"):
        node.on_surface(estimate)


def test_results_without_a_milestone_write_null_not_nan(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 15: `"rmse_mm": NaN` in explore_result when a milestone is not reached; JSON has no NaN."""
    ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
    results = tmp_path / "out" / "explore.json"
    node = ExploreEvalNode(ExploreEvalNodeConfig(results_path=str(results)), ctx)
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    node.on_truth_object(truth(np.asarray(box.vertices), np.asarray(box.faces)))
    node.close()

    def refuse(name: str) -> None:
        raise ValueError(f"not JSON: {name}")

    written = json.loads(results.read_text(), parse_constant=refuse)
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("explore_result: "))
    printed = json.loads(line.removeprefix("explore_result: "), parse_constant=refuse)
    for result in (written, printed):
        milestone = result["milestones"]["80"]
        assert milestone["reached"] is False and milestone["rmse_mm"] is None and milestone["angle_deg"] is None
    # the printed line is a summary: the per-touch rows and the shape series are in the file only
    assert {"touches", "shape"} <= set(written) and not {"touches", "shape"} & set(printed)


@pytest.mark.parametrize(
    ("stopped_by", "finished"),
    [("planner: no candidate", "stopped"), ("", "clock"), ("exploration finished: goal", "clock")],
)
def test_a_run_another_node_ended_is_reported_stopped_with_its_reason(stopped_by: str, finished: str) -> None:
    """The launch path (the runtime sets run_stopped_by from the RunControl it receives): a run the
    planner or controller ended said "clock" in explore_result."""
    ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
    node = ExploreEvalNode(ExploreEvalNodeConfig(report=False), ctx)
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    node.on_truth_object(truth(np.asarray(box.vertices), np.asarray(box.faces)))
    ctx.run_stopped_by = stopped_by
    node.close()
    assert node.result["finished"] == finished
    assert node.result.get("stop_reason") == (stopped_by if finished == "stopped" else None)


def test_a_run_ended_by_the_clock_says_it_has_no_end_of_run_scores(
    caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: a run shortened with duration_s (as the size note advised) ended with every
    milestone score null and an empty shape series, without a word."""
    ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
    node = ExploreEvalNode(ExploreEvalNodeConfig(report=True), ctx)
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    node.on_truth_object(truth(np.asarray(box.vertices), np.asarray(box.faces)))
    with caplog.at_level("WARNING"):
        node.close()
    capsys.readouterr()  # the headline and result lines
    assert node.result["finished"] == "clock"
    [said] = [r.getMessage() for r in caplog.records if "ended on the simulated clock" in r.getMessage()]
    assert "after 0 contacts, before any end-of-run score: its last shape scores are none" in said


def test_a_repeated_truth_keeps_the_records_and_another_object_is_refused() -> None:
    ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
    node = ExploreEvalNode(ExploreEvalNodeConfig(report=False), ctx)
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    touch = TouchEvent(
        stamp_ns=0,
        index=0,
        position_m=np.array([0.0, 0.0, 0.025]),
        normal=np.array([0.0, 0.0, 1.0]),
        approach_direction=np.array([0.0, 0.0, -1.0]),
        predicted_contact_m=np.full(3, np.nan),
        missed=False,
        travelled_m=0.0,
        rotation_deg=0.0,
    )
    with pytest.raises(InputError, match=r"^index: touch 0 came while no object truth \(truth/object\) was taken"):
        node.on_touches(touch)
    node.on_truth_object(truth(V, F))
    first = node.evaluator
    node.on_touches(touch)
    assert first is not None and first.tracker.contacts == 1
    assert first.touches[0].normal == [0.0, 0.0, 1.0]  # recorded, so the estimate can be rebuilt
    node.on_truth_object(truth(V, F))  # latched or re-published: nothing changes
    assert node.evaluator is first and first.tracker.contacts == 1
    with pytest.raises(InputError, match=r"^name: a second object 'ball' during the run on 'box'"):
        node.on_truth_object(truth(V * 0.5, F, name="ball"))
    assert node.evaluator is first
    # an outside fuzzer: one touch with a path of 1e308 m summed to an infinite travel and ended the run
    # as "travel budget" (a clean exit, travel inf cm); such a touch is refused and nothing is recorded
    from dataclasses import replace

    for field, value, message in [
        ("travelled_m", 1e308, r"^travelled_m: value 1e\+308 m is outside \[0, 1e\+06\] m"),
        ("travelled_m", -1.0, r"^travelled_m: value -1 m is outside"),
        ("rotation_deg", 1e300, r"^rotation_deg: value 1e\+300 deg is outside \[0, 1e\+09\] deg"),
    ]:
        with pytest.raises(InputError, match=message):
            node.on_touches(replace(touch, **{field: value}))
    assert first.tracker.contacts == 1 and len(first.touches) == 1
    # a touch refused for another field leaves the odometers as they were (a review)
    later = replace(touch, stamp_ns=10**9, travelled_m=0.5, rotation_deg=1e300)
    with pytest.raises(InputError, match=r"^rotation_deg"):
        node.on_touches(later)
    assert node.travelled.last == 0.0 and node.travelled.stamp_ns == 0


def test_a_launched_run_ends_with_a_line_for_a_reader_before_its_json() -> None:
    from palpate.nodes.explore_eval.node import _headline

    result = {
        "object": "torus",
        "contacts": 149,
        "coverage": 0.8031,
        "finished": "goal",
        "touches": [{"travel_cm": 237.6}],
    }
    assert _headline(result) == "torus: 149 contacts, coverage 80.3 %, travel 237.6 cm, finished: goal"
    stopped = {**result, "contacts": 0, "touches": [], "finished": "stopped", "stop_reason": "controller: no surface"}
    assert _headline(stopped).endswith(
        "0 contacts, coverage 80.3 %, travel 0.0 cm, finished: stopped (controller: no surface)"
    )


def test_output_paths_it_could_not_write_are_named_before_the_run(tmp_path: Path) -> None:
    """An outside walkthrough: `results:=DIR` and `plot:=x.weird` passed --dry-run and failed after the
    whole run with a traceback (the files are written only at its end)."""
    from palpate.nodes.explore_eval.node import SPEC

    assert SPEC.checks is not None
    blocker = tmp_path / "file"
    blocker.write_text("")
    fine = ExploreEvalNodeConfig(results_path=str(tmp_path / "new" / "r.json"), plot_path=str(tmp_path / "p.svg"))
    assert SPEC.checks(fine) == {}
    assert SPEC.checks(ExploreEvalNodeConfig(plot_path=str(tmp_path / "run"))) == {}  # no suffix: a PNG
    problems = SPEC.checks(ExploreEvalNodeConfig(results_path=str(tmp_path), plot_path="out/x.weird"))
    assert problems[("results_path",)] == f"{tmp_path} is a directory; give a file name, such as {tmp_path}/run.json"
    assert problems[("plot_path",)].startswith("out/x.weird: the plot's format comes from its suffix, one of ")
    problems = SPEC.checks(ExploreEvalNodeConfig(plot_path=str(blocker / "p.png")))
    assert problems == {("plot_path",): f"{blocker}/p.png: {blocker} is not a folder"}


def test_a_result_file_it_cannot_write_is_logged_and_the_result_still_printed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
    blocker = tmp_path / "file"
    blocker.write_text("")
    node = ExploreEvalNode(ExploreEvalNodeConfig(results_path=str(blocker / "r.json")), ctx)
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    node.on_truth_object(truth(np.asarray(box.vertices), np.asarray(box.faces)))
    node.close()
    assert "explore_result: {" in capsys.readouterr().out
    assert "explore_eval: could not write the run's files: " in caplog.text


def test_a_launched_run_on_an_object_too_small_or_too_large_says_so(caplog: pytest.LogCaptureFixture) -> None:
    """An outside walkthrough: a launch on a 3 mm sphere ended "complete" after one touch, and one on a
    1.5 m sphere at 0 % coverage, each without a word (eval explore said so; a launch did not)."""
    for radius_m, said in [
        (0.0015, "explore_eval: bead has 0.282 cm^2 of surface: 0.24 touches of 6 mm cover 80% of it at best"),
        (
            0.75,
            "explore_eval: bead has 7.06 m^2 of surface: 60,388 touches of 6 mm cover 80% of it, so its runs may take",
        ),
    ]:
        ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
        node = ExploreEvalNode(ExploreEvalNodeConfig(), ctx)
        ball = trimesh.creation.icosphere(subdivisions=4, radius=radius_m)
        caplog.clear()
        with caplog.at_level("WARNING"):
            node.on_truth_object(truth(np.asarray(ball.vertices), np.asarray(ball.faces), name="bead"))
        assert len(caplog.messages) == 1 and caplog.messages[0].startswith(said), caplog.messages
    assert (
        "contacts_per_bound=0 ...; a run ended by the launch's duration_s has no end-of-run scores); give scale:= if"
        in (caplog.messages[0])
    )
    caplog.clear()
    with caplog.at_level("WARNING"):
        ball = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
        node = ExploreEvalNode(ExploreEvalNodeConfig(), ctx)
        node.on_truth_object(truth(np.asarray(ball.vertices), np.asarray(ball.faces)))
    assert not caplog.messages  # a YCB-sized object: nothing to say
    caplog.clear()
    with caplog.at_level("WARNING"):  # an evaluation's run (it says so itself, once per object)
        ball = trimesh.creation.icosphere(subdivisions=4, radius=0.0015)
        node = ExploreEvalNode(ExploreEvalNodeConfig(report=False), ctx)
        node.on_truth_object(truth(np.asarray(ball.vertices), np.asarray(ball.faces)))
    assert not caplog.messages


def test_a_negative_variance_of_an_estimate_is_refused() -> None:
    """An outside audit: a variance of -1 counted every face as confident, so the headline RMSE took the
    whole estimate (26.6 mm) where the GP said nothing was sure."""
    ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
    node = ExploreEvalNode(ExploreEvalNodeConfig(report=False), ctx)
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    node.on_truth_object(truth(np.asarray(box.vertices), np.asarray(box.faces)))
    estimate = SurfaceMesh(
        stamp_ns=0,
        region="global",
        num_contacts=1,
        vertices_m=np.asarray(box.vertices),
        faces=np.asarray(box.faces, dtype=np.int32),
        vertex_normals=np.asarray(box.vertex_normals),
        variance_vertices=np.arange(len(box.vertices), dtype=np.int32),
        vertex_variance=np.full(len(box.vertices), -1.0),
    )
    with pytest.raises(InputError, match=r"^vertex_variance: value -1 m\^2 is outside \[0, 1e\+06\] m\^2"):
        node.on_surface(estimate)
    assert len(node.last_variance) == 0


def test_a_run_without_an_object_truth_fails_after_a_while_naming_it() -> None:
    """An outside clock-source driver in C that sent no truth (or one the evaluator refused): every touch was
    refused as coming "before the object's truth", the run went on to its end, printed no result and the
    launch exited 0."""
    ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
    node = ExploreEvalNode(ExploreEvalNodeConfig(report=False), ctx)
    start = 1_764_000_000 * 10**9  # a hardware clock's epoch stamps: the wait counts from the first tick
    for tick in range(501):
        node.on_tick(start + tick * 10_000_000)
        if tick < 500:
            assert not ctx.stop_requested, tick
    assert ctx.stop_requested.startswith("explore_eval: no usable object truth on truth/object 5 s into the run")
    assert ctx.failure == ctx.stop_requested  # a failure: the launch exits 1


def test_a_true_mesh_that_is_not_closed_is_said(caplog: pytest.LogCaptureFixture) -> None:
    """An outside clock-source driver: a sphere truth with a quarter of its faces missing was taken without
    a word (area 0.015 instead of 0.020 m^2, the run "complete")."""
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    V, F = np.asarray(ball.vertices), np.asarray(ball.faces)
    for faces, said in ((F, False), (F[: 3 * len(F) // 4], True)):
        ctx = NodeContext("eval", 0, lambda topic, message: None, {"request": "surface/request"})
        caplog.clear()
        with caplog.at_level("WARNING"):
            ExploreEvalNode(ExploreEvalNodeConfig(report=False), ctx).on_truth_object(truth(V, faces, name="ball"))
        assert any("the true mesh of 'ball' is not closed" in m for m in caplog.messages) == said
