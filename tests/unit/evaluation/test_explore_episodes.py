"""Episode set-up of the exploration benchmark: seeded starts, initial targets, launch arguments."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from palpate.errors import ConfigError, LaunchError, MeshError
from palpate.evaluation.explore import (
    EXPLORE_LAUNCH,
    QUIET_RUNS,
    ObjectCase,
    approach,
    check_episodes,
    episode_launch,
    episodes,
    objects_in,
    parse_sets,
    parse_strategies,
    probe_quaternion,
    profile_summary,
    profile_table,
    report_short,
    report_stopped,
    run_episode,
    stopped_early,
)
from palpate.geometry.mesh_query import ExactContactSensor
from palpate.geometry.rotations import quat_to_matrix
from palpate.launch.graph import resolve
from palpate.launch.loader import apply_params, load_launch
from palpate.metrics.exploration import DistanceField
from palpate.nodes.sim.objects import primitive_mesh


def test_start_and_target_follow_the_ray_to_the_centre() -> None:
    box = trimesh.creation.box((0.04, 0.06, 0.02))
    box.apply_translation([0.01, 0.0, 0.01])
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    centre = 0.5 * (V.min(axis=0) + V.max(axis=0))
    radius = float(np.linalg.norm(V - centre, axis=1).max())
    for run in range(5):
        a = approach(V, F, run)
        assert a.direction[2] >= 0.0 and np.linalg.norm(a.direction) == pytest.approx(1.0)
        np.testing.assert_allclose(np.linalg.norm(a.start_m - centre), radius + 0.03, atol=1e-12)
        # the target lies on the ray, 3 mm inside the surface
        ray = (a.target_m - a.start_m) / np.linalg.norm(a.target_m - a.start_m)
        np.testing.assert_allclose(ray, -a.direction, atol=1e-6)
        hit = a.target_m + 0.003 * a.direction
        assert DistanceField(box).distance(hit[None])[0] == pytest.approx(0.0, abs=1e-6)
        assert ExactContactSensor(box).closest(a.target_m[None]).distance_m[0] < 0.0  # inside
    # seeded: the same run gives the same start, another run another one
    np.testing.assert_array_equal(approach(V, F, 2).start_m, approach(V, F, 2).start_m)
    assert not np.allclose(approach(V, F, 2).start_m, approach(V, F, 3).start_m)


def test_rays_through_the_torus_hole_are_drawn_again() -> None:
    torus = primitive_mesh("torus", (0.04, 0.015))
    V, F = np.asarray(torus.vertices), np.asarray(torus.faces)
    draws = [approach(V, F, run).draws for run in range(8)]
    assert max(draws) > 1  # steep rays pass through the hole
    sensor = ExactContactSensor(torus)
    for run in range(8):
        assert sensor.closest(approach(V, F, run).target_m[None]).distance_m[0] < 0.0


def test_separate_bodies_around_an_empty_centre_get_rays_aimed_at_their_surface() -> None:
    """An outside walkthrough: two boxes 0.8 m apart (a dumbbell) stopped the whole evaluation with "no
    ray ... towards the centre hits the mesh", naming no file."""
    boxes = [trimesh.creation.box((0.04, 0.04, 0.04)).apply_translation([x, 0.0, 0.0]) for x in (-0.4, 0.4)]
    dumbbell = trimesh.util.concatenate(boxes)
    V, F = np.asarray(dumbbell.vertices), np.asarray(dumbbell.faces)
    sensor = ExactContactSensor(dumbbell)
    for run in range(3):
        a = approach(V, F, run, max_draws=16)
        assert a.draws > 16  # none through the centre
        hit = a.target_m + 0.003 * a.direction  # the target: 3 mm past the ray's hit, inside
        assert DistanceField(dumbbell).distance(hit[None])[0] == pytest.approx(0.0, abs=1e-6)
        assert sensor.closest(a.target_m[None]).distance_m[0] < 0.0
        ray = (a.target_m - a.start_m) / np.linalg.norm(a.target_m - a.start_m)
        np.testing.assert_allclose(ray, -a.direction, atol=1e-9)  # the probe faces along its ray


def test_probe_faces_the_object() -> None:
    d = np.array([0.3, -0.2, 0.9])
    d /= np.linalg.norm(d)
    R = quat_to_matrix(probe_quaternion(d))
    np.testing.assert_allclose(R[:, 2], -d, atol=1e-12)


