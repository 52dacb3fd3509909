"""The exact sensor's batch refinement in compiled code (closest_kernels.refine_batch) gives numpy's bits."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

import palpate.geometry.mesh_query as mesh_query
from palpate.geometry.mesh_query import ExactContactSensor, refine_matches_numpy
from palpate.nodes.sim.objects import ObjectSpec, load_object, read_mesh_file


def _points(mesh: trimesh.Trimesh, seed: int) -> np.ndarray:
    """Points near both sides of the surface, on it, at its vertices and anywhere around it."""
    rng = np.random.default_rng(seed)
    surface = np.asarray(mesh.sample(400, seed=seed))
    corners = np.asarray(mesh.vertices)[rng.integers(len(mesh.vertices), size=100)]
    lo, hi = mesh.bounds
    return np.concatenate(
        [
            surface + rng.normal(0.0, 0.004, surface.shape),
            surface + rng.normal(0.0, 1e-7, surface.shape),
            corners,
            corners + rng.normal(0.0, 1e-4, corners.shape),
            lo + rng.random((200, 3)) * (hi - lo) * 1.4 - 0.2 * (hi - lo),
        ]
    )


def _assert_same_bits(mesh: trimesh.Trimesh, points: np.ndarray, monkeypatch: pytest.MonkeyPatch) -> None:
    sensor = ExactContactSensor(mesh)
    local = points - sensor._centre
    found, _ = sensor._scene.closest(local)
    for got, expected in zip(sensor._refine_compiled(local, found), sensor._refine(local, found), strict=True):
        assert got.dtype == expected.dtype
        np.testing.assert_array_equal(got, expected)
    compiled = sensor.closest(points)
    monkeypatch.setattr(mesh_query, "refine_matches_numpy", lambda: False)
    reference = sensor.closest(points)
    for name in ("points_m", "distance_m", "normals", "face_ids"):
        assert getattr(compiled, name).tobytes() == getattr(reference, name).tobytes(), name


def test_the_compiled_refinement_gives_numpys_bits_here() -> None:
    assert refine_matches_numpy(samples=3000)


@pytest.mark.parametrize(
    "spec",
    [
        ObjectSpec(kind="torus", size_m=(0.04, 0.012), position_m=(0.3, -0.2, 0.1)),
        ObjectSpec(kind="box", size_m=(0.1, 0.06, 0.04), position_m=(1.5, -1.0, 0.7)),
        ObjectSpec(kind="cylinder"),
    ],
    ids=["torus", "box", "cylinder"],
)
def test_compiled_refinement_on_primitives(spec: ObjectSpec, monkeypatch: pytest.MonkeyPatch) -> None:
    mesh = load_object(spec).mesh
    _assert_same_bits(mesh, _points(mesh, 1), monkeypatch)


def test_compiled_refinement_with_a_degenerate_triangle(monkeypatch: pytest.MonkeyPatch) -> None:
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    vertices = np.vstack([box.vertices, box.vertices[box.faces[0, 0]]])  # a zero-area sliver on a face
    faces = np.vstack([box.faces, [[box.faces[0, 0], box.faces[0, 1], len(vertices) - 1]]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    _assert_same_bits(mesh, _points(mesh, 3), monkeypatch)


@pytest.mark.ycb
def test_compiled_refinement_on_a_folded_scan_and_the_banana(ycb: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """block_of_wood_6in has a folded triangle whose pseudo-normals cancel (weak signs)."""
    for name in ("block_of_wood_6in.stl", "011_banana.stl"):
        mesh = read_mesh_file(ycb / name)
        _assert_same_bits(mesh, _points(mesh, 4), monkeypatch)
