"""The warm-started query (WarmClosest) answers as the exact sensor does, bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from palpate.geometry.mesh_query import ExactContactSensor, WarmClosest, closest_points_on_triangles
from palpate.nodes.sim.objects import ObjectSpec, load_object, read_mesh_file


def _walks(mesh: trimesh.Trimesh, rng: np.random.Generator, walks: int, steps: int, height_m: float) -> np.ndarray:
    """Random walks (walks * steps, 3) starting ``height_m`` above surface samples, 0.1 mm per step."""
    points, faces = trimesh.sample.sample_surface(mesh, walks, seed=int(rng.integers(1 << 30)))
    out = []
    for p0, f in zip(points, faces, strict=True):
        p = p0 + height_m * mesh.face_normals[f]
        d = rng.normal(size=3)
        for _ in range(steps):
            d = d + 0.2 * rng.normal(size=3)
            d /= np.linalg.norm(d)
            p = p + 1e-4 * d
            out.append(p)
    return np.array(out)


def _assert_bitwise(sensor: ExactContactSensor, points: np.ndarray) -> WarmClosest:
    warm = WarmClosest(sensor)
    for p in points:
        point, distance, face = warm.query(p)
        expected = sensor.closest(p[None, :])
        assert (point, distance, face) == (
            tuple(expected.points_m[0].tolist()),
            float(expected.distance_m[0]),
            int(expected.face_ids[0]),
        )
    return warm


@pytest.mark.parametrize(
    "spec",
    [
        ObjectSpec(kind="torus", size_m=(0.04, 0.012), position_m=(0.3, -0.2, 0.1)),
        ObjectSpec(kind="box", size_m=(0.1, 0.06, 0.04), position_m=(1.5, -1.0, 0.7)),
        ObjectSpec(kind="sphere", size_m=(0.03,)),
    ],
    ids=["torus", "box", "sphere"],
)
def test_warm_query_equals_the_sensor_along_walks(spec: ObjectSpec) -> None:
    mesh = load_object(spec).mesh
    sensor = ExactContactSensor(mesh)
    rng = np.random.default_rng(1)
    points = np.concatenate(
        [
            _walks(mesh, rng, 6, 120, 0.008),  # a fingertip sliding 8 mm above the surface
            _walks(mesh, rng, 3, 60, -0.002),  # inside, near the surface
            _walks(mesh, rng, 2, 60, 0.05),  # far: the sensor's own search
        ]
    )
    warm = _assert_bitwise(sensor, points)
    assert warm.counts["builds"] >= 9 and warm.counts["patch"] > 0.8 * len(points) and warm.counts["full"] > 0


def test_warm_query_rejects_non_finite_points() -> None:
    sensor = ExactContactSensor(load_object(ObjectSpec(kind="cube")).mesh)
    with pytest.raises(ValueError, match="finite"):
        WarmClosest(sensor).query([0.0, np.nan, 0.1])
    with pytest.raises(ValueError, match="reach_m"):
        WarmClosest(sensor, reach_m=0.0)


@pytest.mark.ycb
def test_warm_query_on_a_folded_scan_the_banana_and_the_fork(ycb: Path) -> None:
    rng = np.random.default_rng(2)
    for name in ("block_of_wood_6in.stl", "011_banana.stl", "030_fork.stl"):
        mesh = read_mesh_file(ycb / name)
        _assert_bitwise(ExactContactSensor(mesh), _walks(mesh, rng, 4, 100, 0.008))


# --- the compiled kernels against plain Python (no fused multiply-add, no reassociation) ------------


def _region_py(d1: float, d2: float, d3: float, d4: float, d5: float, d6: float) -> tuple[int, float, float]:
    """Ericson 5.1.5 in plain Python floats (the code the kernels were compiled from)."""
    if d1 <= 0.0 and d2 <= 0.0:
        return 1, 0.0, 0.0
    if d3 >= 0.0 and d4 <= d3:
        return 2, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return 4, d1 / (d1 - d3), 0.0
    if d6 >= 0.0 and d5 <= d6:
        return 3, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return 6, 0.0, d2 / (d2 - d6)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 >= d3 and d5 >= d6:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 5, 1.0 - t, t
    denom = 1.0 / (va + vb + vc)
    return 0, vb * denom, vc * denom


def _project_py(tri: np.ndarray, p: list[float]) -> tuple[float, int, float, float]:
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = tri.tolist()
    abx, aby, abz, acx, acy, acz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
    x, y, z = p[0] - ax, p[1] - ay, p[2] - az
    bpx, bpy, bpz = p[0] - bx, p[1] - by, p[2] - bz
    cpx, cpy, cpz = p[0] - cx, p[1] - cy, p[2] - cz
    region, wb, wc = _region_py(
        abx * x + aby * y + abz * z,
        acx * x + acy * y + acz * z,
        abx * bpx + aby * bpy + abz * bpz,
        acx * bpx + acy * bpy + acz * bpz,
        abx * cpx + aby * cpy + abz * cpz,
        acx * cpx + acy * cpy + acz * cpz,
    )
    ox, oy, oz = x - wb * abx - wc * acx, y - wb * aby - wc * acy, z - wb * abz - wc * acz
    return ox * ox + oy * oy + oz * oz, region, wb, wc


def test_compiled_projection_is_bitwise_plain_python() -> None:
    from palpate.geometry import closest_kernels

    rng = np.random.default_rng(0)
    n = 4000
    tri = rng.normal(size=(n, 3, 3)) * 0.01
    p = 0.02 * rng.normal(size=(n, 3))
    p[::5] = tri[::5, 0] + 0.5 * (tri[::5, 1] - tri[::5, 0])  # on an edge
    regions = set()
    for i in range(n):
        x, y, z = p[i].tolist()
        got = closest_kernels.project(tri, i, x, y, z)
        assert got == _project_py(tri[i], [x, y, z])
        regions.add(got[1])
    assert regions == set(range(7))


def test_exact_ties_go_to_the_lowest_face_id_on_every_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """Points above a box's vertices and edges are equally close to several faces: the sensor's
    few-point path and the warm query (the compiled projection's arithmetic) and the vectorised path
    (numpy's) answer with the lowest id among the faces at exactly the smallest squared distance, in
    their own arithmetic, even where Open3D's search offers the highest of them and whichever face
    the warm query starts from."""
    from palpate.geometry import closest_kernels

    mesh = trimesh.creation.box((0.04, 0.03, 0.02))
    sensor = ExactContactSensor(mesh)
    corners = np.asarray(mesh.vertices)
    edges = 0.5 * (corners[mesh.edges_unique[:, 0]] + corners[mesh.edges_unique[:, 1]])
    points = np.concatenate([corners, edges]) * 1.25  # outside, over a vertex or an edge
    faces = range(len(mesh.faces))
    tri = sensor._triangles

    def tied(p: list[float]) -> np.ndarray:
        squared = np.array([closest_kernels.project(tri, f, *p)[0] for f in faces])
        return np.flatnonzero(squared == squared.min())

    scalar, vectorised, tie_counts = [], [], []
    for p in (points - sensor._centre).tolist():
        scalar.append(int(tied(p).min()))
        tie_counts.append(len(tied(p)))
        q, _ = closest_points_on_triangles(np.repeat([p], len(tri), 0), tri[:, 0], tri[:, 1], tri[:, 2])
        squared = np.einsum("ij,ij->i", q - p, q - p)
        vectorised.append(int(np.flatnonzero(squared == squared.min()).min()))
    assert sum(count >= 2 for count in tie_counts) >= 6  # points that tie exactly

    # Open3D's search offers the highest tied face (the old rule kept the face Open3D offered)
    scene = sensor._scene
    found = scene.closest

    def highest(local: np.ndarray) -> list[int]:
        return [int(tied(p).max()) for p in np.asarray(local).tolist()]

    monkeypatch.setattr(scene, "closest_face_ids", highest)
    monkeypatch.setattr(scene, "closest", lambda local: (np.array(highest(local)), found(local)[1]))
    few = [int(sensor.closest(p[None]).face_ids[0]) for p in points]
    warm = WarmClosest(sensor)
    warm_faces = []
    for start in (0, len(mesh.faces) - 1):  # warm starts at the first and at the last face
        for p in points:
            warm._face, warm._faces = start, None
            warm_faces.append(warm.query(p)[2])
    monkeypatch.setattr("palpate.geometry.mesh_query.FEW_POINTS", 0)
    batch = sensor.closest(points).face_ids.tolist()
    assert few == scalar and warm_faces == 2 * scalar and batch == vectorised


def test_a_warm_query_that_adopts_another_patch_answers_the_same() -> None:
    """Any valid patch gives the same answers: a query handed another query's (older) patch through
    ``adopt`` answers as that query does, and as the sensor does."""
    mesh = load_object(ObjectSpec(kind="torus", size_m=(0.04, 0.012))).mesh
    sensor = ExactContactSensor(mesh)
    points = _walks(mesh, np.random.default_rng(4), 4, 60, 0.006)
    leader, follower = WarmClosest(sensor), WarmClosest(sensor)
    for i, p in enumerate(points):
        if i % 7 == 0:
            p0, face, faces, planes, offsets, lower0 = leader.patch()
            follower.adopt(p0, face, faces, planes, offsets, lower0)
        assert follower.query(p) == leader.query(p)
