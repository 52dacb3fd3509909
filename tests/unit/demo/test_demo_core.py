"""The minimal demo's pure parts."""

from __future__ import annotations

import numpy as np

from palpate.nodes.demo.core import ContactStatistics, sample_cube_contacts


def test_cube_contacts_lie_on_the_faces_with_outward_normals() -> None:
    rng = np.random.default_rng(1)
    positions, normals = sample_cube_contacts(0.05, 500, rng)
    assert positions.shape == normals.shape == (500, 3)
    np.testing.assert_allclose(np.abs(positions).max(axis=1), 0.025, atol=1e-12)
    # the normal points along the axis of the face the point lies on
    np.testing.assert_allclose(np.einsum("ij,ij->i", positions, normals), 0.025, atol=1e-12)


def test_statistics_track_counts_and_extent() -> None:
    stats = ContactStatistics()
    np.testing.assert_array_equal(stats.extent_m(), np.zeros(3))
    stats.add(np.array([[0.0, 0.0, 0.0], [0.01, 0.02, 0.03]]))
    stats.add(np.zeros((0, 3)))
    assert (stats.messages, stats.contacts) == (2, 2)
    np.testing.assert_allclose(stats.extent_m(), [0.01, 0.02, 0.03])


def test_box_variance_is_that_of_a_uniform_distribution_over_the_longest_edge_per_contact() -> None:
    stats = ContactStatistics()
    stats.add(np.array([[0.0, 0.0, 0.0], [0.01, 0.03, 0.02]]))
    stats.add(np.array([[0.005, 0.01, 0.0]]))
    assert stats.box_variance_m2() == 0.03**2 / 12 / 3
