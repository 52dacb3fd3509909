"""Exact-mesh contact sensor: kernel vs a slow reference, analytic distances, holes and cups, bench."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from palpate.bench.contacts import ReferenceMesh
from palpate.nodes.sim.contacts import (
    EDGE_AB,
    FACE,
    VERTEX_C,
    ExactContactSensor,
    closest_points_on_triangles,
)
from palpate.nodes.sim.objects import ObjectSpec, load_object, read_mesh_file, sample_surface


def _slow_closest(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Reference: the plane projection if it falls inside, else the closest of the three edges."""
    n = np.cross(b - a, c - a)
    q = p - np.dot(p - a, n) / np.dot(n, n) * n
    # barycentric coordinates of q by least squares
    w = np.linalg.lstsq(np.stack([b - a, c - a], axis=1), q - a, rcond=None)[0]
    if w[0] >= 0 and w[1] >= 0 and w.sum() <= 1:
        return np.asarray(q)
    best, best_d = a, math.inf
    for s, e in ((a, b), (b, c), (c, a)):
        t = np.clip(np.dot(p - s, e - s) / np.dot(e - s, e - s), 0.0, 1.0)
        x = s + t * (e - s)
        if np.linalg.norm(p - x) < best_d:
            best, best_d = x, float(np.linalg.norm(p - x))
    return np.asarray(best)


def test_triangle_kernel_matches_slow_reference() -> None:
    rng = np.random.default_rng(0)
    n = 3000
    a, b, c = (rng.normal(size=(n, 3)) for _ in range(3))
    p = 2.0 * rng.normal(size=(n, 3))
    q, region = closest_points_on_triangles(p, a, b, c)
    expected = np.array([_slow_closest(p[i], a[i], b[i], c[i]) for i in range(n)])
    np.testing.assert_allclose(q, expected, atol=1e-12)
    assert set(np.unique(region)) == set(range(7))  # every Voronoi region was exercised


def test_triangle_kernel_regions() -> None:
    a, b, c = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    points = np.array([[0.2, 0.2, 1.0], [0.5, -1.0, 0.3], [-0.1, 2.0, 0.0]])
    q, region = closest_points_on_triangles(points, *(np.repeat(x, 3, axis=0) for x in (a, b, c)))
    np.testing.assert_array_equal(region, [FACE, EDGE_AB, VERTEX_C])
    np.testing.assert_allclose(q, [[0.2, 0.2, 0], [0.5, 0, 0], [0, 1, 0]], atol=1e-15)


def _box_signed_distance(p: np.ndarray, half: np.ndarray) -> np.ndarray:
    d = np.abs(p) - half
    outside = np.linalg.norm(np.maximum(d, 0.0), axis=1)
    inside = np.minimum(d.max(axis=1), 0.0)
    return np.asarray(outside + inside)


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (1.5, -1.0, 0.7)])
def test_signed_distance_of_a_box_is_exact_far_from_the_origin(offset: tuple[float, float, float]) -> None:
    """The float64 refinement makes distances exact even where float32 spacing is ~1e-7 m."""
    half = np.array([0.05, 0.03, 0.02])
    spec = ObjectSpec(kind="box", size_m=tuple(2 * half), position_m=offset)
    sensor = ExactContactSensor(load_object(spec).mesh)
    rng = np.random.default_rng(2)
    local = rng.uniform(-0.08, 0.08, size=(5000, 3))
    got = sensor.closest(local + np.array(offset))
    np.testing.assert_allclose(got.distance_m, _box_signed_distance(local, half), atol=1e-13)
    assert got.points_m.dtype == got.distance_m.dtype == got.normals.dtype == np.float64
    # where the closest point is inside one face, the normal is that face's axis, pointing outward
    d = np.abs(local) - half
    order = np.sort(d, axis=1)
    face_region = (order[:, 1] < 0) & (order[:, 2] - order[:, 1] > 1e-4)  # one face clearly closest
    axis = np.argmax(d, axis=1)
    expected = np.zeros_like(local)
    expected[np.arange(len(local)), axis] = np.sign(local[np.arange(len(local)), axis])
    np.testing.assert_allclose(got.normals[face_region], expected[face_region], atol=1e-12)


