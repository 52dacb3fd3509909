"""Mesh queries: triangle kernel vs a slow reference, the Open3D scene vs brute force, the exact sensor's
analytic distances, holes and cups."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from palpate.errors import MeshError
from palpate.geometry.mesh_query import (
    EDGE_AB,
    FACE,
    VERTEX_C,
    ExactContactSensor,
    MeshScene,
    closest_points_on_triangles,
    face_rings,
)
from palpate.nodes.sim.objects import read_mesh_file


def _torus(R: float, r: float, x_m: float = 0.0) -> trimesh.Trimesh:
    """The simulator's torus: 128 x 64 sections, axis z, centred at (x_m, 0, 0)."""
    mesh = trimesh.creation.torus(major_radius=R, minor_radius=r, major_sections=128, minor_sections=64)
    mesh.apply_translation([x_m, 0.0, 0.0])
    return mesh


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
    box = trimesh.creation.box(extents=2 * half)
    box.apply_translation(offset)
    sensor = ExactContactSensor(box)
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
    sensor = ExactContactSensor(_torus(R, r))
    theta = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    core = np.stack([R * np.cos(theta), R * np.sin(theta), np.zeros_like(theta)], axis=1)
    # the 128 x 64 tessellation lies inside the true tube by at most its two chord sags
    sag = r * (1 - math.cos(math.pi / 64)) + (R + r) * (1 - math.cos(math.pi / 128))
    distance = sensor.closest(core).distance_m
    np.testing.assert_array_less(distance, -r + 1e-12 + sag)
    np.testing.assert_array_less(-r - 1e-12, distance)


