"""thin_near: the planner's candidate thinning, shared with the GPIS node's variance sites."""

from __future__ import annotations

import numpy as np

from palpate.geometry.thinning import thin_near


def test_one_point_per_voxel_nearest_its_centre_within_the_radius() -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.05, 0.05, (4000, 3))
    centre = np.array([0.003, -0.002, 0.001])
    keep = thin_near(points, centre, 0.01, 0.04)
    assert np.all(np.diff(keep) > 0)
    rel = (points - centre) / 0.01
    voxel = np.floor(rel + 0.5).astype(int)
    inside = np.linalg.norm(points - centre, axis=1) <= 0.04
    assert len({tuple(v) for v in voxel[inside]}) == len(keep)  # every occupied voxel once
    for i in keep[:50]:  # the kept point is the nearest to its voxel centre among the voxel's points
        same = inside & np.all(voxel == voxel[i], axis=1)
        d = np.linalg.norm(rel[same] - voxel[i], axis=1)
        assert np.linalg.norm(rel[i : i + 1] - voxel[i], axis=1)[0] == d.min()  # the same sum as d's


def test_thinning_the_kept_points_again_keeps_them_all() -> None:
    rng = np.random.default_rng(1)
    points = rng.normal(0.0, 0.03, (3000, 3))
    keep = thin_near(points, np.zeros(3), 0.005, 0.06)
    again = thin_near(points[keep], np.zeros(3), 0.005, 0.06)
    np.testing.assert_array_equal(again, np.arange(len(keep)))


def test_no_point_within_the_radius_keeps_none() -> None:
    assert thin_near(np.array([[1.0, 0.0, 0.0]]), np.zeros(3), 0.005, 0.06).shape == (0,)


def test_an_infinite_radius_keeps_one_point_per_voxel_everywhere() -> None:
    rng = np.random.default_rng(4)
    points = rng.uniform(-0.2, 0.2, (3000, 3))
    centre = np.array([0.01, -0.02, 0.0])
    everywhere = thin_near(points, centre, 0.005, np.inf)  # raised OverflowError
    np.testing.assert_array_equal(everywhere, thin_near(points, centre, 0.005, 1.0))
    assert 0 < len(everywhere) < len(points)