def test_inside_is_negative_on_a_torus_and_matches_the_core_circle() -> None:
    R, r = 0.04, 0.012
    sensor = ExactContactSensor(load_object(ObjectSpec(kind="torus", size_m=(R, r))).mesh)
    theta = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    core = np.stack([R * np.cos(theta), R * np.sin(theta), np.zeros_like(theta)], axis=1)
    # the 128 x 64 tessellation lies inside the true tube by at most its two chord sags
    sag = r * (1 - math.cos(math.pi / 64)) + (R + r) * (1 - math.cos(math.pi / 128))
    distance = sensor.closest(core).distance_m
    np.testing.assert_array_less(distance, -r + 1e-12 + sag)
    np.testing.assert_array_less(-r - 1e-12, distance)


def test_probe_in_the_torus_hole_reports_no_contact_but_pressed_on_the_surface_does() -> None:
    R, r, probe = 0.04, 0.012, 0.008
    sensor = ExactContactSensor(load_object(ObjectSpec(kind="torus", size_m=(R, r), position_m=(0.1, 0, 0))).mesh)
    touching, _ = sensor.touch(np.array([[0.1, 0.0, 0.0]]), probe)  # hole centre, 20 mm from the tube
    assert not touching[0]
    # pressed 0.2 mm onto the outer equator and the top of the tube
    centres = np.array([[0.1 + R + r + probe - 2e-4, 0, 0], [0.1 + R, 0, r + probe - 2e-4]])
    touching, closest = sensor.touch(centres, probe)
    assert touching.all()
    angles = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", closest.normals, [[1, 0, 0], [0, 0, 1]]), -1, 1)))
    # facet normals of the 128 x 64 torus deviate by at most half a step in each direction
    np.testing.assert_array_less(angles, math.degrees(math.hypot(math.pi / 64, math.pi / 128)))
    np.testing.assert_allclose(closest.distance_m, probe - 2e-4, atol=3e-5)
    # just out of reach (tolerance 0.1 mm) is not a contact
    touching, _ = sensor.touch(centres + np.array([[5e-4, 0, 0], [0, 0, 5e-4]]), probe)
    assert not touching.any()


@pytest.mark.ycb
def test_probe_inside_an_open_cup_reports_no_contact_until_it_touches_the_floor(ycb: Path) -> None:
    mesh = read_mesh_file(ycb / "065-e_cups.stl")  # a cup standing open end up, its floor near z = 7 mm
    sensor = ExactContactSensor(mesh)
    zmin, zmax = mesh.bounds[:, 2]
    middle = np.array([[0.0, 0.0, 0.5 * (zmin + zmax)]])
    touching, _ = sensor.touch(middle, 0.008)
    assert not touching[0]
    assert ExactContactSensor(mesh.convex_hull).touch(middle, 0.008)[0][0]  # where MuJoCo would touch
    # the probe descending inside the cup until it meets the floor: the normal points up (+z)
    path = np.array([[0.0, 0.0, z] for z in np.linspace(middle[0, 2], zmin, 2000)])
    touching, closest = sensor.touch(path, 0.008)
    first = int(np.argmax(touching))
    assert touching[first] and not touching[:first].any()
    assert 0.01 < path[first, 2] < 0.02
    assert closest.normals[first, 2] > 0.95


def test_queries_are_validated_and_empty_is_fine() -> None:
    sensor = ExactContactSensor(load_object(ObjectSpec(kind="cube")).mesh)
    assert sensor.closest(np.zeros((0, 3))).points_m.shape == (0, 3)
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        sensor.closest(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        sensor.closest(np.array([[0.0, np.nan, 0.0]]))


@pytest.mark.ycb
def test_folded_scan_triangle_does_not_flip_the_sign(ycb: Path) -> None:
    """block_of_wood_6in has a triangle folded back against its neighbours (face 81): the pseudo-normal
    of its corner cancels, and the sign must come from ray parity. These points are outside."""
    mesh = read_mesh_file(ycb / "block_of_wood_6in.stl")
    points = np.array([[0.03130689, -0.03054209, 0.1126743], [0.03335627, -0.03037272, 0.11379165]])
    np.testing.assert_allclose(ReferenceMesh(mesh).winding_number(points), 0.0, atol=1e-9)
    closest = ExactContactSensor(mesh).closest(points)
    assert np.all(closest.distance_m > 0.02)


def test_sampled_surface_points_are_on_the_surface() -> None:
    mesh = load_object(ObjectSpec(kind="sphere", size_m=(0.03,))).mesh
    points, normals = sample_surface(mesh, 1000, np.random.default_rng(6))
    closest = ExactContactSensor(mesh).closest(points + 1e-3 * normals)
    np.testing.assert_allclose(closest.distance_m, 1e-3, atol=1e-12)
    np.testing.assert_allclose(closest.normals, normals, atol=1e-12)