def test_episodes_pair_strategies_on_the_same_start_and_load_as_launch_arguments() -> None:
    case = ObjectCase(name="sphere", kind="sphere", size_m=(0.03,))
    items = episodes([case], 2, ("igef", "gpv"), params={"eval.report": False})
    assert [(e.run, e.strategy) for e in items] == [(0, "igef"), (0, "gpv"), (1, "igef"), (1, "gpv")]
    assert items[0].start_m == items[1].start_m and items[0].start_m != items[2].start_m
    launch = load_launch(EXPLORE_LAUNCH, items[1].launch_args())
    apply_params(launch, items[1].params)
    nodes = {n.fields["name"]: n.fields for n in launch.nodes}
    assert nodes["planner"]["params"]["strategy"] == "gpv"
    assert nodes["gpis"]["params"]["vertex_variance"] == "auto"  # the launcher settles it (test below)
    assert nodes["eval"]["params"]["report"] is False
    assert launch.seed == 0


def test_parameter_overrides_are_checked() -> None:
    assert parse_sets(["planner.candidate_step_m=0.01", "gpis.gp.kernel=gaussian"]) == {
        "planner.candidate_step_m": 0.01,
        "gpis.gp.kernel": "gaussian",
    }
    with pytest.raises(ConfigError, match=r"--set 'no_equals_sign': expected NODE\.KEY=VALUE"):
        parse_sets(["no_equals_sign"])
    with pytest.raises(ConfigError, match=r"NODE\.KEY=VALUE"):
        parse_sets(["candidate_step_m=0.01"])
    with pytest.raises(ConfigError, match="--strategies"):  # each run's strategy is a launch argument
        parse_sets(["planner.strategy=gpv"])
    launch = load_launch(EXPLORE_LAUNCH)
    with pytest.raises(ConfigError, match=r"node\.key"):
        apply_params(launch, [("nosuchnode.x", 1)])
    apply_params(launch, [("controller.controller.v0_m_s", 0.1)])
    assert next(n for n in launch.nodes if n.fields["name"] == "controller").fields["params"]["controller"] == {
        "v0_m_s": 0.1
    }


def test_strategies_and_overrides_are_checked_before_any_run() -> None:
    assert parse_strategies(" igef, tour ") == ["igef", "tour"]
    for text, error in ((",", "names no strategy"), ("igef,foo", "unknown strategy 'foo'"), ("gpv,gpv", "twice")):
        with pytest.raises(ConfigError, match=error):
            parse_strategies(text)
    params = {**QUIET_RUNS, "noise.position_sigma_m": -1}  # the evaluation's own override is not named
    [episode] = episodes([ObjectCase(name="cube", kind="cube")], 1, ["igef"], params=params)
    # the error names the parameters too, which are not in the file it points at
    bad = r"node 'noise': params\.position_sigma_m: expected a finite number >= 0.*\(strategy igef; parameters noise\."
    with pytest.raises(LaunchError, match=bad + r"position_sigma_m=-1\)$"):
        check_episodes([episode])
    check_episodes(episodes([ObjectCase(name="cube", kind="cube")], 1, ["igef", "tour"]))


def test_two_meshes_of_one_name_are_refused(tmp_path: Path) -> None:
    # runs, tables and a resumed log know an object by its file name without the extension
    for suffix in (".stl", ".ply"):
        trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(tmp_path / f"box{suffix}")
    with pytest.raises(ConfigError, match=r"two meshes named 'box' \(box\.ply and box\.stl\)"):
        objects_in(tmp_path)


