"""Candidate sampling on the estimated surface (0.5 cm steps up to 5 cm from the last contact)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from palpate.errors import PlanningError
from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.core import Planner, sample_candidates


def dense_plane(spacing: float = 0.001, half: float = 0.08) -> np.ndarray:
    g = np.arange(-half, half + 1e-12, spacing)
    X, Y = np.meshgrid(g, g, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)


def test_plane_thins_to_the_step_grid() -> None:
    V = dense_plane()
    N = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    Q = np.linspace(0, 1, len(V))
    c = np.zeros(3)
    cand = sample_candidates(V, N, Q, c, step_m=0.005, radius_m=0.05)
    # One candidate per 5 mm voxel that holds a surface point in range ...
    in_range = V[np.linalg.norm(V, axis=1) <= 0.05]
    voxels = {tuple(v) for v in np.floor(in_range / 0.005 + 0.5).astype(int).tolist()}
    assert len(cand.indices) == len(voxels)
    # ... and where the voxel centre itself is in range (on the 1 mm grid), that centre is chosen.
    centre = np.floor(cand.points_m / 0.005 + 0.5) * 0.005
    inner = np.linalg.norm(centre, axis=1) <= 0.05 - 1e-9
    np.testing.assert_allclose(cand.points_m[inner], centre[inner], atol=1e-12)
    assert inner.sum() == int(np.sum(np.add.outer(np.arange(-10, 11) ** 2, np.arange(-10, 11) ** 2) < 100))
    assert np.all(np.linalg.norm(cand.points_m - c, axis=1) <= 0.05 + 1e-12)
    # The arrays are rows of the inputs.
    np.testing.assert_array_equal(cand.points_m, V[cand.indices])
    np.testing.assert_array_equal(cand.variance, Q[cand.indices])
    np.testing.assert_array_equal(cand.normals, N[cand.indices])


def test_every_surface_point_in_range_has_a_candidate_nearby() -> None:
    rng = np.random.default_rng(6)
    x = rng.normal(size=(30_000, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    V = 0.04 * x  # a 4 cm sphere, irregular points
    c = V[0]
    cand = sample_candidates(V, x, np.zeros(len(V)), c)
    near = V[np.linalg.norm(V - c, axis=1) <= 0.05]
    gap, _ = cKDTree(cand.points_m).query(near)
    assert gap.max() <= 0.005 * np.sqrt(3)  # at most a voxel diagonal away
    spacing, _ = cKDTree(cand.points_m).query(cand.points_m, k=2)
    assert np.median(spacing[:, 1]) > 0.003  # thinned: about one point per 5 mm voxel
    assert 150 < len(cand.indices) < 800


def test_gpv_samples_further() -> None:
    V = dense_plane()
    N = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    igef = Planner().sample(V, N, np.zeros(len(V)), np.zeros(3))
    gpv = Planner(PlannerConfig(strategy="gpv")).sample(V, N, np.zeros(len(V)), np.zeros(3))
    assert np.linalg.norm(igef.points_m, axis=1).max() == pytest.approx(0.05)
    assert np.linalg.norm(gpv.points_m, axis=1).max() == pytest.approx(0.06)


def test_nothing_in_range_gives_no_candidates_and_bad_shapes_raise() -> None:
    V = dense_plane()
    N = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    empty = sample_candidates(V, N, np.zeros(len(V)), np.array([0.0, 0.0, 1.0]))
    assert empty.points_m.shape == (0, 3) and empty.indices.shape == (0,)
    with pytest.raises(PlanningError, match="must match"):
        sample_candidates(V, N[:-1], np.zeros(len(V)), np.zeros(3))
    with pytest.raises(PlanningError, match="NaN"):
        sample_candidates(np.full((2, 3), np.nan), np.ones((2, 3)), np.zeros(2), np.zeros(3))
