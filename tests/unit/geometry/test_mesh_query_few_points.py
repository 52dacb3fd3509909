"""The exact contact sensor's few-point path (Python scalars) gives the vectorised path's answer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

import palpate.geometry.mesh_query as mesh_query
from palpate.geometry.mesh_query import (
    FEW_POINTS,
    ExactContactSensor,
    closest_points_on_triangles,
    closest_region,
)
from palpate.nodes.sim.objects import ObjectSpec, load_object, read_mesh_file


def test_scalar_region_matches_the_vectorised_kernel() -> None:
    rng = np.random.default_rng(0)
    n = 3000
    a, b, c = (rng.normal(size=(n, 3)) for _ in range(3))
    p = 2.0 * rng.normal(size=(n, 3))
    q, region = closest_points_on_triangles(p, a, b, c)
    ab, ac = b - a, c - a
    scalar_q = np.empty_like(q)
    scalar_region = np.empty(n, dtype=np.int64)
    for i in range(n):
        ap, bp, cp = p[i] - a[i], p[i] - b[i], p[i] - c[i]
        code, wb, wc = closest_region(
            float(ab[i] @ ap),
            float(ac[i] @ ap),
            float(ab[i] @ bp),
            float(ac[i] @ bp),
            float(ab[i] @ cp),
            float(ac[i] @ cp),
        )
        scalar_region[i] = code
        scalar_q[i] = a[i] + wb * ab[i] + wc * ac[i]
    np.testing.assert_array_equal(scalar_region, region)
    np.testing.assert_allclose(scalar_q, q, atol=1e-12)
    assert len(np.unique(region)) == 7  # every Voronoi region was exercised


def _general(
    sensor: ExactContactSensor, points: np.ndarray, monkeypatch: pytest.MonkeyPatch
) -> mesh_query.ClosestPoints:
    with monkeypatch.context() as patch:
        patch.setattr(mesh_query, "FEW_POINTS", 0)
        return sensor.closest(points)


def _assert_same(sensor: ExactContactSensor, points: np.ndarray, monkeypatch: pytest.MonkeyPatch) -> None:
    expected = _general(sensor, points, monkeypatch)
    got = [sensor.closest(points[i : i + 1]) for i in range(len(points))]
    got_points = np.concatenate([g.points_m for g in got])
    got_distance = np.concatenate([g.distance_m for g in got])
    got_faces = np.concatenate([g.face_ids for g in got])
    np.testing.assert_allclose(got_points, expected.points_m, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got_distance, expected.distance_m, rtol=0, atol=1e-15)  # sign included
    # another face only on exact ties (a shared edge or vertex): the same point, and that face is as close
    tri = np.asarray(sensor.mesh.triangles)
    for faces in (got_faces, expected.face_ids):
        q, _ = closest_points_on_triangles(points, tri[faces, 0], tri[faces, 1], tri[faces, 2])
        np.testing.assert_allclose(np.linalg.norm(points - q, axis=1), np.abs(expected.distance_m), rtol=0, atol=1e-15)
    for g in got:
        assert g.points_m.dtype == g.distance_m.dtype == g.normals.dtype == np.float64
        assert g.face_ids.dtype == np.int64
        np.testing.assert_array_equal(g.normals, sensor.mesh.face_normals[g.face_ids])
    # a batch of a few points equals the points one by one
    few = sensor.closest(points[:FEW_POINTS])
    np.testing.assert_array_equal(few.points_m, got_points[:FEW_POINTS])
    np.testing.assert_array_equal(few.distance_m, got_distance[:FEW_POINTS])


@pytest.mark.parametrize(
    "spec",
    [
        ObjectSpec(kind="torus", size_m=(0.04, 0.012), position_m=(0.3, -0.2, 0.1)),
        ObjectSpec(kind="box", size_m=(0.1, 0.06, 0.04), position_m=(1.5, -1.0, 0.7)),
        ObjectSpec(kind="sphere", size_m=(0.03,)),
    ],
    ids=["torus", "box", "sphere"],
)
def test_few_point_path_equals_the_vectorised_path(spec: ObjectSpec, monkeypatch: pytest.MonkeyPatch) -> None:
    mesh = load_object(spec).mesh
    sensor = ExactContactSensor(mesh)
    rng = np.random.default_rng(1)
    surface = np.asarray(mesh.sample(300, seed=2))
    lo, hi = mesh.bounds
    points = np.concatenate(
        [
            surface + rng.normal(0.0, 0.004, surface.shape),  # near, both sides
            surface + rng.normal(0.0, 1e-7, surface.shape),  # on the surface
            lo + rng.random((100, 3)) * (hi - lo) * 1.4 - 0.2 * (hi - lo),  # anywhere around
        ]
    )
    _assert_same(sensor, points, monkeypatch)


def test_few_point_path_handles_a_degenerate_triangle(monkeypatch: pytest.MonkeyPatch) -> None:
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    # a zero-area sliver on a face: its bound rows are zero, so it is always projected
    vertices = np.vstack([box.vertices, box.vertices[box.faces[0, 0]]])
    faces = np.vstack([box.faces, [[box.faces[0, 0], box.faces[0, 1], len(vertices) - 1]]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    sensor = ExactContactSensor(mesh)
    points = np.random.default_rng(3).uniform(-0.05, 0.05, size=(200, 3))
    _assert_same(sensor, points, monkeypatch)


@pytest.mark.ycb
def test_few_point_path_on_a_folded_scan_and_the_banana(ycb: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """block_of_wood_6in has a folded triangle whose corner pseudo-normal cancels: ray parity decides."""
    rng = np.random.default_rng(4)
    for name, extra in (("block_of_wood_6in.stl", [[0.03130689, -0.03054209, 0.1126743]]), ("011_banana.stl", [])):
        mesh = read_mesh_file(ycb / name)
        surface = np.asarray(mesh.sample(150, seed=5))
        points = np.concatenate([np.array(extra).reshape(-1, 3), surface + rng.normal(0.0, 0.003, surface.shape)])
        _assert_same(ExactContactSensor(mesh), points, monkeypatch)