def test_choosing_the_smallest_objects_names_a_mesh_it_cannot_read(tmp_path: Path) -> None:
    """--quick and sweep explore rank the folder's meshes by area: a corrupt one is a MeshError naming
    the file, as in a full evaluation (it was trimesh's traceback)."""
    from palpate.evaluation.explore import select_cases

    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(tmp_path / "box.stl")
    (tmp_path / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99\n")
    with pytest.raises(MeshError, match=r"broken\.obj: "):
        select_cases([tmp_path], smallest=1)
    (tmp_path / "broken.obj").unlink()
    assert [c.name for c in select_cases([tmp_path], smallest=1)] == ["box"]


def test_objects_may_be_mesh_files_as_well_as_folders(tmp_path: Path) -> None:
    """A user picking three objects of the YCB folder had to link them into a folder of their own."""
    from palpate.evaluation.explore import select_cases

    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(tmp_path / name / f"{name}box.stl")
    trimesh.creation.icosphere(radius=0.02).export(tmp_path / "ball.stl")
    chosen = select_cases([tmp_path / "a", tmp_path / "ball.stl"])
    assert [c.name for c in chosen] == ["abox", "ball"] and chosen[1].mesh == str(tmp_path / "ball.stl")
    (tmp_path / "b" / "ball.stl").write_bytes((tmp_path / "ball.stl").read_bytes())
    with pytest.raises(ConfigError, match=r"--objects names two meshes 'ball'"):
        select_cases([tmp_path / "ball.stl", tmp_path / "b"])
    with pytest.raises(ConfigError, match=r"011_banan\.stl' does not exist"):
        select_cases([tmp_path / "011_banan.stl"])
    (tmp_path / "notes.txt").write_text("not a mesh")
    with pytest.raises(ConfigError, match=r"is neither a folder nor a mesh file"):
        select_cases([tmp_path / "notes.txt"])
    # a file given twice, or beside its folder, is one object
    assert [c.name for c in select_cases([tmp_path / "a", tmp_path / "a" / "abox.stl", tmp_path / "ball.stl"])] == [
        "abox",
        "ball",
    ]


def test_runs_from_a_file_leave_out_a_cut_last_line_and_refuse_a_repeated_run(tmp_path: Path) -> None:
    """--from-runs: a file cut by a kill was a JSONDecodeError traceback; a run repeated by a --resume
    with other settings was counted twice (an outside audit)."""
    from palpate.evaluation.explore import runs_from

    path = tmp_path / "runs.jsonl"
    a = '{"run_key": "k1", "object": "ball", "strategy": "igef", "run": 0, "x": 1}'
    b = '{"run_key": "k2", "object": "ball", "strategy": "gpv", "run": 0, "x": 2}'
    path.write_text(f"{a}\n{b}\n" + b[:20])
    assert runs_from(path) == [
        {"object": "ball", "strategy": "igef", "run": 0, "x": 1},
        {"object": "ball", "strategy": "gpv", "run": 0, "x": 2},
    ]
    path.write_text(f"{a}\n{b}\n{a.replace('k1', 'k3')}\n")
    with pytest.raises(ConfigError, match=r"runs.jsonl:3 repeats ball igef run 0 of line 1"):
        runs_from(path)
    path.write_text(f"{a}\nnot json\n{b}\n")
    with pytest.raises(ConfigError, match=r"runs.jsonl:2 is not JSON"):
        runs_from(path)


def test_files_of_other_3d_formats_in_the_folder_are_named_as_skipped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside audit: a .3ds or .xyz file beside the meshes was skipped without a word."""
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(tmp_path / "box.stl")
    (tmp_path / "scan.xyz").write_text("0 0 0\n")
    (tmp_path / "README.md").write_text("meshes\n")
    (tmp_path / "cup.stl.gz").write_bytes(b"\x1f\x8b")  # and an archive (an outside walkthrough: not a word)
    assert [c.name for c in objects_in(tmp_path)] == ["box"]
    err = capsys.readouterr().err
    assert "skipped 1 file(s) of formats palpate does not read: scan.xyz" in err and "README" not in err
    assert "skipped 1 archive(s) or compressed file(s): cup.stl.gz; an evaluation reads mesh files" in err


def test_gltf_files_are_taken_and_subfolders_with_meshes_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: a .gltf that `palpate launch` reads was refused by eval explore, and a
    subfolder's meshes were skipped without a word. A .gltf whose buffers lie beside it is refused by
    name (a review: the worker gets the one file, and every run failed on its missing .bin)."""
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    box.export(tmp_path / "box.gltf", embed_buffers=True)
    (tmp_path / "split").mkdir()
    box.export(tmp_path / "split" / "box.gltf")  # trimesh writes gltf_buffer_0.bin beside it
    with pytest.raises(
        ConfigError, match=r"box\.gltf: a \.gltf that keeps its data in files beside it \(gltf_buffer_0"
    ):
        objects_in(tmp_path / "split")
    with pytest.raises(ConfigError, match=r"export it as \.glb"):
        objects_in(tmp_path / "split" / "box.gltf")
    capsys.readouterr()
    (tmp_path / "split" / "box.gltf").unlink()
    (tmp_path / "more").mkdir()
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(tmp_path / "more" / "crate.stl")
    assert [c.name for c in objects_in(tmp_path)] == ["box"]
    assert "its subfolders are not searched; more hold mesh files" in capsys.readouterr().err
    (tmp_path / "box.gltf").unlink()
    with pytest.raises(
        ConfigError, match=r"no mesh files .* \(its subfolders more hold some: give them as --objects\)"
    ):
        objects_in(tmp_path)
    assert [c.name for c in objects_in(tmp_path / "more")] == ["crate"]


def test_a_budget_given_on_the_command_line_is_not_scaled_by_the_object() -> None:
    import argparse

    from palpate.evaluation.explore import eval_params

    given = eval_params(argparse.Namespace(max_contacts=30, max_travel_m=None, set=[]))
    assert given["eval.eval.max_contacts"] == 30 and given["eval.eval.contacts_per_bound"] == 0.0
    assert "eval.eval.travel_per_bound_m" not in given
    assert "eval.eval.contacts_per_bound" not in eval_params(
        argparse.Namespace(max_contacts=None, max_travel_m=None, set=[])
    )


def test_the_quick_evaluation_runs_our_strategy_beside_the_papers_two() -> None:
    import argparse

    from palpate.evaluation.explore import strategies_of

    assert strategies_of(argparse.Namespace(strategies=None, quick=True)) == ["igef", "gpv", "tour"]
    assert strategies_of(argparse.Namespace(strategies=None, quick=False)) == ["igef", "gpv"]
    assert strategies_of(argparse.Namespace(strategies=" area, igef ", quick=True)) == ["area", "igef"]
    with pytest.raises(ConfigError, match="names no strategy"):  # "--strategies $S" with S unset ran the defaults
        strategies_of(argparse.Namespace(strategies="", quick=True))


def test_a_run_key_names_the_run_and_digests_the_mesh_bytes_not_its_path(tmp_path: Path) -> None:
    from palpate.evaluation.explore import episode_task

    mesh = trimesh.creation.box((0.02, 0.02, 0.02))
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        mesh.export(tmp_path / folder / "cube.stl")
    cases = [ObjectCase(name="cube", mesh=str(tmp_path / folder / "cube.stl")) for folder in ("a", "b")]
    here, there = (episodes([case], 1, ["igef"])[0] for case in cases)
    assert episode_task(here).key == episode_task(there).key
    # the same key as before objects had a scale (runs.jsonl files of older versions still resume)
    assert episode_task(here).key == "explore-cube-igef-0-5bbf52f2eb56"
    assert episode_task(here).files == (tmp_path / "a" / "cube.stl",)
    # another budget is another run
    (other,) = episodes([cases[0]], 1, ["igef"], params={"eval.eval.max_contacts": 5})
    assert episode_task(other).key != episode_task(here).key


def test_a_folder_of_millimetre_meshes_is_explored_in_metres_with_a_scale(tmp_path: Path) -> None:
    from palpate.evaluation.explore import episode_task, objects_in

    trimesh.creation.box((20.0, 20.0, 20.0)).export(tmp_path / "cube.stl")  # millimetres
    (case,) = objects_in(tmp_path, scale=0.001)
    vertices, _ = case.true_mesh()
    np.testing.assert_allclose(np.ptp(vertices, axis=0), [0.02, 0.02, 0.02])
    assert case.launch_args()["scale"] == 0.001  # the simulation builds the same object
    (metres,) = objects_in(tmp_path)
    with pytest.raises(MeshError, match=r"--scale 0\.001"):
        metres.true_mesh()
    (larger,) = objects_in(tmp_path, scale=0.0011)
    keys = {episode_task(episodes([c], 1, ["igef"])[0]).key for c in (case, larger)}
    assert len(keys) == 2  # the scale is part of the run


def test_the_gpis_node_gives_the_variance_only_to_strategies_that_rate_it(tmp_path: Path) -> None:
    case = ObjectCase(name="sphere", kind="sphere", size_m=(0.03,))

    def variance(strategy: str, params: dict[str, float]) -> str:
        item = episodes([case], 1, (strategy,), params=params)[0]
        gpis = resolve(episode_launch(item), bus_dir=tmp_path).by_name["gpis"]
        assert gpis.params["vertex_variance"] == gpis.config.vertex_variance  # what the node process gets
        return str(gpis.config.vertex_variance)

    assert variance("gpv", {}) == "candidates"
    assert variance("tour", {}) == "none" and variance("area", {}) == "none" and variance("igef", {}) == "none"
    assert variance("tour", {"planner.tour_variance_weight": 1.0}) == "candidates"
    assert variance("area", {"planner.area_variance_weight": 2.0}) == "candidates"
    assert variance("igef", {"planner.area_variance_weight": 2.0}) == "none"  # another strategy's weight
    assert variance("tour", {"planner.tour_variance_weight": 1.0, "planner.tour_sites": 2}) == "candidates"
    assert variance("igef", {"gpis.vertex_variance": "all"}) == "all"  # set, not left to the graph
    with pytest.raises(LaunchError, match=r"no_such_weight"):  # a misspelt key is named
        variance("tour", {"planner.no_such_weight": 1.0})


def test_an_object_a_touch_or_two_cover_is_noted(capsys: pytest.CaptureFixture[str]) -> None:
    tiny = ObjectCase(name="bead", kind="sphere", size_m=(0.003,))  # 4 pi r^2 = 1.13 cm^2
    episodes([tiny], 1, ["igef"])
    assert "note: bead has 1.13 cm^2 of surface: 0.97 touches of 6 mm" in capsys.readouterr().err
    episodes([ObjectCase(name="ball", kind="sphere", size_m=(0.03,))], 1, ["igef"])
    assert "note" not in capsys.readouterr().err
    crate = ObjectCase(name="crate", kind="box", size_m=(0.6, 0.6, 0.6))  # 2.16 m^2: about 18,500 touches
    episodes([crate], 1, ["igef"])
    note = capsys.readouterr().err
    assert "note: crate has 2.16 m^2 of surface: 18,475 touches" in note
    assert "budgets are 46,189 contacts and 924 m" in note  # 2.5 x and 5 cm x the bound
    episodes([crate], 1, ["igef"], params={"eval.eval.max_contacts": 300, "eval.eval.contacts_per_bound": 0.0})
    note = capsys.readouterr().err  # as --max-contacts 300 sets it: the runs end there, not after hours
    assert "18,475 touches of 6 mm cover 80% of it at best, more than its budget of 300 contacts" in note
    assert "hours" not in note


def test_a_large_objects_clock_lets_its_runs_use_their_travel_budget() -> None:
    """The launch file's clock (3600 s) ends no run before its budgets: a 60 cm crate's travel budget
    (924 m at 5 cm/s: 18,475 s) gets twice that; a ball keeps 3600 s; a faster controller needs less."""
    ball = episodes([ObjectCase(name="ball", kind="sphere", size_m=(0.03,))], 1, ["igef"])[0]
    assert ball.duration_s == 3600.0
    crate = ObjectCase(name="crate", kind="box", size_m=(0.6, 0.6, 0.6))
    (slow,) = episodes([crate], 1, ["igef"])
    (fast,) = episodes([crate], 1, ["igef"], params={"controller.controller.v0_m_s": 0.1})
    assert slow.duration_s == pytest.approx(2.0 * 0.05 * 18_475.2 / 0.05, rel=1e-4)
    assert fast.duration_s == pytest.approx(slow.duration_s / 2)
    assert slow.launch_args()["duration_s"] == slow.duration_s


@pytest.mark.parametrize("text", ["0", "-1", "nan", "inf", "mm"])
def test_a_scale_that_is_not_a_finite_positive_number_is_refused(text: str) -> None:
    import argparse

    from palpate.argtypes import positive_scale

    with pytest.raises(argparse.ArgumentTypeError, match=f"expected a finite number > 0.*got '{text}'"):
        positive_scale(text)
    assert positive_scale("0.001") == 0.001


def test_a_run_another_node_ends_is_marked_stopped_and_reported_once_per_reason(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """An initial target outside the object: the controller's first approach finds no surface and ends the
    run. The row says "stopped" (not the evaluator's "clock") with the controller's reason, and the
    evaluation prints that reason on stderr once for all such runs."""
    case = ObjectCase(name="sphere", kind="sphere", size_m=(0.03,))
    (episode,) = episodes([case], 1, ("igef",), params={"controller.initial_target_m": [0.5, 0.5, 0.5]})
    row = run_episode(episode)
    assert row["finished"] == "stopped" and row["contacts"] == 0
    assert row["stop_reason"].startswith("controller: the initial approach from the start position towards")
    assert not stopped_early("") and not stopped_early("exploration finished: goal")  # the clock, the evaluator
    finished = {**row, "finished": "goal", "stop_reason": "exploration finished: goal"}
    report_stopped([row, {**row, "run": 1}, finished])
    err = capsys.readouterr().err.splitlines()
    assert err == [f"2 run(s) stopped early (first: sphere igef run 0): {row['stop_reason']}"]


def test_runs_that_ended_short_of_the_goal_are_named_once_per_way_of_ending(capsys: pytest.CaptureFixture[str]) -> None:
    def row(run: int, finished: str, coverage: float, **more: object) -> dict[str, object]:
        return {"object": "crate", "strategy": "igef", "run": run, "finished": finished, "coverage": coverage,
                "contacts": 2516, **more}  # fmt: skip

    report_short(
        [
            row(0, "goal", 0.8),
            row(1, "no progress", 0.017),
            row(2, "contact budget", 0.64),
            row(3, "no progress", 0.2),
            row(4, "stopped", 0.1),  # report_stopped names these
            row(5, "", 0.0, error="MeshError: crate.stl: ..."),  # and report_errors these
        ]
    )
    assert capsys.readouterr().err.splitlines() == [
        "2 run(s) ended short of the coverage goal by no progress (first: crate igef run 1, 2 % with 2516 "
        "contacts); runs.csv holds each run's end",
        "1 run(s) ended short of the coverage goal by contact budget (first: crate igef run 2, 64 % with 2516 "
        "contacts); runs.csv holds each run's end",
    ]


def test_a_run_tells_its_progress_after_a_touch_at_most_every_ten_seconds(monkeypatch: pytest.MonkeyPatch) -> None:
    from types import SimpleNamespace

    from palpate.evaluation import explore

    clock = [100.0]
    monkeypatch.setattr(explore.time, "perf_counter", lambda: clock[0])
    touches: list[SimpleNamespace] = []
    handled: list[int] = []
    node = SimpleNamespace(run=SimpleNamespace(evaluator=SimpleNamespace(touches=touches)))
    node.on_touches = handled.append
    told: list[str] = []
    explore._report_touches(node, told.append)
    for i, t in enumerate((5.0, 10.0, 12.0, 19.9, 20.0)):
        clock[0] = 100.0 + t
        touches.append(SimpleNamespace(coverage=0.01 * (i + 1), travel_cm=150.0 * (i + 1)))
        node.on_touches(i)
    assert handled == [0, 1, 2, 3, 4]  # every touch reaches the evaluator
    assert told == ["2 contacts, 2.0 % covered, 3.0 m", "5 contacts, 5.0 % covered, 7.5 m"]  # at 10 s and 20 s


def test_a_real_run_reports_its_progress_through_the_evaluators_touches(monkeypatch: pytest.MonkeyPatch) -> None:
    from palpate.evaluation import explore

    monkeypatch.setattr(explore, "PROGRESS_EVERY_S", 0.0)  # after every touch
    case = ObjectCase(name="sphere", kind="sphere", size_m=(0.03,))
    (episode,) = episodes([case], 1, ("igef",), params={"eval.eval.coverage_goal": 0.05})
    told: list[str] = []
    row = run_episode(episode, progress=told.append)
    assert len(told) == row["contacts"] >= 2
    assert told[0].startswith("1 contact, ") and told[-1].startswith(f"{row['contacts']} contacts, ")
    assert f", {100.0 * row['coverage']:.1f} % covered, " in told[-1]  # the last touch's, as the row's


def test_a_profiled_run_carries_each_parts_seconds_and_the_summary_adds_them_up() -> None:
    case = ObjectCase(name="sphere", kind="sphere", size_m=(0.03,))
    (episode,) = episodes([case], 1, ("gpv",), params={"eval.eval.coverage_goal": 0.05})  # a few touches
    plain, profiled = run_episode(episode), run_episode(episode, profile=True)
    assert "node_s" not in plain and profiled["contacts"] == plain["contacts"]
    parts = profiled["node_s"]
    assert {"step", "transfer", "gpis.inputs", "planner.inputs", "eval.inputs"} <= set(parts)
    assert all(seconds >= 0.0 for seconds in parts.values()) and parts["gpis.inputs"] > 0.0
    runs = [profiled, {**profiled, "strategy": "igef", "node_s": {"step": 1.0}}, plain]
    total = profile_summary(runs)
    assert total["step"] == pytest.approx(parts["step"] + 1.0) and next(iter(total)) == "step"
    assert profile_summary(runs, "igef") == {"step": 1.0} and profile_summary(runs, "gpv") == parts
    rows = profile_table(runs, ["gpv", "igef"]).splitlines()[-len(total) :]
    assert rows[0].startswith("| step | ") and rows[0].endswith(f" | {parts['step']:.1f} | 1.0 |")
    shares = [float(row.split("|")[3].strip().removesuffix("%")) for row in rows]
    assert sum(shares) == pytest.approx(100.0, abs=0.1 * len(rows))


def test_a_worker_names_the_users_mesh_file_and_leaves_its_warnings_to_the_main_process(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import warnings

    from palpate.errors import MeshWarning
    from palpate.evaluation import explore

    user_file = tmp_path / "part.stl"
    cached = tmp_path / "cache" / "3f9a.stl"
    case = ObjectCase(name="part", kind="mesh", mesh=str(user_file))
    start = {"start_m": (0.0, 0.0, 0.1), "target_m": (0.0, 0.0, 0.0), "quaternion_wxyz": (0.0, 1.0, 0.0, 0.0)}
    episode = explore.Episode(case=case, strategy="igef", run=0, **start)

    def fails(episode: explore.Episode, profile: bool = False, progress: object = None) -> dict[str, object]:
        warnings.warn(f"{episode.case.mesh}: 3 duplicate faces dropped", MeshWarning, stacklevel=1)
        raise MeshError(f"{episode.case.mesh}: the mesh has no volume")

    monkeypatch.setattr(explore, "local_copy", lambda shared: cached)
    monkeypatch.setattr(explore, "run_episode", fails)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        row = explore.run_episode_on_worker(episode, False, object())  # type: ignore[arg-type]
    assert row["error"] == f"MeshError: {user_file}: the mesh has no volume"
    assert not [w for w in caught if issubclass(w.category, MeshWarning)]


def test_a_run_out_of_memory_is_an_error_row_not_a_task_for_dask_to_retry(monkeypatch: pytest.MonkeyPatch) -> None:
    from palpate.evaluation import explore

    case = ObjectCase(name="crate", kind="mesh", mesh="crate.stl")
    start = {"start_m": (0.0, 0.0, 0.1), "target_m": (0.0, 0.0, 0.0), "quaternion_wxyz": (0.0, 1.0, 0.0, 0.0)}
    episode = explore.Episode(case=case, strategy="tour", run=2, **start)

    def runs_out(episode: explore.Episode, profile: bool = False, progress: object = None) -> dict[str, object]:
        raise MemoryError("Unable to allocate 9.59 GiB for an array with shape (35875, 35875)")

    monkeypatch.setattr(explore, "run_episode", runs_out)
    row = explore.run_episode_on_worker(episode, False)
    assert row["error"].startswith("MemoryError: the run ran out of memory (Unable to allocate 9.59 GiB")
    assert "--max-contacts" in row["error"]
    assert (row["object"], row["strategy"], row["run"], row["complete"], row["contacts"]) == (
        "crate",
        "tour",
        2,
        False,
        0,
    )


def test_a_symlink_loop_in_the_objects_folder_is_named(tmp_path: Path) -> None:
    trimesh.creation.box((0.05, 0.05, 0.05)).export(tmp_path / "box.stl")
    (tmp_path / "loop1.stl").symlink_to("loop2.stl")
    (tmp_path / "loop2.stl").symlink_to("loop1.stl")
    with pytest.raises(MeshError, match=r"loop1\.stl: cannot follow it to a mesh file"):
        objects_in(tmp_path)


def test_a_refused_evaluation_leaves_no_empty_out_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An outside walkthrough: a missing --objects folder was named, but the --out folder had been made."""
    from palpate.cli import main

    out = tmp_path / "out"
    assert main(["eval", "explore", "--objects", str(tmp_path / "none"), "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not out.exists()


def test_quick_takes_no_runs_and_from_runs_tables_the_strategies_it_holds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside walkthrough: `--quick --runs 0` ran one start per object without a word; `--from-runs`
    with a strategy the file lacks was an IndexError traceback, and without --strategies it tabled
    IGEF and GP-V only, dropping the quick run's tour."""
    import argparse

    from palpate.cli import main
    from palpate.evaluation.explore import runs_from, runs_of, strategies_in

    with pytest.raises(ConfigError, match="--quick runs one start per object; leave out --runs 0"):
        runs_of(argparse.Namespace(quick=True, runs=0))
    assert runs_of(argparse.Namespace(quick=True, runs=None)) == 1
    assert runs_of(argparse.Namespace(quick=False, runs=None)) == 3
    with pytest.raises(ConfigError, match="--runs must be >= 1, got 0"):
        runs_of(argparse.Namespace(quick=False, runs=0))
    assert main(["sweep", "explore", "--quick", "--runs", "2", "--out", str(tmp_path / "sw")]) == 2
    assert "--quick runs one start per object" in capsys.readouterr().err
    rows = [{"object": "box", "strategy": s, "run": 0} for s in ("tour", "gpv", "igef")]
    assert strategies_in(rows, None, tmp_path) == ["igef", "gpv", "tour"]  # the planner's order
    assert strategies_in(rows, "tour,igef", tmp_path) == ["tour", "igef"]
    with pytest.raises(ConfigError, match="holds no run of area; its strategies: igef, gpv, tour"):
        strategies_in(rows, "igef,area", tmp_path)
    table = tmp_path / "runs.csv"
    table.write_text("object,strategy\n")
    with pytest.raises(ConfigError, match=r"is the runs' table; give the runs\.jsonl beside it"):
        runs_from(table)
    with pytest.raises(ConfigError, match=r"^RUNS\.jsonl '.*none\.jsonl' is not a file"):
        runs_from(tmp_path / "none.jsonl", given_as="RUNS.jsonl")
    monkeypatch.setenv("PALPATE_YCB_DIR", str(tmp_path / "nowhere"))
    assert main(["eval", "explore", "--out", str(tmp_path / "o")]) == 2
    assert f"{tmp_path / 'nowhere'} is no folder (give --objects DIR, or set PALPATE_YCB_DIR" in capsys.readouterr().err


def test_from_runs_names_what_it_leaves_aside_and_writes_no_runs_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: `--from-runs F --out D` said it wrote D/runs.jsonl (it does not: D's own,
    of other runs, stayed beside tables of F's), and took --runs and --set without a word."""
    import argparse

    from palpate.evaluation.explore import _note_from_runs

    given = tmp_path / "given.jsonl"
    given.write_text("")
    out = tmp_path / "out"
    out.mkdir()
    (out / "runs.jsonl").write_text("")
    args = argparse.Namespace(
        from_runs=given,
        runs=2,
        quick=False,
        objects=None,
        set=["planner.tour_pool=3"],
        max_contacts=None,
        max_travel_m=None,
        resume=False,
        profile=False,
    )
    _note_from_runs(args, out)
    err = capsys.readouterr().err
    assert "--from-runs tables the file's runs as they are; ignored: --runs, --set" in err
    assert f"note: {out / 'runs.jsonl'} is not {given}" in err
    _note_from_runs(argparse.Namespace(**{**vars(args), "runs": None, "set": []}), tmp_path)  # no runs.jsonl there
    assert capsys.readouterr().err == ""


def test_every_refused_mesh_is_named_at_once(tmp_path: Path) -> None:
    """An outside walkthrough: a folder of three bad meshes named one per attempt."""
    from palpate.errors import MeshError

    flat = tmp_path / "flat.stl"
    trimesh.Trimesh([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0]], [[0, 1, 2]]).export(flat)
    empty = tmp_path / "empty.stl"
    empty.write_text("solid nothing\nendsolid nothing\n")
    cases = [
        ObjectCase(name="flat", mesh=str(flat)),
        ObjectCase(name="cube", kind="cube"),
        ObjectCase(name="empty", mesh=str(empty)),
    ]
    with pytest.raises(MeshError, match=r"^2 meshes refused:\n  .*flat\.stl: .*\n  .*empty\.stl: "):
        episodes(cases, 1, ["igef"])
    with pytest.raises(MeshError, match=r"^[^\n]*flat\.stl: "):  # one alone as before
        episodes(cases[:2], 1, ["igef"])


def test_a_worker_warms_up_once_untimed_before_its_first_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """An outside audit: the first runs of a worker carried its imports and numba's kernels (a sweep's rows
    run first showed twice the CPU seconds of the others)."""
    from palpate.evaluation import explore

    ran: list[tuple[float, str, bool]] = []

    def fake_run(episode: explore.Episode, **kwargs: object) -> dict[str, object]:
        ran.append((episode.duration_s, episode.results_path, "progress" in kwargs))
        return {"coverage": 0.0}

    monkeypatch.setattr(explore, "run_episode", fake_run)
    monkeypatch.setattr(explore, "_warmed_up", False)
    [episode] = episodes([ObjectCase(name="cube", kind="cube")], 1, ["igef"])
    episode = replace(episode, results_path="/tmp/results.json")
    for _ in range(2):
        explore.run_episode_on_worker(episode, False)
    timed = (episode.duration_s, "/tmp/results.json", True)
    assert ran == [(explore.WARM_UP_S, "", False), timed, timed]


def test_an_evaluation_in_which_no_run_finished_leaves_the_folder_as_it_was(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: every run lost to killed workers replaced an earlier evaluation's tables and
    runs.csv with empty ones, beside its runs.jsonl and plots, and said it wrote runs.jsonl and plots."""
    import argparse

    from palpate.evaluation import explore
    from palpate.evaluation.dask_runs import Outcome

    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(tmp_path / "box.stl")
    out = tmp_path / "out"
    out.mkdir()
    (out / "tables.md").write_text("the earlier evaluation's tables")

    def all_lost(items, log, config, profile=False):  # type: ignore[no-untyped-def]
        return [None] * len(items), Outcome(failed={"k": "box igef run 0: KilledWorker"})

    monkeypatch.setattr(explore, "run_episodes", all_lost)
    parser = argparse.ArgumentParser()
    explore.configure(parser)
    args = parser.parse_args(
        ["--objects", str(tmp_path / "box.stl"), "--runs", "1", "--out", str(out), "--workers", "1"]
    )
    assert explore.main(args) == 1
    assert (out / "tables.md").read_text() == "the earlier evaluation's tables" and not (out / "runs.csv").exists()
    captured = capsys.readouterr()
    assert f"no run finished: nothing written to {out}" in captured.err and "wrote" not in captured.out
