"""`palpate bench contacts`: the reference, one mesh's row, the folder and YCB lookup, the CLI."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

from palpate.bench import contacts as bench_contacts
from palpate.errors import BenchmarkError
from palpate.geometry.mesh_query import ExactContactSensor
from palpate.nodes.sim.objects import ObjectSpec, load_object


def test_reference_winding_number_separates_inside_and_outside() -> None:
    mesh = load_object(ObjectSpec(kind="torus", size_m=(0.04, 0.012))).mesh
    reference = bench_contacts.ReferenceMesh(mesh)
    points = np.array([[0.04, 0, 0], [0, 0, 0], [0.1, 0, 0], [0, 0.04, 0.011]])
    np.testing.assert_allclose(reference.winding_number(points), [1, 0, 0, 1], atol=1e-9)


def test_reference_closest_matches_the_sensor_on_random_points() -> None:
    mesh = load_object(ObjectSpec(kind="torus", size_m=(0.04, 0.012))).mesh
    points = np.random.default_rng(3).uniform(-0.07, 0.07, size=(500, 3))
    ref = bench_contacts.ReferenceMesh(mesh).closest(points, tie_m=1e-7)
    got = ExactContactSensor(mesh).closest(points)
    np.testing.assert_allclose(np.abs(got.distance_m), ref["distance"], atol=1e-12)
    # the reported point is a closest point (near the medial axis several are equally close)
    np.testing.assert_allclose(np.linalg.norm(points - got.points_m, axis=1), ref["distance"], atol=1e-12)
    np.testing.assert_allclose(
        bench_contacts.ReferenceMesh(mesh).closest(got.points_m, 1e-7)["distance"], 0.0, atol=1e-15
    )
    same = np.all(np.abs(got.points_m - ref["points"]) < 1e-12, axis=1)
    assert same.mean() > 0.97


def test_bench_passes_on_a_torus_and_catches_hull_contacts() -> None:
    mesh = trimesh.creation.torus(0.04, 0.012, major_sections=48, minor_sections=24)  # coarse: fast
    row = bench_contacts.bench_mesh("torus", mesh, 150, np.random.default_rng(4))
    assert row["touches"] == 150 and row["free_probes"] > 150
    assert row["position_p95_mm"] < 1e-9 and row["normal_p95_deg"] < 1e-3
    assert row["phantom_contacts"] == 0 and row["missed_contacts"] == 0
    # a sensor on the convex hull (what MuJoCo collides) touches in the hole: phantom contacts
    hull_sensor = ExactContactSensor(mesh.convex_hull)
    hull = bench_contacts.bench_mesh("torus", mesh, 150, np.random.default_rng(4), sensor=hull_sensor)
    assert hull["phantom_contacts"] > 10
    s = bench_contacts.summary([row, hull])
    assert s["phantom_contacts"] == row["phantom_contacts"] + hull["phantom_contacts"]
    assert not s["pass"]
    assert {"position_p95_mm_max", "normal_p95_deg_max", "phantom_contacts"} <= set(s)
    assert "FAIL" in bench_contacts.format_table([row, hull])


@pytest.mark.ycb
def test_bench_runs_on_every_mesh_of_a_folder(ycb: Path, tmp_path: Path) -> None:
    (tmp_path / "fork.stl").symlink_to(ycb / "030_fork.stl")
    (tmp_path / "README.md").write_text("not a mesh")
    rows = bench_contacts.run_contact_bench(bench_contacts.object_paths(tmp_path), 100, np.random.default_rng(5))
    assert [row["object"] for row in rows] == ["fork"]
    assert bench_contacts.summary(rows)["pass"]
    names = [p.stem for p in bench_contacts.object_paths(None, ycb)]
    assert names[:2] == ["011_banana", "030_fork"] and len(names) == 13


def test_contacts_without_ycb_says_what_to_do(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PALPATE_YCB_DIR", str(tmp_path / "absent"))
    with pytest.raises(
        BenchmarkError, match=r"the YCB meshes were not found: set PALPATE_YCB_DIR .* or pass --objects DIR"
    ):
        bench_contacts.object_paths(None)


def test_contacts_objects_must_be_a_folder_of_meshes(tmp_path: Path) -> None:
    with pytest.raises(BenchmarkError, match="not a directory"):
        bench_contacts.object_paths(tmp_path / "nope")
    (tmp_path / "README.md").write_text("no mesh here")
    with pytest.raises(BenchmarkError, match="no mesh files"):
        bench_contacts.object_paths(tmp_path)


def test_contacts_json_last_line_has_the_goal_keys(tmp_path: Path, capsys: Any) -> None:
    import trimesh

    trimesh.creation.torus(0.04, 0.012, major_sections=48, minor_sections=24).export(tmp_path / "torus.stl")
    args = argparse.Namespace(objects=tmp_path, touches=60, seed=1, quick=True, json=True)
    assert bench_contacts.main(args) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert "torus" in out[-3] or any(line.startswith("torus") for line in out)
    last = json.loads(out[-1])
    assert {"position_p95_mm_max", "normal_p95_deg_max", "phantom_contacts"} <= set(last)
    assert last["pass"] and last["phantom_contacts"] == 0 and last["objects"] == 1
    assert last["rows"][0]["object"] == "torus" and last["touches_per_object"] == 60


def test_contacts_reads_a_folder_in_millimetres_with_scale(tmp_path: Path, capsys: Any) -> None:
    import trimesh

    trimesh.creation.torus(40.0, 12.0, major_sections=48, minor_sections=24).export(tmp_path / "torus_mm.stl")
    args = argparse.Namespace(objects=tmp_path, touches=40, seed=1, quick=True, json=True, scale=1.0)
    assert bench_contacts.main(args) == 1
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert not last["pass"] and last["rows"] == [] and list(last["refused"]) == ["torus_mm.stl"]
    assert "--scale 0.001 for palpate eval explore, sweep explore and bench contacts" in last["refused"]["torus_mm.stl"]
    assert bench_contacts.main(argparse.Namespace(**{**vars(args), "scale": 0.001})) == 0
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert last["pass"] and last["rows"][0]["object"] == "torus_mm" and last["refused"] == {}


def test_a_refused_mesh_file_fails_the_benchmark_but_the_others_are_benchmarked(tmp_path: Path, capsys: Any) -> None:
    import trimesh

    trimesh.creation.box(extents=(3.0, 3.0, 3.0)).export(tmp_path / "a_crate.stl")  # 3 m: too large
    trimesh.creation.icosphere(subdivisions=2, radius=0.03).export(tmp_path / "b_ball.stl")
    args = argparse.Namespace(objects=tmp_path, touches=40, seed=1, quick=True, json=True, scale=1.0)
    assert bench_contacts.main(args) == 1
    out = capsys.readouterr().out.strip().splitlines()
    last = json.loads(out[-1])
    assert [row["object"] for row in last["rows"]] == ["b_ball"] and last["phantom_contacts"] == 0
    assert list(last["refused"]) == ["a_crate.stl"] and not last["pass"]
    assert out[-2].startswith("1 of 2 mesh files refused (FAIL): ") and "a_crate.stl: absurd scale" in out[-2]


def test_an_entry_named_like_a_mesh_that_is_no_file_is_named(tmp_path: Path) -> None:
    """It was left out without a word, and the benchmark passed on the other objects."""
    trimesh.creation.box((0.05, 0.05, 0.05)).export(tmp_path / "good.stl")
    (tmp_path / "sub.stl").mkdir()
    (tmp_path / "gone.obj").symlink_to(tmp_path / "nowhere.obj")
    with pytest.raises(BenchmarkError, match=r"gone\.obj, sub\.stl named like meshes but not regular files"):
        bench_contacts.object_paths(tmp_path)
