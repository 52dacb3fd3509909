"""The contact benchmark's float64 reference and its runs (the sensor itself: tests/unit/geometry)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from palpate.geometry.mesh_query import ExactContactSensor
from palpate.nodes.sim.contact_bench import (
    ReferenceMesh,
    bench_mesh,
    default_object_paths,
    format_table,
    run_contact_bench,
    summary,
)
from palpate.nodes.sim.objects import ObjectSpec, load_object, sample_surface


def test_reference_winding_number_separates_inside_and_outside() -> None:
    mesh = load_object(ObjectSpec(kind="torus", size_m=(0.04, 0.012))).mesh
    reference = ReferenceMesh(mesh)
    points = np.array([[0.04, 0, 0], [0, 0, 0], [0.1, 0, 0], [0, 0.04, 0.011]])
    np.testing.assert_allclose(reference.winding_number(points), [1, 0, 0, 1], atol=1e-9)


def test_reference_closest_matches_the_sensor_on_random_points() -> None:
    mesh = load_object(ObjectSpec(kind="torus", size_m=(0.04, 0.012))).mesh
    points = np.random.default_rng(3).uniform(-0.07, 0.07, size=(500, 3))
    ref = ReferenceMesh(mesh).closest(points, tie_m=1e-7)
    got = ExactContactSensor(mesh).closest(points)
    np.testing.assert_allclose(np.abs(got.distance_m), ref["distance"], atol=1e-12)
    # the reported point is a closest point (near the medial axis several are equally close)
    np.testing.assert_allclose(np.linalg.norm(points - got.points_m, axis=1), ref["distance"], atol=1e-12)
    np.testing.assert_allclose(ReferenceMesh(mesh).closest(got.points_m, 1e-7)["distance"], 0.0, atol=1e-15)
    same = np.all(np.abs(got.points_m - ref["points"]) < 1e-12, axis=1)
    assert same.mean() > 0.97


def test_bench_passes_on_a_torus_and_catches_hull_contacts() -> None:
    mesh = trimesh.creation.torus(0.04, 0.012, major_sections=48, minor_sections=24)  # coarse: fast
    row = bench_mesh("torus", mesh, 150, np.random.default_rng(4))
    assert row["touches"] == 150 and row["free_probes"] > 150
    assert row["position_p95_mm"] < 1e-9 and row["normal_p95_deg"] < 1e-3
    assert row["phantom_contacts"] == 0 and row["missed_contacts"] == 0
    # a sensor on the convex hull (what MuJoCo collides) touches in the hole: phantom contacts
    hull_sensor = ExactContactSensor(mesh.convex_hull)
    hull = bench_mesh("torus", mesh, 150, np.random.default_rng(4), sensor=hull_sensor)
    assert hull["phantom_contacts"] > 10
    s = summary([row, hull])
    assert s["phantom_contacts"] == row["phantom_contacts"] + hull["phantom_contacts"]
    assert not s["pass"]
    assert {"position_p95_mm_max", "normal_p95_deg_max", "phantom_contacts"} <= set(s)
    assert "FAIL" in format_table([row, hull])


@pytest.mark.ycb
def test_bench_runs_on_every_mesh_of_a_folder(ycb: Path, tmp_path: Path) -> None:
    (tmp_path / "fork.stl").symlink_to(ycb / "030_fork.stl")
    (tmp_path / "README.md").write_text("not a mesh")
    rows = run_contact_bench(tmp_path, 100, np.random.default_rng(5))
    assert [row["object"] for row in rows] == ["fork"]
    assert summary(rows)["pass"]
    names = [p.stem for p in default_object_paths(ycb)]
    assert names[:2] == ["011_banana", "030_fork"] and len(names) == 13


def test_sampled_surface_points_are_on_the_surface() -> None:
    mesh = load_object(ObjectSpec(kind="sphere", size_m=(0.03,))).mesh
    points, normals = sample_surface(mesh, 1000, np.random.default_rng(6))
    closest = ExactContactSensor(mesh).closest(points + 1e-3 * normals)
    np.testing.assert_allclose(closest.distance_m, 1e-3, atol=1e-12)
    np.testing.assert_allclose(closest.normals, normals, atol=1e-12)
