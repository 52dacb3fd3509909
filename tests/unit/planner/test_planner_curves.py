"""Admissibility of candidate curves against the estimated surface (planner.curves.curves_clear)."""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from palpate.nodes.planner.curves import curves_clear


def _plane(size: float = 0.1, step: float = 0.005) -> tuple[np.ndarray, np.ndarray]:
    g = np.arange(-size, size + 1e-9, step)
    X, Y = np.meshgrid(g, g)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    return V, np.tile([0.0, 0.0, 1.0], (len(V), 1))


def test_hop_over_a_plane_is_clear_and_one_under_it_is_not() -> None:
    V, N = _plane()
    start = np.array([0.0, 0.0, 0.008])  # fingertip centre resting on the plane
    down = np.array([0.0, 0.0, -1.0])  # it came down onto it
    centres = np.array([[0.02, 0.0, 0.008], [0.02, 0.0, -0.008]])  # above the plane / below (its back side)
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    clear = curves_clear(V, N, start, down, centres, normals, 0.007)
    np.testing.assert_array_equal(clear, [True, False])


def test_curve_to_the_far_side_of_a_small_ball_is_rejected() -> None:
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    V, N = np.asarray(ball.vertices), np.asarray(ball.vertex_normals)
    start = np.array([0.0, 0.0, 0.028])
    down = np.array([0.0, 0.0, -1.0])
    side = np.array([[1.0, 0.0, 0.2]]) / np.linalg.norm([1.0, 0.0, 0.2])
    far = np.array([[0.0, 0.0, -1.0]])
    targets = np.vstack([0.028 * side, 0.028 * far])
    clear = curves_clear(V, N, start, down, targets, np.vstack([side, far]), 0.007)
    np.testing.assert_array_equal(clear, [True, False])


def test_a_shared_tree_of_the_mesh_gives_the_same_answer() -> None:
    """The planner builds the mesh's k-d tree once per plan and passes it to every batch of curves."""
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    V, N = np.asarray(ball.vertices), np.asarray(ball.vertex_normals)
    rng = np.random.default_rng(3)
    normals = rng.normal(size=(40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    args = (V, N, np.array([0.0, 0.0, 0.028]), np.array([0.0, 0.0, -1.0]), 0.028 * normals, normals, 0.007)
    alone = curves_clear(*args)
    assert alone.any() and not alone.all()
    np.testing.assert_array_equal(curves_clear(*args, tree=cKDTree(V)), alone)


def test_points_beyond_the_patch_count_as_clear() -> None:
    V, N = _plane(size=0.01)
    start = np.array([0.0, 0.0, 0.2])
    clear = curves_clear(
        V, N, start, np.array([0.0, 0.0, -1.0]), np.array([[0.2, 0.0, 0.2]]), np.array([[0, 0, 1.0]]), 0.007
    )
    assert clear.all()


def test_the_curves_start_where_the_fingertip_rests_is_not_checked() -> None:
    """Samples lie at tau in (0, 1): a fingertip centre 6.5 mm over an estimate it rests on (closer than
    the 7 mm clearance) can still leave along a curve whose first sample (tau = 1/32) is 7.4 mm over it."""
    V, N = _plane()
    start = np.array([0.0, 0.0, 0.0065])
    centres, normals = np.array([[0.03, 0.0, 0.008]]), np.array([[0.0, 0.0, 1.0]])
    assert curves_clear(V, N, start, np.array([0.0, 0.0, -1.0]), centres, normals, 0.007).all()


def test_a_curve_exactly_at_the_clearance_is_clear() -> None:
    # a point fingertip (clearance 0) hopping along the plane z = 0 against a sideways target normal:
    # every sample lies on the plane, signed distance 0 >= 0
    V, N = _plane()
    clear = curves_clear(
        V, N, np.zeros(3), np.zeros(3), np.array([[0.02, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]]), 0.0
    )
    assert clear.all()