def test_probe_in_the_torus_hole_reports_no_contact_but_pressed_on_the_surface_does() -> None:
    R, r, probe = 0.04, 0.012, 0.008
    sensor = ExactContactSensor(_torus(R, r, 0.1))
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
    sensor = ExactContactSensor(trimesh.creation.box(extents=[0.05] * 3))
    assert sensor.closest(np.zeros((0, 3))).points_m.shape == (0, 3)
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        sensor.closest(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        sensor.closest(np.array([[0.0, np.nan, 0.0]]))


def _winding_number(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Slow reference inside test: generalised winding number, the summed solid angles of the triangles
    over 4 pi (Van Oosterom and Strackee 1983); 1 inside a closed outward mesh, 0 outside."""
    total = np.zeros(len(points))
    for a, b, c in np.asarray(mesh.triangles, dtype=np.float64):
        A, B, C = a - points, b - points, c - points
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (A, B, C))
        det = np.einsum("ij,ij->i", A, np.cross(B, C))
        dots = la * lb * lc + np.einsum("ij,ij->i", A, B) * lc + np.einsum("ij,ij->i", B, C) * la
        total += 2.0 * np.arctan2(det, dots + np.einsum("ij,ij->i", C, A) * lb)
    return total / (4.0 * np.pi)


@pytest.mark.ycb
def test_folded_scan_triangle_does_not_flip_the_sign(ycb: Path) -> None:
    """block_of_wood_6in has a triangle folded back against its neighbours (face 81): the pseudo-normal
    of its corner cancels, and the sign must come from ray parity. These points are outside."""
    mesh = read_mesh_file(ycb / "block_of_wood_6in.stl")
    points = np.array([[0.03130689, -0.03054209, 0.1126743], [0.03335627, -0.03037272, 0.11379165]])
    np.testing.assert_allclose(_winding_number(mesh, points), 0.0, atol=1e-9)
    closest = ExactContactSensor(mesh).closest(points)
    assert np.all(closest.distance_m > 0.02)


def _brute_force_closest(mesh: trimesh.Trimesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slow reference: the float64 closest point over every triangle. Returns distances (n,), points (n, 3)."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    F = len(tri)
    q, _ = closest_points_on_triangles(
        np.repeat(points, F, axis=0), *(np.tile(tri[:, k], (len(points), 1)) for k in range(3))
    )
    d = np.linalg.norm(q - np.repeat(points, F, axis=0), axis=1).reshape(len(points), F)
    best = np.argmin(d, axis=1)
    return d[np.arange(len(points)), best], q.reshape(len(points), F, 3)[np.arange(len(points)), best]


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (1.5, -1.0, 0.7)])
def test_scene_closest_and_distance_match_brute_force_in_float32(offset: tuple[float, float, float]) -> None:
    """Open3D answers in float32 on the shifted mesh: errors ~1e-8 m even 2 m from the world origin."""
    mesh = _torus(0.04, 0.012)
    mesh = trimesh.Trimesh(mesh.vertices[:, [0, 2, 1]] + offset, mesh.faces[:, [0, 2, 1]])  # tilted, moved
    mesh.fix_normals()
    subset = mesh.submesh([np.arange(0, len(mesh.faces), 7)], append=True)  # a lighter, open mesh
    scene = MeshScene(subset.vertices, subset.faces)
    np.testing.assert_array_equal(scene.origin_m, 0.5 * (subset.vertices.min(axis=0) + subset.vertices.max(axis=0)))
    points = np.asarray(offset) + np.random.default_rng(9).uniform(-0.07, 0.07, size=(300, 3))
    expected_d, expected_q = _brute_force_closest(subset, points)
    local = points - scene.origin_m
    faces, q = scene.closest(local)
    assert faces.dtype == np.int64 and q.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(q - local, axis=1), expected_d, rtol=0, atol=5e-8)
    # a closest point: on the surface (near the medial axis it may be another one than brute force's)
    np.testing.assert_allclose(_brute_force_closest(subset, q + scene.origin_m)[0], 0.0, rtol=0, atol=5e-8)
    assert np.mean(np.all(np.abs(q + scene.origin_m - expected_q) < 5e-8, axis=1)) > 0.97
    np.testing.assert_allclose(scene.distance(local), expected_d, rtol=0, atol=5e-8)
    single_faces, _ = scene.closest(local[:3])  # single-threaded below SMALL_BATCH: the same answer
    np.testing.assert_array_equal(single_faces, faces[:3])


def test_scene_inside_test_and_rays_on_a_box() -> None:
    half = np.array([0.05, 0.03, 0.02])
    box = trimesh.creation.box(extents=2 * half)
    box.apply_translation([0.2, 0.1, 0.0])
    scene = MeshScene(box.vertices, box.faces, origin_m=[0.2, 0.1, 0.0])  # the box's centre
    rng = np.random.default_rng(10)
    local = rng.uniform(-0.08, 0.08, size=(2000, 3))
    margin = np.abs(np.abs(local) - half).min(axis=1) > 1e-4  # away from the faces
    inside = np.all(np.abs(local) < half, axis=1)
    np.testing.assert_array_equal(scene.occupied(local[margin]), inside[margin])
    # rays from 10 cm out along -x, -y, -z hit the faces at 10 cm - half; a ray pointing away misses
    starts = np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1], [0.1, 0.0, 0.0]])
    directions = np.array([[-1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0], [1.0, 0, 0]])
    t = scene.ray_hit_distance(starts, directions)
    np.testing.assert_allclose(t[:3], 0.1 - half, rtol=0, atol=1e-8)
    assert t[3] == np.inf and t.dtype == np.float64
    np.testing.assert_allclose(scene.ray_hit_distance(starts[0], directions[0]), [0.1 - half[0]], atol=1e-8)


def test_scene_refuses_a_mesh_without_faces() -> None:
    with pytest.raises(MeshError, match="faces"):
        MeshScene(np.zeros((3, 3)), np.zeros((0, 3), dtype=np.int64))


def test_a_vertex_shared_by_thousands_of_faces_is_refused_before_its_table_is_built() -> None:
    """A fan of 20,000 faces around one vertex: trimesh's (vertices x largest degree) table alone took
    15 s and 7 GB before the limit on the face rings refused the mesh."""
    n = 20000
    theta = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    rim = 0.05 * np.c_[np.cos(theta), np.sin(theta), np.zeros(n)]
    faces = np.c_[np.zeros(n, dtype=np.int64), 1 + np.arange(n), 1 + (np.arange(n) + 1) % n]
    fan = trimesh.Trimesh(np.vstack([[0.0, 0.0, 0.0], rim]), faces, process=False)
    with pytest.raises(MeshError, match=r"20000 faces with a vertex shared by 20000 of them: .* remesh it"):
        face_rings(fan)
    assert "vertex_faces" not in fan._cache.cache  # refused before trimesh built the table
