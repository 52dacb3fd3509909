"""Exploration metrics on a sphere and a cube with known answers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from palpate.errors import MeshError
from palpate.metrics.exploration import (
    COVERING_DENSITY,
    CoverageTracker,
    DistanceField,
    RmseScorer,
    angle_to_normal_deg,
    confident_faces,
    covering_bound_contacts,
    mesh_area,
    packing_bound_contacts,
    prediction_miss_m,
    sample_surface,
    surface_rmse,
)

INCH = 0.0254


@pytest.fixture(scope="module")
def sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=5, radius=0.05)


@pytest.fixture(scope="module")
def cube() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(INCH, INCH, INCH))


def box_distance(p: np.ndarray, half: float) -> np.ndarray:
    """Exact unsigned distance from points to the surface of the cube [-half, half]^3."""
    q = np.abs(p) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return np.abs(outside + inside)


def test_areas(sphere: trimesh.Trimesh, cube: trimesh.Trimesh) -> None:
    assert mesh_area(cube) == pytest.approx(6 * INCH**2, rel=1e-12)
    assert mesh_area((sphere.vertices, sphere.faces)) == pytest.approx(4 * np.pi * 0.05**2, rel=2e-3)


def test_surface_samples_pick_triangles_by_area() -> None:
    # two triangles in the plane z = 0 of areas 1/2 and 3/2: a quarter and three quarters of the samples
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [2.0, 0.0, 0.0], [5.0, 0.0, 0.0], [2.0, 1.0, 0.0]])
    F = np.array([[0, 1, 2], [3, 4, 5]])
    n = 40_000
    pts = sample_surface((V, F), n, np.random.default_rng(3))
    in_small = pts[:, 0] + pts[:, 1] <= 1.0
    in_large = (pts[:, 0] >= 2.0) & (pts[:, 0] + 3.0 * pts[:, 1] <= 5.0) & (pts[:, 1] >= 0.0)
    assert np.all(in_small ^ in_large)  # every sample on one of the two triangles
    assert in_small.mean() == pytest.approx(0.25, abs=5 * np.sqrt(0.25 * 0.75 / n))


def test_surface_samples_are_uniform_by_area(cube: trimesh.Trimesh) -> None:
    pts = sample_surface(cube, 60_000, np.random.default_rng(0))
    np.testing.assert_allclose(box_distance(pts, INCH / 2), 0.0, atol=1e-12)
    face = np.argmax(np.abs(pts), axis=1) * 2 + (pts[np.arange(len(pts)), np.argmax(np.abs(pts), axis=1)] > 0)
    counts = np.bincount(face, minlength=6)
    np.testing.assert_allclose(counts / len(pts), 1 / 6, atol=5 * np.sqrt(1 / 6 * 5 / 6 / len(pts)))


def test_covering_bound() -> None:
    assert pytest.approx(1.2092, abs=1e-4) == COVERING_DENSITY
    area = 6 * INCH**2
    bound = covering_bound_contacts(area)
    assert bound == pytest.approx(COVERING_DENSITY * 0.8 * area / (np.pi * 0.006**2), rel=1e-12)
    assert 32 <= bound <= 34  # the "about 32 contacts" for a 1-inch cube
    assert covering_bound_contacts(area, fraction=0.5) == pytest.approx(bound * 5 / 8)
    assert packing_bound_contacts(area) == pytest.approx(bound / COVERING_DENSITY)


def test_disjoint_contacts_reach_the_packing_bound(sphere: trimesh.Trimesh) -> None:
    """Contacts 2 r apart on a sphere never overlap: each explores exactly pi r^2 (Archimedes)."""
    r = 0.006
    z = np.array([-0.03, 0.0, 0.03])  # rings far apart; points within a ring 2 r + 1 mm apart
    contacts = []
    for zi in z:
        ring = np.sqrt(0.05**2 - zi**2)
        k = int(2 * np.pi * ring // (2 * r + 0.001))
        a = 2 * np.pi * np.arange(k) / k
        contacts.append(np.column_stack([ring * np.cos(a), ring * np.sin(a), np.full(k, zi)]))
    C = np.vstack(contacts)
    tracker = CoverageTracker(sphere, radius_m=r, samples=100_000, rng=np.random.default_rng(12))
    coverage = tracker.add_contacts(C)
    # coverage = n pi r^2 / A, i.e. exactly the packing bound's count for that coverage
    assert packing_bound_contacts(tracker.area_m2, coverage, r) == pytest.approx(len(C), rel=0.03)


def test_coverage_of_one_contact_on_a_sphere(sphere: trimesh.Trimesh) -> None:
    # Archimedes: the part of a sphere within distance rho of a point on it has area pi rho^2.
    rho, R, n = 0.03, 0.05, 50_000
    tracker = CoverageTracker(sphere, radius_m=rho, samples=n, rng=np.random.default_rng(1))
    coverage = tracker.add_contact(np.array([0.0, 0.0, R]))
    expected = rho**2 / (4 * R**2)
    assert coverage == pytest.approx(expected, abs=5 * np.sqrt(expected * (1 - expected) / n))
    assert tracker.contacts == 1
    # Vertex coverage: icosphere vertices are spread evenly, so the same fraction within 1%.
    assert tracker.vertex_coverage == pytest.approx(expected, abs=0.01)


def test_coverage_on_a_cube_face_and_corner(cube: trimesh.Trimesh) -> None:
    n = 100_000
    tracker = CoverageTracker(cube, samples=n, rng=np.random.default_rng(2))
    assert tracker.coverage == 0.0
    tracker.add_contact(np.array([0.0, 0.0, INCH / 2]))  # a 6 mm disc in the middle of a face
    expected = np.pi * 0.006**2 / (6 * INCH**2)
    assert tracker.coverage == pytest.approx(expected, abs=5 * np.sqrt(expected / n))
    assert tracker.vertex_coverage == 0.0  # no corner within 6 mm
    tracker.add_contact(np.full(3, INCH / 2))  # a corner: 1 of the 8 vertices
    assert tracker.vertex_coverage == pytest.approx(1 / 8)
    # Adding the same contacts again changes nothing; a batch equals one-by-one.
    before = tracker.coverage
    tracker.add_contacts(np.array([[0.0, 0.0, INCH / 2], [INCH / 2] * 3]))
    assert tracker.coverage == before


def test_batch_equals_sequential(sphere: trimesh.Trimesh) -> None:
    rng = np.random.default_rng(3)
    contacts = sample_surface(sphere, 40, rng)
    a = CoverageTracker(sphere, samples=5000, rng=np.random.default_rng(4))
    b = CoverageTracker(sphere, samples=5000, rng=np.random.default_rng(4))
    for c in contacts:
        a.add_contact(c)
    b.add_contacts(contacts)
    np.testing.assert_array_equal(a.explored_mask, b.explored_mask)
    assert a.vertex_coverage == b.vertex_coverage and 0 < a.coverage < 1


def test_distance_field_is_exact_on_metre_scale_meshes(sphere: trimesh.Trimesh, cube: trimesh.Trimesh) -> None:
    field = DistanceField(sphere)
    np.testing.assert_allclose(field.distance(sphere.vertices), 0.0, atol=1e-8)
    pts = np.random.default_rng(5).uniform(-0.03, 0.03, size=(2000, 3))
    np.testing.assert_allclose(DistanceField(cube).distance(pts), box_distance(pts, INCH / 2), atol=1e-8)


def test_rmse_of_a_grown_sphere_is_the_offset(sphere: trimesh.Trimesh) -> None:
    grown = trimesh.creation.icosphere(subdivisions=5, radius=0.051)
    err = surface_rmse(grown, sphere, samples=20_000, rng=np.random.default_rng(6))
    for value in (err.estimate_to_truth_m, err.truth_to_estimate_m, err.symmetric_m):
        assert value == pytest.approx(0.001, rel=0.02)


def test_rmse_of_a_scaled_cube(cube: trimesh.Trimesh) -> None:
    half, big = INCH / 2, 1.1 * INCH / 2
    estimate = trimesh.creation.box(extents=(2 * big,) * 3)
    err = surface_rmse(estimate, cube, samples=40_000, rng=np.random.default_rng(7))
    # truth -> estimate: every true surface point is exactly big - half inside the big cube's surface
    assert err.truth_to_estimate_m == pytest.approx(big - half, rel=1e-5)
    # estimate -> truth: compare with the exact box distance on independent samples
    pts = sample_surface(estimate, 200_000, np.random.default_rng(8))
    expected = np.sqrt(np.mean(box_distance(pts, half) ** 2))
    assert err.estimate_to_truth_m == pytest.approx(expected, rel=0.01)
    assert err.estimate_to_truth_m > err.truth_to_estimate_m  # corners of the big cube are further
    sym = np.sqrt((err.estimate_to_truth_m**2 + err.truth_to_estimate_m**2) / 2)
    assert err.symmetric_m == pytest.approx(sym, rel=1e-9)


def test_the_rmse_scorer_gives_surface_rmses_bits_for_every_estimate(
    sphere: trimesh.Trimesh, cube: trimesh.Trimesh
) -> None:
    """The true mesh's samples and field made once, each estimate's draw from the generator's state
    after them: the same figures as surface_rmse with a fresh generator, estimate after estimate."""
    scorer = RmseScorer(sphere, samples=3000, seed=4)
    grown = trimesh.creation.icosphere(subdivisions=4, radius=0.052)
    points = np.asarray(sphere.vertices)[::7]
    for estimate in (grown, cube, points, grown):
        assert scorer.score(estimate) == surface_rmse(estimate, sphere, samples=3000, rng=np.random.default_rng(4))
    assert scorer.score(grown) != surface_rmse(grown, sphere, samples=3000, rng=np.random.default_rng(5))


def test_rmse_of_a_point_set_estimate(sphere: trimesh.Trimesh) -> None:
    err = surface_rmse(np.asarray(sphere.vertices), sphere, samples=5000, rng=np.random.default_rng(9))
    assert err.estimate_to_truth_m < 1e-8
    assert err.truth_to_estimate_m < 0.002  # truth samples to the nearest vertex (~1 mm apart)


def test_angle_to_normal() -> None:
    n = np.array([[0.0, 0.0, 1.0]] * 4)
    axis = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0], [1.0, 0.0, -1.0]])
    np.testing.assert_allclose(angle_to_normal_deg(axis, n), [0.0, 90.0, 180.0, 45.0], atol=1e-12)
    assert angle_to_normal_deg(np.array([0, 0, -1.0]), np.array([0, 0, 1.0])).shape == (1,)


def test_prediction_miss() -> None:
    miss = prediction_miss_m(np.array([[0.0, 0.0, 0.0], [0.003, 0.004, 0.0]]), np.zeros((2, 3)))
    np.testing.assert_allclose(miss, [0.0, 0.005], atol=1e-15)
    with pytest.raises(ValueError, match=r"predicted \(2, 3\) and actual \(3, 3\) must be the same"):
        prediction_miss_m(np.zeros((2, 3)), np.zeros((3, 3)))  # numpy would broadcast or fail without the shapes


def test_bad_meshes_raise() -> None:
    with pytest.raises(MeshError, match="faces"):
        mesh_area((np.zeros((3, 3)), np.zeros((0, 3))))
    with pytest.raises(MeshError, match="out of range"):
        mesh_area((np.zeros((3, 3)), np.array([[0, 1, 3]])))
    with pytest.raises(MeshError, match="NaN"):
        mesh_area((np.full((3, 3), np.nan), np.array([[0, 1, 2]])))


@pytest.mark.ycb
def test_ycb_surface_points_are_at_zero_distance(ycb: Path) -> None:
    """The YCB README warns trimesh misreports up to 0.37 mm here; the Open3D field must not."""
    mesh = trimesh.load_mesh(ycb / "011_banana.stl")
    pts = sample_surface(mesh, 5000, np.random.default_rng(10))
    assert DistanceField(mesh).distance(pts).max() < 1e-6
    tracker = CoverageTracker(mesh, samples=20_000, rng=np.random.default_rng(11))
    tracker.add_contacts(pts[::25])
    assert 0.0 < tracker.coverage <= 1.0 and 0.0 < tracker.vertex_coverage <= 1.0
    assert 150 < covering_bound_contacts(tracker.area_m2) < 220  # the "about 185" for the banana


def test_point_arrays_of_the_wrong_shape_or_not_finite_are_named() -> None:
    """(3, 2) and (1, 6) arrays were read as 2 points; NaN was a distance of NaN or scipy's error."""
    cube = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    field, tracker = DistanceField(cube), CoverageTracker(cube, samples=500)
    for bad in (np.zeros((3, 2)), np.zeros((1, 6)), np.zeros(6)):
        with pytest.raises(ValueError, match=r"points must have shape \(n, 3\)"):
            field.distance(bad)
        with pytest.raises(ValueError, match=r"contacts must have shape \(n, 3\)"):
            tracker.add_contacts(bad)
    with pytest.raises(ValueError, match="points must be finite"):
        field.distance([[np.nan, 0.0, 0.0]])
    with pytest.raises(ValueError, match="contact must be finite"):
        tracker.add_contact([np.nan, 0.0, 0.0])
    with pytest.raises(MeshError, match="points must be finite"):
        surface_rmse(np.array([[np.nan, 0.0, 0.0]]), cube, samples=100)
    assert tracker.contacts == 0 and field.distance(np.zeros((0, 3))).shape == (0,)
    np.testing.assert_allclose(field.distance([0.0, 0.0, 0.0]), [0.025])  # one point (3,)
    with pytest.raises(ValueError, match=r"faces must have shape \(f, 3\), got \(2, 2\)"):
        confident_faces(np.zeros((2, 2), dtype=int), np.zeros(3), 0.001)
    with pytest.raises(ValueError, match=r"vertex_variance \(2,\) has no value for vertex 2"):
        confident_faces(np.array([[0, 1, 2]]), np.zeros(2), 0.001)  # an IndexError without the check


def test_the_angle_to_a_zero_vector_is_undefined() -> None:
    """arctan2(0, 0) had called a zero normal or axis a perfect 0 degrees."""
    angles = angle_to_normal_deg(
        [[0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, -1.0]], [[0, 0, 1], [0, 0, 1], [0, 0, 0]]
    )
    assert angles[0] == 0.0 and np.isnan(angles[1:]).all()


def test_the_contact_bounds_refuse_a_negative_area_and_a_radius_of_zero() -> None:
    """An outside audit: covering_bound_contacts(-1) was -8553 contacts, and radius 0 infinity with a warning."""
    for bound in (covering_bound_contacts, packing_bound_contacts):
        assert bound(0.0) == 0.0
        with pytest.raises(ValueError, match=r"area_m2 must be finite and >= 0, got -1"):
            bound(-1.0)
        with pytest.raises(ValueError, match=r"radius_m must be finite and > 0, got 0"):
            bound(0.01, radius_m=0.0)
        with pytest.raises(ValueError, match=r"fraction must lie in \[0, 1\], got 1.5"):
            bound(0.01, fraction=1.5)
