"""The single-point fast path of ExactContactSensor.closest agrees with the vectorised path."""

from __future__ import annotations

import numpy as np
import trimesh

from palpate.geometry.mesh_query import ExactContactSensor
from palpate.nodes.sim.objects import primitive_mesh


def test_single_point_queries_match_the_batch_path() -> None:
    rng = np.random.default_rng(3)
    for mesh in (primitive_mesh("torus", (0.04, 0.015)), trimesh.creation.box((0.05, 0.04, 0.03))):
        sensor = ExactContactSensor(mesh)
        points = np.asarray(mesh.sample(300, seed=1)) + rng.normal(scale=0.01, size=(300, 3))
        batch = sensor.closest(points)
        single = [sensor.closest(points[i : i + 1]) for i in range(len(points))]
        np.testing.assert_allclose(np.vstack([s.points_m for s in single]), batch.points_m, rtol=0, atol=1e-15)
        np.testing.assert_allclose(np.concatenate([s.distance_m for s in single]), batch.distance_m, atol=1e-15)
        # faces may differ only where two faces share the closest point (an edge or a vertex)
        assert all(s.points_m.shape == (1, 3) and s.normals.shape == (1, 3) for s in single)


def test_single_point_inside_is_negative() -> None:
    sensor = ExactContactSensor(trimesh.creation.box((0.02, 0.02, 0.02)))
    inside = sensor.closest(np.array([[0.001, 0.002, 0.003]]))
    np.testing.assert_allclose(inside.distance_m, [-0.007], atol=1e-15)
    np.testing.assert_allclose(inside.points_m, [[0.001, 0.002, 0.01]], atol=1e-15)
    np.testing.assert_allclose(inside.normals, [[0.0, 0.0, 1.0]], atol=1e-12)
